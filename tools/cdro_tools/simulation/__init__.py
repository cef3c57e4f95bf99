"""The network simulator behind cdro-sim: scenarios, the world's truth, the UWB error model, the
simulated device (the firmware's contract, docs/protocol.md "Device behaviour"), fault injection,
and the pseudo-terminal link. docs/tools.md documents the scenario format and the figures used."""
