"""Reads docs/outputs.schema.json, the one definition of cdro-hostd's JSON objects, and writes
the key tables of docs/outputs.md from it.

    python -m cdro_tools.outputs_schema docs/outputs.schema.json --docs docs/outputs.md

Only the standard library: validating against the schema (tests/hostd/test_output_schema.py)
uses the jsonschema package, a development dependency; reading its key lists does not.
"""
from __future__ import annotations

import argparse
import json
import pathlib

from cdro_tools.codegen import replace_generated_section

DOC_BEGIN = ("<!-- BEGIN GENERATED KEY TABLES "
             "(python -m cdro_tools.outputs_schema docs/outputs.schema.json --docs docs/outputs.md) -->")
DOC_END = "<!-- END GENERATED KEY TABLES -->"

# The objects of the docs, in the order they are documented: (definition, heading).
DOCUMENTED = [
    ("node", "`node` line"),
    ("robot", "`robot` line"),
    ("health", "`health` line"),
    ("rates", "`rates` of a health line"),
    ("map", "`/api/map` (and `/api/events` map events)"),
    ("map_node", "node object of `/api/map`"),
    ("map_link", "link object of `/api/map`"),
    ("components", "`/api/nodes/<id>/components`"),
    ("component", "component object"),
    ("floor_plan", "`/api/floor-plan`"),
]
# Objects documented as another documented object plus keys of their own.
EXTENDS = {"map_node": "`node` line"}


def load(path: str | pathlib.Path) -> dict:
    return json.loads(pathlib.Path(path).read_text())


def _definition(schema: dict, ref: str) -> tuple[str, dict]:
    prefix = "#/$defs/"
    if not ref.startswith(prefix):
        raise ValueError(f"{ref}: only local definitions are used")
    name = ref[len(prefix):]
    return name, schema["$defs"][name]


def properties(schema: dict, name: str) -> dict[str, dict]:
    """Every key of definition `name`, in the order the writers write them: the keys of the
    definition it builds on ($ref) first, then its own."""
    definition = schema["$defs"][name]
    keys: dict[str, dict] = {}
    if "$ref" in definition:
        keys.update(properties(schema, _definition(schema, definition["$ref"])[0]))
    keys.update(definition.get("properties", {}))
    return keys


def _type_text(schema: dict, spec: dict) -> str:
    if "const" in spec:
        return json.dumps(spec["const"])
    if "enum" in spec:
        return " or ".join(json.dumps(value) for value in spec["enum"])
    if "$ref" in spec:
        name, definition = _definition(schema, spec["$ref"])
        if "const" in definition or "pattern" in definition or definition.get("type") == "integer":
            return _type_text(schema, definition)
        return f"{name} object"
    if "oneOf" in spec:
        return " or ".join(_type_text(schema, option) for option in spec["oneOf"])
    kinds = spec.get("type", "any")
    kinds = kinds if isinstance(kinds, list) else [kinds]
    text = " or ".join(kinds)
    if "array" in kinds and "items" in spec:
        text = f"array of {_type_text(schema, spec['items'])}"
    if "pattern" in spec:
        text = 'string "0x...."' if spec["pattern"] == "^0x[0-9A-F]{4}$" else f"string ({spec['pattern']})"
    if "minimum" in spec and "maximum" in spec:
        text += f" {spec['minimum']}..{spec['maximum']}"
    elif "minimum" in spec:
        text += f" >= {spec['minimum']}"
    return text


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def key_tables(schema: dict) -> str:
    """Markdown: for each documented object, its keys in order with type, unit and meaning."""
    out = [DOC_BEGIN, ""]
    for name, heading in DOCUMENTED:
        definition = schema["$defs"][name]
        out += [f"#### {heading}", ""]
        if "description" in definition:
            out += [definition["description"], ""]
        if name in EXTENDS:
            out += [f"All keys of the {EXTENDS[name]}, then:", ""]
            keys = definition["properties"]
        else:
            keys = properties(schema, name)
        out += ["| Key | Type | Unit | Since | Meaning |", "|---|---|---|---|---|"]
        for key, spec in keys.items():
            out.append(f"| `{key}` | {_cell(_type_text(schema, spec))} | {_cell(spec.get('x-unit', '')) or '-'} | "
                       f"{spec.get('x-since', 1)} | {_cell(spec.get('description', ''))} |")
        out.append("")
    out.append(DOC_END)
    return "\n".join(out)


def update_docs(schema_path: pathlib.Path, doc_path: pathlib.Path) -> bool:
    """Rewrites the generated section of doc_path; returns True if it changed."""
    return replace_generated_section(doc_path, key_tables(load(schema_path)), DOC_BEGIN, DOC_END)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("schema", type=pathlib.Path, help="docs/outputs.schema.json")
    parser.add_argument("--docs", type=pathlib.Path, required=True, help="rewrite the generated tables in this file")
    args = parser.parse_args(argv)
    update_docs(args.schema, args.docs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
