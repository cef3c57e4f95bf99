"""Generates cdro_tools/codec/layout.py from common/'s layout tables (the .def files).

The C code expands the same tables with X-macros; this parser reads their simple grammar
(documented at the top of frame_layout.def), so the Python codec never restates a layout.

    python -m cdro_tools.codegen common/include > tools/cdro_tools/codec/layout.py

    python -m cdro_tools.codegen common/include --docs docs/protocol.md

tests/tools/test_layout.py fails when the committed layout.py or the generated tables in
docs/protocol.md are out of date.
"""
from __future__ import annotations

import argparse
import pathlib
import pprint
import re
import sys

DEFINE = re.compile(r"^#define\s+(CDRO_[A-Z0-9_]+)\s+(0x[0-9A-Fa-f]+|\d+)[UL]*\b", re.M)
STRING_DEFINE = re.compile(r'^#define\s+(CDRO_[A-Z0-9_]+)\s+"([^"\\]*)"', re.M)
LIST = re.compile(r"#define\s+(CDRO_[A-Z_]*LIST)\(X\)((?:[^\n]*\\\n)*[^\n]*)")
RECORD = re.compile(r'X\((\w+),\s*(\w+),\s*(\w+),\s*"([^"]*)"\)')
FIELDS = re.compile(r"#define\s+CDRO_(?:BLOCK_)?FIELDS_(\w+)\(F, R, A(?:, L, V, Q)?\)((?:[^\n]*\\\n)*[^\n]*)")
FIELD = re.compile(r'\b([FRALVQ])\(((?:\s*(?:"[^"]*"|[-\w]+)\s*,)*\s*"[^"]*")\s*\)')
ARG = re.compile(r'"([^"]*)"|([-\w]+)')
NUMBER = re.compile(r"(-?(?:0x[0-9A-Fa-f]+|\d+))[UL]*")
# The arguments of each field macro: "t" a token (kind, name, number or constant), "s" a string.
# L, V and Q are the checkpoint blocks' repeated records, vectors and square matrices
# (checkpoint_layout.def).
SHAPES = {"F": "ttss", "R": "ttstts", "A": "tttstts", "L": "tts", "V": "ttss", "Q": "tttss"}
COUNT_KIND = "U32"  # the count before an L or a V

KIND_SIZES = {"U8": 1, "U16": 2, "U32": 4, "U64": 8, "I16": 2, "I32": 4, "I64": 8, "F64": 8}
KIND_LIMITS = {"U8": (0, 0xFF), "U16": (0, 0xFFFF), "U32": (0, 0xFFFFFFFF), "U64": (0, 2**64 - 1),
               "I16": (-2**15, 2**15 - 1), "I32": (-2**31, 2**31 - 1), "I64": (-2**63, 2**63 - 1)}


def _number(token: str, constants: dict) -> int:
    """A bound or maximum of the .def: a number (C suffixes U and L allowed) or a constant."""
    match = NUMBER.fullmatch(token)
    if match:
        return int(match.group(1), 0)
    if token not in constants:
        raise ValueError(f"{token}: neither a number nor a constant of this file")
    return constants[token]


def _field(record: str, shape: str, args: list[tuple[str, str]], constants: dict) -> dict:
    """One F, R or A entry: kind, name, max (arrays), unit, range (R and A), doc; an L entry:
    list (the record's name), name, doc; a V entry has "vector", a Q entry "square_of"."""
    kinds = "".join("s" if quoted or not token else "t" for quoted, token in args)
    if kinds != SHAPES[shape]:
        raise ValueError(f"{record}: {shape}(...) with arguments {args}, expected the shape {SHAPES[shape]}")
    values = [quoted if kind == "s" else token for kind, (quoted, token) in zip(kinds, args)]
    kind, name = values[0], values[1]
    if shape == "L":
        return {"list": kind, "name": name, "doc": values[2]}
    if kind not in KIND_SIZES:
        raise ValueError(f"{record}.{name}: unknown kind {kind}")
    entry = {"kind": kind, "name": name}
    rest = values[2:]
    if shape == "A":
        entry["max"] = _number(rest.pop(0), constants)
    if shape == "V":
        entry["vector"] = True
    if shape == "Q":
        entry["square_of"] = rest.pop(0)
    entry["unit"] = rest.pop(0)
    if shape in "RA":
        lo_text, hi_text = rest.pop(0), rest.pop(0)
        lo, hi = _number(lo_text, constants), _number(hi_text, constants)
        if kind not in KIND_LIMITS:
            raise ValueError(f"{record}.{name}: {kind} takes no range")
        kind_lo, kind_hi = KIND_LIMITS[kind]
        if not kind_lo <= lo <= hi <= kind_hi:
            raise ValueError(f"{record}.{name}: range {lo}..{hi} empty or outside {kind}'s {kind_lo}..{kind_hi}")
        entry["range"] = (lo, hi)
        entry["range_text"] = (lo_text, hi_text)
    entry["doc"] = rest.pop(0)
    return entry


