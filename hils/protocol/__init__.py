"""The shared, neutral layer: NTCIP 1202 objects and values, the intersection config and the one conflict check
(what may be lit together: the config validator, the action converter, the emulator's monitor and the fault
harness all ask it), scenario files and the scenarios derived from RESCO's networks, SNMPv3's security services,
the time grid, the user-error base. The emulator imports this layer and nothing else of hils; it imports nothing
else of hils itself (tests/test_layers.py)."""
