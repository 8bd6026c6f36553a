"""The middleware's decisions: the manager (a pure state machine: events in, effects out), its
vocabulary, and the conversion of agent actions into phase commands. No clock, no I/O."""
