"""Fault injection and the declarative fault scenarios: the faults (decorators that never edit what they wrap,
:mod:`~harness.faults.inject`), a scenario file's tables (:mod:`~harness.faults.table`), the fault types
(:mod:`~harness.faults.registry`), the file's reader (:mod:`~harness.faults.reader`), the runner
(:mod:`~harness.faults.runner`) and the judge (:mod:`~harness.faults.judge`), the UDP fault proxy, the CLI."""
