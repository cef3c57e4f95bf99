"""Writes tests/golden/bounds_cases.json: the edges of every value range of frame_layout.def,
which the C decoder (tests/common/test_bounds.cpp) and the Python decoder
(tests/tools/test_bounds.py) must both judge as written here.

    .venv/bin/python tests/golden/make_bounds_cases.py > tests/golden/bounds_cases.json

Run it after a deliberate change of a range in frame_layout.def; tests/tools/test_bounds.py
fails while the committed table is stale.

For each ranged field, one frame per edge: MIN - 1 and MAX + 1 (where the field's kind can
hold them) are refused as "value", MIN and MAX are accepted. An array's elements get the same
edges (a one-element array), its count 0 and MAX_COUNT are accepted and MAX_COUNT + 1 is
refused as "length". The expected results follow from the ranges alone, never from a decoder.
Every other field keeps the value of the type's first frame in vectors.json, a valid frame.
The "rules" cases probe the hand-written rules beside the generated ranges, in both languages.
"""
from __future__ import annotations

import json
import pathlib
import struct
import sys

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tools"))

from cdro_tools.codec import Frame, cobs_encode, crc16, encode_frame  # noqa: E402
from cdro_tools.codec.layout import CONSTANTS, FRAME_TYPES  # noqa: E402

KIND_LIMITS = {"U8": (0, 0xFF), "U16": (0, 0xFFFF), "U32": (0, 0xFFFFFFFF),
               "I16": (-2**15, 2**15 - 1), "I32": (-2**31, 2**31 - 1)}
ARRAY_ID_BASE = 0x6000  # distinct, valid node ids for a full array


def base_frames() -> dict[str, dict]:
    """The fields of the first golden frame of each type (all of them valid)."""
    vectors = json.loads((ROOT / "tests" / "golden" / "vectors.json").read_text())
    bases: dict[str, dict] = {}
    for v in vectors["frames"]:
        bases.setdefault(v["type"], v["fields"])
    return bases


def case(name: str, frame_type: str, fields: dict, result: str, **extra) -> dict:
    chunk = encode_frame(Frame(frame_type, 0, fields))[:-1]
    return {"name": name, **extra, "type": frame_type, "fields": fields, "chunk": chunk.hex(), "result": result}


def edges(lo: int, hi: int, kind: str) -> list[tuple[str, int, str]]:
    """(edge, value, result) for the edges a kind can hold."""
    kind_lo, kind_hi = KIND_LIMITS[kind]
    out = [("min-1", lo - 1, "value")] if lo > kind_lo else []
    out += [("min", lo, "ok"), ("max", hi, "ok")]
    out += [("max+1", hi + 1, "value")] if hi < kind_hi else []
    return out


def overfull_chunk(frame_type: str, fields: dict, array: dict) -> str:
    """A frame whose array count is MAX_COUNT + 1 with as many elements: the encoder refuses to
    write it, so the payload is packed here field by field."""
    formats = {"U8": "<B", "U16": "<H", "U32": "<I", "I16": "<h", "I32": "<i"}
    payload = b""
    for field in FRAME_TYPES[frame_type]["fields"]:
        if field is array:
            count = field["max"] + 1
            payload += bytes([count])
            payload += b"".join(struct.pack(formats[field["kind"]], ARRAY_ID_BASE + i) for i in range(count))
        else:
            payload += struct.pack(formats[field["kind"]], fields[field["name"]])
    raw = struct.pack("<BBHB", CONSTANTS["CDRO_PROTOCOL_VERSION"], FRAME_TYPES[frame_type]["id"], 0, len(payload))
    raw += payload
    return cobs_encode(raw + struct.pack("<H", crc16(raw))).hex()


def range_cases() -> list[dict]:
    bases = base_frames()
    out = []
    for frame_type, spec in FRAME_TYPES.items():
        for field in spec["fields"]:
            if "range" not in field:
                continue
            name = field["name"]
            lo, hi = field["range"]
            label = f"{frame_type}.{name}"
            for edge, value, result in edges(lo, hi, field["kind"]):
                fields = dict(bases[frame_type], **{name: [value] if "max" in field else value})
                shown = f"[{value}]" if "max" in field else str(value)
                out.append(case(f"{label} = {shown} ({edge})", frame_type, fields, result,
                                field=label, edge=edge, value=value))
            if "max" in field:
                count_label = f"{label}_count"
                for count in (0, field["max"]):
                    fields = dict(bases[frame_type], **{name: [ARRAY_ID_BASE + i for i in range(count)]})
                    edge = "min" if count == 0 else "max"
                    out.append(case(f"{count_label} = {count} ({edge})", frame_type, fields, "ok",
                                    field=count_label, edge=edge, value=count))
                fields = dict(bases[frame_type])
                out.append({"name": f"{count_label} = {field['max'] + 1} (max+1)", "field": count_label,
                            "edge": "max+1", "value": field["max"] + 1, "type": frame_type,
                            "chunk": overfull_chunk(frame_type, fields, field), "result": "length"})
    return out


def rule_cases() -> list[dict]:
    """The hand-written rules (other_rules_ok in frames.c, _other_rule_problem in frames.py)."""
    bases = base_frames()

    def rule(name: str, frame_type: str, result: str, **values) -> dict:
        return case(name, frame_type, dict(bases[frame_type], **values), result, rule=True)

    out = [
        rule("RANGE from_id == to_id", "RANGE", "value", from_id=0x6A11, to_id=0x6A11),
        rule("RANGE from_id and to_id one apart", "RANGE", "ok", from_id=0x6A11, to_id=0x6A12),
        rule("NODE_LIST an id twice", "NODE_LIST", "value", node_ids=[5, 6, 5]),
        rule("NODE_LIST distinct ids", "NODE_LIST", "ok", node_ids=[5, 6, 7]),
        rule("SET_NODES an id twice", "SET_NODES", "value", node_ids=[0xFFFF, 0xFFFF]),
        rule("SET_NODES distinct ids", "SET_NODES", "ok", node_ids=[0xFFFE, 0xFFFF]),
    ]
    for channel, result in ((5, "ok"), (6, "value"), (7, "ok")):
        out.append(rule(f"SET_UWB uwb_channel {channel}", "SET_UWB", result, uwb_channel=channel))
    for prf in range(4):
        for bitrate in (0, 2, 3, 0x3F):
            rates = prf << 6 | bitrate
            result = "ok" if 1 <= prf <= 2 and bitrate <= 2 else "value"
            out.append(rule(f"SET_UWB uwb_rates 0x{rates:02X} (PRF {prf}, bitrate {bitrate})", "SET_UWB",
                            result, uwb_rates=rates))
    preamble_codes = (0x04, 0x14, 0x24, 0x34, 0x08, 0x18, 0x28, 0x0C)  # UWB_PLEN, register facts 2.4
    for plen in (*preamble_codes, 0x00, 0x05, 0x0B, 0x1C, 0x44, 0xFF):
        out.append(rule(f"SET_UWB uwb_plen 0x{plen:02X}", "SET_UWB", "ok" if plen in preamble_codes else "value",
                        uwb_plen=plen))
    return out


def main() -> None:
    table = {
        "about": "Edges of the value ranges of frame_layout.def; see tests/golden/make_bounds_cases.py.",
        "cases": range_cases() + rule_cases(),
    }
    json.dump(table, sys.stdout, indent=1)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()
