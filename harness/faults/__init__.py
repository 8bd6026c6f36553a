"""Fault injection and the declarative fault scenarios: the faults (decorators that never edit what
they wrap), the scenario files' reader, the runner and the judge, the UDP fault proxy, the CLI."""
