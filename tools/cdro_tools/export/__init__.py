"""The service's outputs for other tools: Foxglove (live and MCAP), ROS 2 MCAP, ranges.csv.

- `stream`: the live stream (JSON Lines objects, live map events) as a map state; bad input is
  counted by reason and skipped.
- `scene`: the map state as Foxglove messages; `ros2`: as ROS 2 messages (dicts).
- `recorder`: the sinks (Foxglove channels, an MCAP file of either kind) and the loop that feeds them.
- `ranges`: a capture's RANGE frames, as the service's intake takes them.
- `cli`: cdro-export. The live bridge is `cdro_tools.foxglove_bridge` (cdro-foxglove).
"""
