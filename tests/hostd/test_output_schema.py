"""docs/outputs.schema.json is the one definition of cdro-hostd's JSON objects, and everyone
follows it: every line cdro-hostd writes (a replay with a robot, a live run on the simulated
device) and every live-map object it serves validates against it, with the keys in the order
the schema lists them; the live map's page (web/app.js) and cdro-plot read only keys it
defines; docs/outputs.md's key tables are generated from it. MQTT payloads are the same
objects as the lines (map_state.cpp writes both). Timeouts are deadlock guards only."""
from __future__ import annotations

import ast
import json
import os
import re
import socket
import struct
import subprocess
import sys
import time
import urllib.error
import urllib.request
import zlib

import jsonschema
import pytest

from cdro_tools import outputs_schema
from robot_capture import ROBOT, write_robot_capture

GUARD_S = 300.0


@pytest.fixture(scope="module")
def schema(repo_root) -> dict:
    return outputs_schema.load(repo_root / "docs" / "outputs.schema.json")


def validator(schema: dict, definition: str | None = None) -> jsonschema.Draft202012Validator:
    """Validates against the whole schema (a JSON Lines line) or one of its definitions."""
    target = schema if definition is None else {**schema, "$ref": f"#/$defs/{definition}"}
    if definition is not None:
        target = {key: value for key, value in target.items() if key != "oneOf"}
    return jsonschema.Draft202012Validator(target)


def check(schema: dict, obj, definition: str | None = None, where: str = "") -> None:
    errors = sorted(validator(schema, definition).iter_errors(obj), key=lambda e: list(e.path))
    assert not errors, f"{where}: {obj}\n" + "\n".join(f"{list(e.path)}: {e.message}" for e in errors[:5])


def check_order(schema: dict, obj: dict, definition: str, where: str = "") -> None:
    """The writers write the keys in the schema's order (so the schema describes the bytes): every
    key, but those marked x-optional (written only on some objects: a 3D track's var_z_m2)."""
    keys = outputs_schema.properties(schema, definition)
    expected = [key for key, spec in keys.items() if key in obj or not spec.get("x-optional")]
    assert list(obj) == expected, f"{where}: {list(obj)}"


def check_line(schema: dict, line: dict, where: str) -> None:
    check(schema, line, where=where)
    check_order(schema, line, line["type"], where)


# ---- the schema itself and the docs ----------------------------------------------------------

def test_the_schema_is_a_valid_draft_2020_12_schema(schema):
    jsonschema.Draft202012Validator.check_schema(schema)
    for name, definition in schema["$defs"].items():
        keys = definition.get("properties", {})
        always = {key for key, spec in keys.items() if not spec.get("x-optional")}
        assert set(definition.get("required", [])) == always, f"{name}: every key not x-optional is always written"


def test_docs_key_tables_are_generated_from_the_schema(repo_root, schema):
    text = (repo_root / "docs" / "outputs.md").read_text()
    begin = text.index(outputs_schema.DOC_BEGIN)
    end = text.index(outputs_schema.DOC_END) + len(outputs_schema.DOC_END)
    assert text[begin:end] == outputs_schema.key_tables(schema), (
        "docs/outputs.md is stale: run "
        "`.venv/bin/python -m cdro_tools.outputs_schema docs/outputs.schema.json --docs docs/outputs.md`")


def test_the_documented_examples_follow_the_schema(repo_root, schema):
    text = (repo_root / "docs" / "outputs.md").read_text()
    examples = [json.loads(line) for line in text.splitlines() if line.startswith('{"type":')]
    assert {line["type"] for line in examples} == {"node", "robot"}
    for line in examples:
        check_line(schema, line, "docs/outputs.md example")


# ---- the readers -------------------------------------------------------------------------------

# web/app.js names each object the same way everywhere; a member read on one of these names is a
# key of that definition (JavaScript's own members, like toFixed, are on numbers, not on these).
APP_JS_NAMES = {
    "n": "map_node", "a": "map_node", "b": "map_node", "l": "map_link", "p": "map_link", "q": "map_link",
    "map.robot": "robot", "r": "robot", "h": "health", "c": "component", "selectedComponents": "components",
    "f": "floor_plan", "floorPlan": "floor_plan", "map": "map",
}
APP_JS_READ = re.compile(r"(?<![\w.])(" + "|".join(sorted(map(re.escape, APP_JS_NAMES), key=len, reverse=True))
                         + r")(?:\?)?\.([A-Za-z_]\w*)\b(?!\s*\()")