def parse_def(text: str) -> dict:
    """Constants (numbers; "strings" apart), record lists and field tables of one .def file.

    A field is {"kind", "name", "unit", "doc"}, with "max" (element count) for an array and
    "range" (lowest, highest valid value; of each element for an array) where it has one.
    "range_text" keeps the range as written in the .def, for the docs.
    """
    constants = {name: int(value, 0) for name, value in DEFINE.findall(text)}
    strings = dict(STRING_DEFINE.findall(text))
    lists = {}
    for list_name, body in LIST.findall(text):
        lists[list_name] = [
            {"name": n, "lower": lower, "id_text": ident, "id": int(ident, 0), "doc": doc}
            for n, lower, ident, doc in RECORD.findall(body)
        ]
    fields = {}
    for record, body in FIELDS.findall(text):
        fields[record] = [_field(record, shape, ARG.findall(args), constants) for shape, args in FIELD.findall(body)]
        if len(fields[record]) != len(re.findall(r"\b[FRALVQ]\(", body)):
            raise ValueError(f"CDRO_FIELDS_{record}: a field line does not follow the grammar")
    return {"constants": constants, "strings": strings, "lists": lists, "fields": fields}


def descriptor(records: list[dict], fields: dict, empty: list[dict] = ()) -> str:
    """The canonical layout text, identical to layout_descriptor.h's expansion."""
    out = []
    for record in records:
        parts = []
        for f in fields[record["name"]]:
            if "list" in f:
                parts.append(f"LIST {f['list']} {f['name']};")
            elif "vector" in f:
                parts.append(f"{f['kind']} {f['name']}[];")
            elif "square_of" in f:
                parts.append(f"{f['kind']} {f['name']}[{f['square_of']}*{f['square_of']}];")
            elif "max" in f:
                parts.append(f"{f['kind']} {f['name']}[{f['max']}];")
            else:
                parts.append(f"{f['kind']} {f['name']};")
        out.append(f"{record['name']} {record['id_text']}{{{''.join(parts)}}}")
    for record in empty:
        out.append(f"{record['name']} {record['id_text']}{{}}")
    return "".join(out)


BLOCK_LISTS = {"ENGINE": "CDRO_CHECKPOINT_ENGINE_LIST", "MOVEMENT": "CDRO_CHECKPOINT_MOVEMENT_LIST",
               "FLIGHT": "CDRO_CHECKPOINT_FLIGHT_LIST", "OUTPUT_FRAME": "CDRO_CHECKPOINT_OUTPUT_FRAME_LIST"}


def check_block(records: list[dict], fields: dict) -> None:
    """A checkpoint block's table: every L names a record of the same list, every Q a V before it."""
    names = {r["name"] for r in records}
    for record in records:
        vectors = set()
        for f in fields[record["name"]]:
            if "list" in f and f["list"] not in names:
                raise ValueError(f"{record['name']}.{f['name']}: L of {f['list']}, not a record of this list")
            if "vector" in f:
                vectors.add(f["name"])
            if "square_of" in f and f["square_of"] not in vectors:
                raise ValueError(f"{record['name']}.{f['name']}: Q of {f['square_of']}, not a V before it")


