"""The shared, neutral layer: NTCIP 1202 objects and values, the intersection config, scenario files
and the scenarios derived from RESCO's networks, SNMPv3's security services, the time grid, the
user-error base. The emulator imports this layer and nothing else of hils; it imports nothing else
of hils itself (tests/test_layers.py)."""
