"""Generates cdro-sim's table of scenario keys and docs/tools.md's table of them from
sim/scenario_keys.def, the one definition of every key that cdro-sim and cdro-fil read (cdro-fil
expands the same file as X-macros, sim/fil/src/scenario_keys.hpp). The grammar is at the top of
the .def.

    python -m cdro_tools.scenario_codegen sim/scenario_keys.def > tools/cdro_tools/simulation/scenario_keys.py

    python -m cdro_tools.scenario_codegen sim/scenario_keys.def --docs docs/tools.md

tests/scenarios/test_scenario_keys.py fails when the committed scenario_keys.py or the generated
table of docs/tools.md is out of date.
"""
from __future__ import annotations

import argparse
import math
import pathlib
import pprint
import re
import sys

import yaml

from cdro_tools.codegen import replace_generated_section

BODY = re.compile(r"#define\s+CDRO_SCENARIO_KEYS\(N, O, T\)((?:[^\n]*\\\n)*[^\n]*)")
RENAMED_BODY = re.compile(r"#define\s+CDRO_SCENARIO_RENAMED_KEYS\(R\)((?:[^\n]*\\\n)*[^\n]*)")
RENAME = re.compile(r'\bR\("([^"\\]*)",\s*"([^"\\]*)"\)')
ENTRY = re.compile(r"\b([NOT])\(")
ARG = re.compile(r'\s*(?:"((?:[^"\\]|\\.)*)"|([-\w.+]+))\s*(,|\))')
# The arguments of each entry: "t" a token, "s" a string.
SHAPES = {"N": "tssttttts", "O": "tssstttts", "T": "tssts"}
TYPES = {"N": ("REAL", "INT"), "O": ("REAL", "INT", "PAIR", "POINTS", "LIST"),
         "T": ("TEXT", "BOOL", "ENUM", "LIST", "MAP")}
BOUNDS = {"CLOSED": (False, False), "OPEN_MIN": (True, False), "OPEN_MAX": (False, True), "OPEN": (True, True)}
TOOLS = {"BOTH": "both", "SIM": "cdro-sim", "FIL": "cdro-fil"}
NUMBER = re.compile(r"-?(?:0x[0-9A-Fa-f]+|\d+(?:\.\d+)?(?:e\d+)?|INF)")


def _number(token: str, where: str) -> float | int:
    if not NUMBER.fullmatch(token):
        raise ValueError(f"{where}: {token!r} is not a number (decimal, hex, with exponent, INF or -INF)")
    if token.lstrip("-") == "INF":
        return -math.inf if token.startswith("-") else math.inf
    if re.fullmatch(r"-?(0x[0-9A-Fa-f]+|\d+)", token):
        return int(token, 0)
    return float(token)


def requirement(spec: dict) -> str:
    """What a value must be, as both readers say it: "in [0, 10] m", "at least 0", "above 0 Hz".
    cdro-fil builds the same words from the same tokens (scenario_keys.hpp, requirement())."""
    low_open, high_open = BOUNDS[spec["bounds"]]
    low, high = spec["min_text"], spec["max_text"]
    unit = f" {spec['unit']}" if spec["unit"] else ""
    if low != "-INF" and high != "INF":
        return f"in {'(' if low_open else '['}{low}, {high}{')' if high_open else ']'}{unit}"
    if low != "-INF":
        return f"{'above' if low_open else 'at least'} {low}{unit}"
    if high != "INF":
        return f"{'below' if high_open else 'at most'} {high}{unit}"
    return "a finite number"


def parse_def(text: str) -> dict[str, dict]:
    """Every key of the .def by path: kind (N, O, T), type, unit, default (the value, or None
    where the key has none), default_text, and for N and O min, max, bounds and requirement."""
    match = BODY.search(text)
    if not match:
        raise ValueError("no #define CDRO_SCENARIO_KEYS(N, O, T)")
    body = match.group(1).replace("\\\n", "\n")
    keys: dict[str, dict] = {}
    for entry in ENTRY.finditer(body):
        shape, at = entry.group(1), entry.end()
        args = []
        while True:
            arg = ARG.match(body, at)
            if not arg:
                start = entry.start()
                raise ValueError(f"{shape}(...) at {body[start:start + 60]!r}: does not follow the grammar")
            quoted, token, end = arg.groups()
            args.append(("s", quoted.replace('\\"', '"')) if quoted is not None else ("t", token))
            at = arg.end()
            if end == ")":
                break
        kinds = "".join(kind for kind, _ in args)
        values = [value for _, value in args]
        where = f"{shape}({values[1] if len(values) > 1 else '?'})"
        if kinds != SHAPES[shape]:
            raise ValueError(f"{where}: arguments {values}, expected the shape {SHAPES[shape]}")
        kind, path = values[0], values[1]
        if kind not in TYPES[shape]:
            raise ValueError(f"{where}: type {kind} is not one of {', '.join(TYPES[shape])}")
        if path in keys:
            raise ValueError(f"{where}: defined twice")
        if shape == "T":
            _, _, default_text, tool, meaning = values
            spec = {"kind": "T", "type": kind, "unit": "", "default_text": default_text,
                    "default": yaml.safe_load(default_text) if kind in ("BOOL", "ENUM") else None}
        else:
            unit, default, low, high, bounds, tool, meaning = values[2:]
            if bounds not in BOUNDS:
                raise ValueError(f"{where}: bounds {bounds} is not one of {', '.join(BOUNDS)}")
            spec = {"kind": shape, "type": kind, "unit": unit, "min": _number(low, where), "max": _number(high, where),
                    "min_text": low, "max_text": high, "bounds": bounds}
            if not spec["min"] < spec["max"]:
                raise ValueError(f"{where}: empty range {low}..{high}")
            if shape == "N":
                spec["default"] = _number(default, where)
                spec["default_text"] = default
                if kind == "REAL":
                    spec["default"] = float(spec["default"])
                if not _inside(spec["default"], spec):
                    raise ValueError(f"{where}: default {default} outside its own range")
            else:
                spec["default_text"] = default
                spec["default"] = yaml.safe_load(default) if kind == "PAIR" and default.startswith("[") else None
            spec["requirement"] = requirement(spec)
        if tool not in TOOLS:
            raise ValueError(f"{where}: tool {tool} is not one of {', '.join(TOOLS)}")
        spec["tool"] = TOOLS[tool]
        spec["meaning"] = meaning
        keys[path] = spec
    if not keys:
        raise ValueError("CDRO_SCENARIO_KEYS has no entries")
    return keys


