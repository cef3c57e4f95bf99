"""The network simulator behind cdro-sim: scenarios, the world's truth, the UWB error model, the
simulated device (the firmware's contract, docs/protocol.md "Device behaviour"), fault injection,
the pseudo-terminal link, and the seeded flights of moving tags that the tracking tests and
scripts share (flights.py). docs/tools.md documents the scenario format and the figures used."""
