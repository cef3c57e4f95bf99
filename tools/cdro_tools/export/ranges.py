"""The RANGE frames of a capture, as the service's intake would take them: the received records'
bytes through the codec's stream decoder (COBS, CRC, version, length, value checks), and, once
the device has sent its node list, only ranges between the own node and listed nodes (the node-id
policy of docs/service.md "Node ids"; before the list is known every range is kept). Rejections
are counted by reason, never fatal."""
from __future__ import annotations

import collections
import dataclasses
from typing import Iterator

from ..codec import CaptureContents, Result, StreamDecoder

RANGES_CSV_HEADER = "t,from,to,range_m"   # what `cdro-hostd --ranges-csv` and cdro-eval read


@dataclasses.dataclass
class RangeRow:
    t_s: float                      # s since the capture was created (the service's t_s)
    host_time_us: int               # us since the Unix epoch, when the chunk arrived
    from_id: int
    to_id: int
    distance_mm: int                # mm, 3D two-way range as the device reported it
    rss_dbm: int
    flags: int
    device_time_ms: int


@dataclasses.dataclass
class RangeTally:
    ranges: int = 0
    frames_ok: int = 0
    rejected: collections.Counter = dataclasses.field(default_factory=collections.Counter)  # decoder result
    not_listed: int = 0             # RANGE naming a node outside the device's node list
    odometry_records: int = 0
    sent_records: int = 0

    def summary(self) -> str:
        parts = [f"{self.ranges} ranges", f"{self.frames_ok} good frames"]
        if self.rejected:
            parts.append("rejected frames: " + ", ".join(f"{n} {r}" for r, n in sorted(self.rejected.items())))
        if self.not_listed:
            parts.append(f"{self.not_listed} ranges naming a node outside the device's node list dropped")
        return "; ".join(parts)


def capture_ranges(contents: CaptureContents, tally: RangeTally) -> Iterator[RangeRow]:
    decoder = StreamDecoder()
    own_id = None
    listed: set[int] | None = None
    created_us = contents.header.created_unix_us
    for record in contents.records:
        if record.odometry:
            tally.odometry_records += 1
            continue
        if record.to_device:
            tally.sent_records += 1
            continue
        for event in decoder.feed(record.data + b"\x00"):
            if event.result != Result.OK or event.frame is None:
                tally.rejected[str(event.result)] += 1
                continue
            tally.frames_ok += 1
            frame = event.frame
            if frame.type == "HELLO":
                own_id = frame.fields["node_id"]
            elif frame.type == "NODE_LIST":
                listed = set(frame.fields["node_ids"])
            elif frame.type == "RANGE":
                f = frame.fields
                if listed is not None and not all(i in listed or i == own_id for i in (f["from_id"], f["to_id"])):
                    tally.not_listed += 1
                    continue
                tally.ranges += 1
                yield RangeRow((record.host_time_us - created_us) / 1e6, record.host_time_us, f["from_id"],
                               f["to_id"], f["distance_mm"], f["rss_dbm"], f["flags"], f["device_time_ms"])


def format_row(row: RangeRow) -> str:
    """t with us resolution; range_m exact to the mm the frame carries."""
    return f"{row.t_s:.6f},{row.from_id},{row.to_id},{row.distance_mm / 1000:.3f}"