def parse_renamed(text: str) -> dict[str, str]:
    """The earlier spellings of keys (path, list entries written []) and what they are called now."""
    match = RENAMED_BODY.search(text)
    if not match:
        raise ValueError("no #define CDRO_SCENARIO_RENAMED_KEYS(R)")
    body = match.group(1)
    renamed = dict(RENAME.findall(body))
    if len(renamed) != len(re.findall(r"\bR\(", body)):
        raise ValueError("CDRO_SCENARIO_RENAMED_KEYS: an entry does not follow the grammar, or is listed twice")
    return renamed


def _inside(value: float, spec: dict) -> bool:
    low_open, high_open = BOUNDS[spec["bounds"]]
    above = value > spec["min"] if low_open else value >= spec["min"]
    below = value < spec["max"] if high_open else value <= spec["max"]
    return above and below


def generate(def_path: pathlib.Path) -> str:
    text = def_path.read_text()
    keys, renamed = parse_def(text), parse_renamed(text)
    lines = [
        '"""GENERATED by cdro_tools.scenario_codegen from sim/scenario_keys.def. Do not edit."""',
        "",
        "inf = float(\"inf\")",
        "",
        f"KEYS = {pprint.pformat(keys, sort_dicts=False, width=100)}",
        "",
        f"RENAMED = {pprint.pformat(renamed, sort_dicts=False, width=100)}",
        "",
    ]
    return "\n".join(lines)


DOC_BEGIN = ("<!-- BEGIN GENERATED SCENARIO KEYS "
             "(python -m cdro_tools.scenario_codegen sim/scenario_keys.def --docs docs/tools.md) -->")
DOC_END = "<!-- END GENERATED SCENARIO KEYS -->"


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def docs_table(def_path: pathlib.Path) -> str:
    """The Markdown table of every key (tool, type, default, valid values, meaning), then the
    earlier spellings and what they are called now."""
    text = def_path.read_text()
    keys, renamed = parse_def(text), parse_renamed(text)
    rows = [DOC_BEGIN, "", "| Key | Tool | Type | Default | Valid | Meaning |", "|---|---|---|---|---|---|"]
    for path, spec in keys.items():
        default = spec["default_text"]
        if spec["kind"] == "N" and spec["unit"]:
            default = f"{default} {spec['unit']}"
        valid = spec.get("requirement", "-")
        if spec["type"] == "LIST" and "requirement" in spec:
            valid = f"{valid} entries"
        elif spec["type"] in ("PAIR", "POINTS"):
            valid = f"each {valid}"
        rows.append(f"| `{path}` | {spec['tool']} | {spec['type'].lower()} | {_cell(default)} | {_cell(valid)} | "
                    f"{_cell(spec['meaning'])} |")
    rows += ["", "| Earlier spelling | Now called |", "|---|---|"]
    rows += [f"| `{old}` | {_cell(now)} |" for old, now in renamed.items()]
    rows += ["", DOC_END]
    return "\n".join(rows)


def update_docs(def_path: pathlib.Path, doc_path: pathlib.Path) -> bool:
    """Rewrites the generated section of doc_path; returns True if it changed."""
    return replace_generated_section(doc_path, docs_table(def_path), DOC_BEGIN, DOC_END)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("def_path", type=pathlib.Path, help="sim/scenario_keys.def")
    parser.add_argument("--docs", type=pathlib.Path, help="rewrite the generated table in this markdown file instead")
    args = parser.parse_args(argv)
    if args.docs:
        update_docs(args.def_path, args.docs)
    else:
        sys.stdout.write(generate(args.def_path))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
