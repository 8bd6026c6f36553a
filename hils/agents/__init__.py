"""The built-in agents (random, fixed-cycle, max-pressure, queue-proportional, webster, and the
controller-run baselines) and how an agent is loaded by name."""
