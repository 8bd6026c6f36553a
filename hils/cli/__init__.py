"""The `hils` command: its parser and subcommands (run, sweep, compare), the status line."""