def crc16(data: bytes) -> int:
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def generate(include_dir: pathlib.Path) -> str:
    frames = parse_def((include_dir / "cdro" / "frame_layout.def").read_text())
    sog = parse_def((include_dir / "cdro" / "sog_layout.def").read_text())
    capture = parse_def((include_dir / "cdro" / "capture_layout.def").read_text())
    checkpoint = parse_def((include_dir / "cdro" / "checkpoint_layout.def").read_text())
    frame_list = frames["lists"]["CDRO_FRAME_LIST"]
    empty_list = frames["lists"]["CDRO_EMPTY_FRAME_LIST"]
    sog_list = sog["lists"]["CDRO_SOG_RECORD_LIST"]
    frame_text = descriptor(frame_list, frames["fields"], empty_list)
    sog_text = descriptor(sog_list, sog["fields"])
    capture_list = capture["lists"]["CDRO_CAPTURE_RECORD_LIST"]
    capture_text = descriptor(capture_list, capture["fields"])
    checkpoint_list = checkpoint["lists"]["CDRO_CHECKPOINT_RECORD_LIST"]
    checkpoint_text = descriptor(checkpoint_list, checkpoint["fields"])
    block_texts = {}
    for block, list_name in BLOCK_LISTS.items():
        check_block(checkpoint["lists"][list_name], checkpoint["fields"])
        block_texts[block] = descriptor(checkpoint["lists"][list_name], checkpoint["fields"])

    def table(fields: list[dict]) -> list[dict]:  # range_text is for the docs only
        return [{key: value for key, value in f.items() if key != "range_text"} for f in fields]

    frame_types = {}
    for record in frame_list:
        frame_types[record["name"]] = {"id": record["id"], "doc": record["doc"],
                                       "fields": table(frames["fields"][record["name"]])}
    for record in empty_list:
        frame_types[record["name"]] = {"id": record["id"], "doc": record["doc"], "fields": []}
    sog_records = {r["name"]: {"doc": r["doc"], "fields": table(sog["fields"][r["name"]])} for r in sog_list}
    capture_records = {r["name"]: {"doc": r["doc"], "fields": table(capture["fields"][r["name"]])}
                       for r in capture_list}
    checkpoint_records = {r["name"]: {"doc": r["doc"], "fields": table(checkpoint["fields"][r["name"]])}
                          for r in checkpoint_list}
    block_records = {
        block: {r["name"]: {"doc": r["doc"], "fields": table(checkpoint["fields"][r["name"]])}
                for r in checkpoint["lists"][list_name]}
        for block, list_name in BLOCK_LISTS.items()}
    constants = dict(frames["constants"])
    constants.update(sog["constants"])
    constants.update(capture["constants"])
    constants.update(checkpoint["constants"])
    strings = {**frames["strings"], **sog["strings"], **capture["strings"], **checkpoint["strings"]}

    lines = [
        '"""GENERATED by cdro_tools.codegen from common/include/cdro/*.def. Do not edit."""',
        "",
        f"CONSTANTS = {pprint.pformat(constants, sort_dicts=True)}",
        "",
        f"STRINGS = {pprint.pformat(strings, sort_dicts=True)}",
        "",
        f"FRAME_TYPES = {pprint.pformat(frame_types, sort_dicts=False, width=100)}",
        "",
        f"SOG_RECORDS = {pprint.pformat(sog_records, sort_dicts=False, width=100)}",
        "",
        f"CAPTURE_RECORDS = {pprint.pformat(capture_records, sort_dicts=False, width=100)}",
        "",
        f"CHECKPOINT_RECORDS = {pprint.pformat(checkpoint_records, sort_dicts=False, width=100)}",
        "",
        f"CHECKPOINT_ENGINE_RECORDS = {pprint.pformat(block_records['ENGINE'], sort_dicts=False, width=100)}",
        "",
        f"CHECKPOINT_MOVEMENT_RECORDS = {pprint.pformat(block_records['MOVEMENT'], sort_dicts=False, width=100)}",
        "",
        f"CHECKPOINT_FLIGHT_RECORDS = {pprint.pformat(block_records['FLIGHT'], sort_dicts=False, width=100)}",
        "",
        "CHECKPOINT_OUTPUT_FRAME_RECORDS = "
        f"{pprint.pformat(block_records['OUTPUT_FRAME'], sort_dicts=False, width=100)}",
        "",
        f"FRAME_LAYOUT_DESCRIPTOR = {frame_text!r}",
        f"FRAME_LAYOUT_HASH_COMPUTED = 0x{crc16(frame_text.encode('ascii')):04X}",
        f"SOG_LAYOUT_DESCRIPTOR = {sog_text!r}",
        f"SOG_LAYOUT_HASH_COMPUTED = 0x{crc16(sog_text.encode('ascii')):04X}",
        f"CAPTURE_LAYOUT_DESCRIPTOR = {capture_text!r}",
        f"CAPTURE_LAYOUT_HASH_COMPUTED = 0x{crc16(capture_text.encode('ascii')):04X}",
        f"CHECKPOINT_LAYOUT_DESCRIPTOR = {checkpoint_text!r}",
        f"CHECKPOINT_LAYOUT_HASH_COMPUTED = 0x{crc16(checkpoint_text.encode('ascii')):04X}",
        f"CHECKPOINT_ENGINE_LAYOUT_DESCRIPTOR = {block_texts['ENGINE']!r}",
        f"CHECKPOINT_ENGINE_LAYOUT_HASH_COMPUTED = 0x{crc16(block_texts['ENGINE'].encode('ascii')):04X}",
        f"CHECKPOINT_MOVEMENT_LAYOUT_DESCRIPTOR = {block_texts['MOVEMENT']!r}",
        f"CHECKPOINT_MOVEMENT_LAYOUT_HASH_COMPUTED = 0x{crc16(block_texts['MOVEMENT'].encode('ascii')):04X}",
        f"CHECKPOINT_FLIGHT_LAYOUT_DESCRIPTOR = {block_texts['FLIGHT']!r}",
        f"CHECKPOINT_FLIGHT_LAYOUT_HASH_COMPUTED = 0x{crc16(block_texts['FLIGHT'].encode('ascii')):04X}",
        f"CHECKPOINT_OUTPUT_FRAME_LAYOUT_DESCRIPTOR = {block_texts['OUTPUT_FRAME']!r}",
        f"CHECKPOINT_OUTPUT_FRAME_LAYOUT_HASH_COMPUTED = "
        f"0x{crc16(block_texts['OUTPUT_FRAME'].encode('ascii')):04X}",
        "",
    ]
    return "\n".join(lines)


