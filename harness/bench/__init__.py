"""Benchmarks: commands that print figures and write them under reports/, each side in fresh
processes, alternating, over seeds; the RESCO study."""
