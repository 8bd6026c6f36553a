"""The I/O shell around the manager: the middleware that carries out the manager's effects, the poller,
the transports (in-process and SNMP over UDP), the clocks (virtual and wall-clock), virtual time's
fast path, the start-up checks, how each controller is reached, and the event log every step of
the data flow writes."""