DOC_BEGIN = ("<!-- BEGIN GENERATED LAYOUT TABLES "
             "(python -m cdro_tools.codegen common/include --docs docs/protocol.md) -->")
DOC_END = "<!-- END GENERATED LAYOUT TABLES -->"
_KIND_TEXT = {"U8": "u8", "U16": "u16", "U32": "u32", "U64": "u64", "I16": "i16", "I32": "i32", "I64": "i64",
              "F64": "f64"}


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


CONSTANT_LINE = re.compile(r'^#define\s+(CDRO_[A-Z0-9_]+)\s+(0x[0-9A-Fa-f]+|\d+|"[^"]*")[UL]*\s*(?:/\*\s*(.*?)\s*\*/)?')


def _constants_table(text: str) -> list[str]:
    """Every #define of a .def with its trailing comment, under its section comment."""
    rows = ["| Constant | Value | Meaning |", "|---|---:|---|"]
    section = ""
    for line in text.splitlines():
        heading = re.match(r"^/\* (.+?)(?: \*/)?$", line)  # a comment starting in column 0
        if heading and not line.startswith("/*\n") and "#define" not in line and len(line) < 90:
            section = heading.group(1)
            continue
        match = CONSTANT_LINE.match(line)
        if match and not match.group(1).endswith("_DEF"):
            meaning = match.group(3) or ""
            if section:
                meaning = f"{section}: {meaning}" if meaning else section
            rows.append(f"| `{match.group(1)}` | {match.group(2)} | {_cell(meaning)} |")
    return rows