def test_the_live_map_page_reads_only_keys_of_the_schema(repo_root, schema):
    source = (repo_root / "host" / "service" / "web" / "app.js").read_text()
    reads = {(name, key) for name, key in APP_JS_READ.findall(source) if f"{name}.{key}" not in APP_JS_NAMES}
    unknown = sorted(f"{name}.{key}" for name, key in reads
                     if key not in outputs_schema.properties(schema, APP_JS_NAMES[name]))
    assert not unknown, f"web/app.js reads keys docs/outputs.schema.json does not define: {unknown}"
    # The check has teeth: it sees the keys the page is known to read.
    assert {("n", "var_x_m2"), ("l", "residual_m"), ("h", "counters"), ("f", "metres_per_pixel"),
            ("map", "t_unix_s"), ("c", "weight")} <= reads


def test_cdro_plot_reads_only_keys_of_the_schema(repo_root, schema):
    tree = ast.parse((repo_root / "tools" / "cdro_tools" / "plot.py").read_text())
    reader = next(node for node in ast.walk(tree) if isinstance(node, ast.FunctionDef)
                  and node.name == "read_json_lines")
    keys = set()
    for node in ast.walk(reader):
        if isinstance(node, ast.Subscript) and isinstance(node.value, ast.Name) and node.value.id == "obj":
            if isinstance(node.slice, ast.Constant):
                keys.add(node.slice.value)
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "get"
              and isinstance(node.func.value, ast.Name) and node.func.value.id == "obj"):
            keys.add(node.args[0].value)
        elif isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "keys" for t in node.targets):
            keys.update(element.value for element in node.value.elts)   # obj[k] for k in keys
    # plot.py reads node and robot lines (and skips health lines by their type)
    defined = set(outputs_schema.properties(schema, "node")) | set(outputs_schema.properties(schema, "robot"))
    assert keys and not keys - defined, f"plot.py reads keys docs/outputs.schema.json does not define: {keys - defined}"
    assert {"t_s", "x_m", "var_x_m2", "placed", "frame"} <= keys


# ---- what cdro-hostd writes ------------------------------------------------------------------

@pytest.fixture(scope="module")
def robot_capture(tmp_path_factory):
    """plaza-like for 120 s: its capture with the odometry records put in their place."""
    path, _ = write_robot_capture(tmp_path_factory.mktemp("schema"), GUARD_S)
    return path


def test_every_line_of_a_replay_with_a_robot_follows_the_schema(build_dir, schema, robot_capture):
    result = subprocess.run([str(build_dir / "bin" / "cdro-hostd"), "--replay", str(robot_capture), "--speed", "max",
                             "--set", f"movement.robot_id={ROBOT:#06x}"], capture_output=True, text=True,
                            timeout=GUARD_S)
    assert result.returncode == 0, result.stderr
    lines = [json.loads(text) for text in result.stdout.splitlines() if text.strip()]
    for number, line in enumerate(lines, 1):
        check_line(schema, line, f"replay line {number}")
    kinds = {line["type"] for line in lines}
    assert kinds == {"node", "robot", "health"}, kinds
    assert any(line["placed"] for line in lines if line["type"] == "node")
    assert any(not line["placed"] for line in lines if line["type"] == "node")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def get_json(port: int, path: str):
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=5) as response:
            return json.loads(response.read())
    except (urllib.error.URLError, ConnectionError, json.JSONDecodeError):
        return None


def first_event(port: int) -> dict:
    """The data of the first `map` event of /api/events."""
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/events", timeout=10) as response:
        event = None
        for raw in response:
            text = raw.decode().rstrip("\n")
            if text.startswith("event: "):
                event = text[len("event: "):]
            elif text.startswith("data: ") and event == "map":
                return json.loads(text[len("data: "):])
    raise AssertionError("no map event")


