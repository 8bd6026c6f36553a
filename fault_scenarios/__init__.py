"""The shipped fault scenarios: declarative TOML files, data rather than code, each with its expected
outcomes (see README.md here). A package only so that they install with hils and `hils faults run` finds
them from any folder."""
