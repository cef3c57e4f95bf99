"""A simulated robot's capture as a live run records it: plaza-like (the device's own tag rides on
the robot) for 120 s, the device's frames with the robot's odometry records put in their place.
Shared by the tests that replay a robot through cdro-hostd."""
from __future__ import annotations

import json
import pathlib
import subprocess
import sys

from cdro_tools.codec import read_capture
from cdro_tools.codec.capture_file import FLAG_ODOMETRY, CaptureRecord, CaptureWriter

ROBOT = 0x6001          # plaza-like: the device's own tag rides on the robot


def write_robot_capture(directory: pathlib.Path, guard_s: float) -> tuple[pathlib.Path, int]:
    """(the capture's path, its start in us since the epoch); guard_s is a deadlock guard only."""
    subprocess.run([sys.executable, "-m", "cdro_tools.sim", "--scenario", "plaza-like", "--duration", "120",
                    "--capture", str(directory / "frames.cdrocap"), "--odometry-csv", str(directory / "odometry.csv")],
                   check=True, capture_output=True, timeout=guard_s)
    frames = read_capture(directory / "frames.cdrocap")
    start_us = frames.header.created_unix_us
    records = [(r.host_time_us, 0, r) for r in frames.records]
    for row in (directory / "odometry.csv").read_text().splitlines()[1:]:
        t_s, distance_m, dheading_rad = map(float, row.split(","))
        at_us = start_us + round(t_s * 1e6)
        message = json.dumps({"t": at_us / 1e6, "distance_m": distance_m, "dheading_rad": dheading_rad,
                              "source": "udp:127.0.0.1:40000"}, separators=(",", ":"))
        records.append((at_us, 1, CaptureRecord(at_us, message.encode(), FLAG_ODOMETRY)))
    records.sort(key=lambda r: (r[0], r[1]))
    path = directory / "robot.cdrocap"
    with CaptureWriter(path, frames.header.source, start_us) as writer:
        for _, _, record in records:
            writer.write(record)
    return path, start_us