def _bound_text(token: str, constants: dict) -> str:
    """A bound as a number: as written in the .def if it is one, else the constant's value."""
    match = NUMBER.fullmatch(token)
    return match.group(1) if match else str(constants[token])


AFTER = re.compile(r"after (\w+)(?:\+(\d+))?")


def _advance(offset: int | str, size: int) -> int | str:
    """The offset size bytes on: a number, "after FIELD+N" past a repeated field, else a sum."""
    if isinstance(offset, int):
        return offset + size
    after = AFTER.fullmatch(offset)
    if after:
        return f"after {after.group(1)}+{int(after.group(2) or 0) + size}"
    return f"{offset}+{size}"


def _repeated_rows(field: dict, offset: int | str) -> list[str]:
    """The rows of an L, V or Q field: its count (L, V) and its elements."""
    doc = _cell(field["doc"])
    count = f"{field['name']}_count"
    if "square_of" in field:
        of = field["square_of"]
        return [f"| {offset} | {_KIND_TEXT[field['kind']]}[{of}_count²] | {field['name']} | "
                f"{_cell(field['unit']) or '-'} | - | {doc}, row by row |"]
    element = field["list"] if "list" in field else _KIND_TEXT[field["kind"]]
    unit = "-" if "list" in field else (_cell(field["unit"]) or "-")
    return [f"| {offset} | {_KIND_TEXT[COUNT_KIND]} | {count} | count | - | number of elements |",
            f"| {_advance(offset, 4)} | {element}[{count}] | {field['name']} | {unit} | - | {doc} |"]


def _fixed_size(fields: list) -> int:
    return sum(KIND_SIZES[f["kind"]] for f in fields)


def _record_section(title: str, record: dict, fields: list, constants: dict, start: int = 0) -> list[str]:
    """One record's part of docs/protocol.md: its heading, its doc sentence and its field table."""
    doc = record["doc"][0].upper() + record["doc"][1:] + "."
    return [f"#### {title}", "", doc, "", *_field_table(fields, constants, start), ""]


def _field_table(fields: list[dict], constants: dict, start: int = 0) -> list[str]:
    """Offsets, types, units and the declared valid ranges ("-": none declared)."""
    rows = ["| Offset | Type | Field | Unit | Range | Meaning |", "|---:|---|---|---|---|---|"]
    offset: int | str = start
    for field in fields:
        if "list" in field or "vector" in field or "square_of" in field:
            rows += _repeated_rows(field, offset)
            offset = f"after {field['name']}"
            continue
        kind = _KIND_TEXT[field["kind"]]
        unit = _cell(field["unit"]) or "-"
        valid = "-"
        if "range_text" in field:
            valid = "..".join(_bound_text(token, constants) for token in field["range_text"])
        doc = _cell(field["doc"])
        if "max" in field:
            rows.append(f"| {offset} | u8 | {field['name']}_count | count | 0..{field['max']} | number of elements |")
            nxt = _advance(offset, 1)
            each = f"{valid} each" if "range_text" in field else valid
            rows.append(f"| {nxt} | {kind}[count] | {field['name']} | {unit} | {each} | {doc} |")
            size = KIND_SIZES[field["kind"]]
            offset = f"{nxt}+{size}*count"
        else:
            rows.append(f"| {offset} | {kind} | {field['name']} | {unit} | {valid} | {doc} |")
            size = KIND_SIZES[field["kind"]]
            offset = _advance(offset, size)
    if not fields:
        rows.append("| - | - | - | - | - | empty payload |")
    return rows


