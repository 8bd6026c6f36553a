"""The SNMP agent that serves the model: BER codec, the MIB view, the agent (v1, v2c, v3 USM),
`hils emulator serve` over UDP, and the hi-res log served over HTTP as a MaxTime does."""