def tiny_png(path, width_px: int, height_px: int) -> None:
    """A grey image, written by hand: the schema test needs no imaging library."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    rows = b"".join(b"\x00" + b"\x80" * width_px for _ in range(height_px))
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width_px, height_px, 8, 0, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))


def test_a_live_run_writes_and_serves_only_objects_of_the_schema(build_dir, schema, tmp_path):
    hostd_bin = build_dir / "bin" / "cdro-hostd"
    seed = int(os.environ.get("CDRO_TEST_SEED", "1"))
    print(f"cdro-sim demo, seed {seed} (set CDRO_TEST_SEED to change it)")
    tiny_png(tmp_path / "plan.png", 40, 30)
    link, port, lines_path = tmp_path / "tty", free_port(), tmp_path / "lines.jsonl"
    config = tmp_path / "hostd.yaml"
    config.write_text(f"""
serial: {{device: {link}, reconnect_min_s: 0.05, reconnect_max_s: 0.4, hello_timeout_s: 0.3, hello_retries: 20}}
nodes: {{ids: [], unknown: reject}}
capture: {{path: ''}}
output: {{jsonl: {lines_path}}}
http: {{port: {port}, update_period_s: 0.1}}
checkpoint: {{path: ''}}
web: {{floor_plan: {{path: {tmp_path / 'plan.png'}, metres_per_pixel: 0.5, origin_x_m: -2.0, origin_y_m: -1.0}}}}
""")
    logs = [open(tmp_path / "sim.log", "w"), open(tmp_path / "hostd.log", "w")]
    sim = subprocess.Popen([sys.executable, "-m", "cdro_tools.sim", "--scenario", "demo", "--seed", str(seed), "--pty",
                            str(link), "--speed", "4", "--duration", "24", "--hold"], stdout=logs[0], stderr=logs[0])
    hostd = None
    try:
        deadline = time.monotonic() + GUARD_S
        while not link.is_symlink():
            assert time.monotonic() < deadline and sim.poll() is None, (tmp_path / "sim.log").read_text()
            time.sleep(0.05)
        hostd = subprocess.Popen([str(hostd_bin), "--config", str(config)], stdout=subprocess.DEVNULL, stderr=logs[1])
        snapshot = None
        while snapshot is None or len([n for n in snapshot["nodes"] if n["placed"]]) < 4:
            assert hostd.poll() is None, (tmp_path / "hostd.log").read_text()
            assert time.monotonic() < deadline, "no map:\n" + (tmp_path / "hostd.log").read_text()
            time.sleep(0.2)
            snapshot = get_json(port, "/api/map")

        check(schema, snapshot, "map", "/api/map")
        check_order(schema, snapshot, "map", "/api/map")
        for node in snapshot["nodes"]:
            check_order(schema, node, "map_node", "/api/map node")
        for link_object in snapshot["links"]:
            check_order(schema, link_object, "map_link", "/api/map link")
        assert snapshot["links"] and snapshot["health"]["link"] == "connected"
        health = get_json(port, "/api/health")
        check(schema, health, "health", "/api/health")
        check_order(schema, health, "health", "/api/health")
        placed = next(n for n in snapshot["nodes"] if n["placed"])
        components = get_json(port, f"/api/nodes/{placed['id']}/components")
        check(schema, components, "components", "components")
        check_order(schema, components, "components", "components")
        assert components["components"]
        for component in components["components"]:
            check_order(schema, component, "component", "component")
        plan = get_json(port, "/api/floor-plan")
        check(schema, plan, "floor_plan", "/api/floor-plan")
        check_order(schema, plan, "floor_plan", "/api/floor-plan")
        assert (plan["width_px"], plan["height_px"]) == (40, 30)
        event = first_event(port)
        check(schema, event, "map", "/api/events")
    finally:
        for process in (hostd, sim):
            if process is not None and process.poll() is None:
                process.terminate()
                process.wait(timeout=GUARD_S)
        for log in logs:
            log.close()

    lines = [json.loads(text) for text in lines_path.read_text().splitlines() if text.strip()]
    for number, line in enumerate(lines, 1):
        check_line(schema, line, f"live line {number}")
    assert {line["type"] for line in lines} == {"node", "health"}