def protocol_tables(include_dir: pathlib.Path) -> str:
    """Markdown byte-offset tables of every frame payload, SoG record, capture file record and
    checkpoint extension block, from the .def files."""
    frame_text = (include_dir / "cdro" / "frame_layout.def").read_text()
    sog_text = (include_dir / "cdro" / "sog_layout.def").read_text()
    capture_text = (include_dir / "cdro" / "capture_layout.def").read_text()
    checkpoint_text = (include_dir / "cdro" / "checkpoint_layout.def").read_text()
    frames = parse_def(frame_text)
    sog = parse_def(sog_text)
    capture = parse_def(capture_text)
    checkpoint = parse_def(checkpoint_text)
    out = [DOC_BEGIN, "", "### Constants", ""]
    out += _constants_table(frame_text) + [""]
    out += _constants_table(sog_text) + [""]
    out += _constants_table(capture_text) + [""]
    out += _constants_table(checkpoint_text) + ["", "### Frame payloads", ""]
    entries = [(r, frames["fields"].get(r["name"], [])) for r in frames["lists"]["CDRO_FRAME_LIST"]]
    entries += [(r, []) for r in frames["lists"]["CDRO_EMPTY_FRAME_LIST"]]
    for record, fields in sorted(entries, key=lambda e: e[0]["id"]):
        direction = "device to host" if record["id"] < 0x40 else "host to device"
        size = sum(KIND_SIZES[f["kind"]] for f in fields if "max" not in f)
        arrays = [f for f in fields if "max" in f]
        most = size + 1 + sum(KIND_SIZES[f["kind"]] * f["max"] for f in arrays)
        size_text = f"{size} bytes" if not arrays else f"{size + 1}..{most} bytes"
        out += _record_section(f"{record['name']} (0x{record['id']:02X}, {direction}, payload {size_text})",
                               record, fields, frames["constants"])
    out.append("### SoG snapshot records")
    out.append("")
    for record in sog["lists"]["CDRO_SOG_RECORD_LIST"]:
        fields = sog["fields"][record["name"]]
        out += _record_section(f"{record['name']} ({_fixed_size(fields)} bytes)", record, fields, sog["constants"])
    out.append("### Capture file records")
    out.append("")
    # CAPTURE_HEAD follows the magic; a record starts with CAPTURE_RECORD_HEAD.
    starts = {"CAPTURE_HEAD": capture["constants"]["CDRO_CAPTURE_MAGIC_SIZE"]}
    for record in capture["lists"]["CDRO_CAPTURE_RECORD_LIST"]:
        fields = capture["fields"][record["name"]]
        out += _record_section(f"{record['name']} ({_fixed_size(fields)} bytes)", record, fields,
                               capture["constants"], starts.get(record["name"], 0))
    out.append("### Checkpoint extension blocks")
    out.append("")
    for record in checkpoint["lists"]["CDRO_CHECKPOINT_RECORD_LIST"]:
        fields = checkpoint["fields"][record["name"]]
        out += _record_section(f"{record['name']} ({_fixed_size(fields)} bytes)", record, fields,
                               checkpoint["constants"])
    for block, list_name in BLOCK_LISTS.items():
        version = f"CDRO_CHECKPOINT_{block}_VERSION"
        title = block.lower().replace("_", " ")
        out.append(f"### Checkpoint {title} block (version {checkpoint['constants'][version]})")
        out.append("")
        for record in checkpoint["lists"][list_name]:
            fields = checkpoint["fields"][record["name"]]
            out += _record_section(record["name"], record, fields, checkpoint["constants"])
    out.append(DOC_END)
    return "\n".join(out)


def replace_generated_section(doc_path: pathlib.Path, section: str, begin_marker: str, end_marker: str) -> bool:
    """Puts section (which starts with begin_marker and ends with end_marker) where doc_path has
    those markers; returns True if the file changed."""
    text = doc_path.read_text()
    begin, end = text.index(begin_marker), text.index(end_marker) + len(end_marker)
    updated = text[:begin] + section + text[end:]
    if updated != text:
        doc_path.write_text(updated)
    return updated != text


def update_docs(include_dir: pathlib.Path, doc_path: pathlib.Path) -> bool:
    """Rewrites the generated section of doc_path; returns True if it changed."""
    return replace_generated_section(doc_path, protocol_tables(include_dir), DOC_BEGIN, DOC_END)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("include_dir", type=pathlib.Path, help="common/include")
    parser.add_argument("--docs", type=pathlib.Path, help="rewrite the generated tables in this markdown file instead")
    args = parser.parse_args(argv)
    if args.docs:
        update_docs(args.include_dir, args.docs)
    else:
        sys.stdout.write(generate(args.include_dir))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
