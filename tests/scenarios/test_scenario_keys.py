"""The scenario keys are defined once (sim/scenario_keys.def): cdro-sim's table and docs/tools.md's
are generated from it and current, and both readers hold every key to the same range, refusing a
value just outside it in the same words and naming the key."""
from __future__ import annotations

import copy
import math
import pathlib
import subprocess

import pytest
import yaml

from cdro_tools import scenario_codegen
from cdro_tools.codec import CONSTANTS as C
from cdro_tools.simulation import scenario_keys
from cdro_tools.simulation.scenario import FAULT_KINDS, FIL_FAULT_KINDS, KEYS, ScenarioError, load_scenario

REPO = pathlib.Path(__file__).resolve().parents[2]
DEF = REPO / "sim" / "scenario_keys.def"
A, B = 0x6000, 0x6A01
BASE = {"own_id": A, "duration_s": 10, "nodes": [{"id": A, "x_m": 0, "y_m": 0}, {"id": B, "x_m": 4, "y_m": 0}]}
# The fault kind that takes each fault key, per tool (faults[].at_s and duration_s: both, each its own kind).
SIM_FAULT = {"bytes": {"kind": "garbage"}, "frames": {"kind": "bit_flip"}, "duration_s": {"kind": "vanish"},
             "at_s": {"kind": "garbage"}}
FIL_FAULT = {"count": {"kind": "nack_address"}, "error_code": {"kind": "error_completion"},
             "node": {"kind": "power_off", "duration_s": 1}, "duration_s": {"kind": "power_off", "node": B},
             "at_s": {"kind": "nack_address"}}
# In-range values where the lowest one would break another rule (0 s: cdro-sim needs a duration; a
# stretch over 2 m ending at 1e6 s is slower than any speed; ids must be among the nodes).
VALID = {"duration_s": 1, "motion[].end_s": 3, "motion[].node": B, "robot.id": A, "faults[].node": B, "own_id": A}


def test_committed_scenario_keys_are_up_to_date():
    committed = (REPO / "tools" / "cdro_tools" / "simulation" / "scenario_keys.py").read_text()
    assert committed == scenario_codegen.generate(DEF), (
        "tools/cdro_tools/simulation/scenario_keys.py is stale: run `.venv/bin/python -m cdro_tools.scenario_codegen "
        "sim/scenario_keys.def > tools/cdro_tools/simulation/scenario_keys.py`")
    assert scenario_keys.KEYS is KEYS  # the reader uses the generated table


def test_docs_table_is_up_to_date():
    text = (REPO / "docs" / "tools.md").read_text()
    begin = text.index(scenario_codegen.DOC_BEGIN)
    end = text.index(scenario_codegen.DOC_END) + len(scenario_codegen.DOC_END)
    assert text[begin:end] == scenario_codegen.docs_table(DEF), (
        "docs/tools.md is stale: run `.venv/bin/python -m cdro_tools.scenario_codegen sim/scenario_keys.def "
        "--docs docs/tools.md`")


def test_a_malformed_entry_is_refused_naming_it():
    good = 'N(REAL, "uwb.noise_std_m", "m", 0.1, 0, 10, CLOSED, BOTH, "noise")'
    for bad, words in [(good.replace("CLOSED", "SHUT"), "bounds SHUT"), (good.replace("0.1,", "11,"), "default 11"),
                       (good.replace("REAL", "TEXT"), "type TEXT"), (good.replace(", 10,", ", 0,"), "empty range"),
                       (good.replace('"m", ', ""), "expected the shape")]:
        with pytest.raises(ValueError, match=words):
            scenario_codegen.parse_def(f"#define CDRO_SCENARIO_KEYS(N, O, T) \\\n    {bad}\n")
    assert scenario_codegen.parse_def(f"#define CDRO_SCENARIO_KEYS(N, O, T) \\\n    {good}\n")["uwb.noise_std_m"][
        "requirement"] == "in [0, 10] m"


def test_the_node_count_is_the_firmwares():
    assert KEYS["nodes"]["max"] == C["CDRO_MAX_NODES"] + 1  # the own node and the remote ones it schedules


def document(path: str, value, tool: str) -> dict:
    """BASE with the key at `path` set to value, inside whatever the key needs around it."""
    doc = copy.deepcopy(BASE)
    *parents, leaf = path.split(".")
    if path == "nodes":
        doc["nodes"] = [{"id": i + 1, "x_m": float(i), "y_m": 0} for i in range(value)]
        doc["own_id"] = 1
        return doc
    if parents[:1] == ["nodes[]"]:
        doc["nodes"][1][leaf] = value
    elif parents[:1] == ["motion[]"]:
        stretch = {"node": B, "start_s": 1, "speed_mps": 1, "waypoints_m": [[4, 2]]}
        if leaf == "end_s":
            del stretch["speed_mps"]
        stretch[leaf] = [[value, 2]] if leaf == "waypoints_m" else value
        doc["motion"] = [stretch]
    elif parents[:1] == ["faults[]"]:
        fault = dict((SIM_FAULT if tool == "cdro-sim" else FIL_FAULT)[leaf], at_s=1)
        fault[leaf] = value
        doc["faults"] = [fault]
    elif parents[:1] == ["robot"]:
        robot = {"id": A, "waypoints_m": [[2, 2]]}
        target = robot.setdefault("odometry", {}) if parents[1:] == ["odometry"] else robot
        target[leaf] = [[value, 2]] if leaf == "waypoints_m" else value
        doc["robot"] = robot
    else:
        target = doc
        for parent in parents:
            target = target.setdefault(parent, {})
        target[leaf] = value
    return doc


def shown(path: str) -> str:
    """How both readers name the key in the document above: its path with the list index."""
    return path.replace("nodes[]", "nodes[1]").replace("motion[]", "motion[0]").replace("faults[]", "faults[0]")


def outside(spec: dict) -> list:
    """Values just outside the key's range: the bound itself where it is open, else one past it."""
    values = []
    open_low, open_high = spec["bounds"] in ("OPEN_MIN", "OPEN"), spec["bounds"] in ("OPEN_MAX", "OPEN")
    if math.isfinite(spec["min"]):
        values.append(spec["min"] if open_low else spec["min"] - 1)
    if math.isfinite(spec["max"]):
        values.append(spec["max"] if open_high else spec["max"] + 1)
    return values


def inside(path: str, spec: dict):
    if path in VALID:
        return VALID[path]
    low, high = spec["min"], spec["max"]
    if spec["bounds"] in ("CLOSED", "OPEN_MAX") and math.isfinite(low):
        return low
    return low + 1 if math.isfinite(low) and low + 1 < high else (low + high) / 2


def as_given(path: str, spec: dict, value):
    """The value as a file writes it: [value, 0.5] for a pair (each element is checked)."""
    if spec["type"] == "PAIR":
        return [value, max(value, 0.5)] if value <= spec["min"] else [min(0.5, value), value]
    if spec["type"] == "LIST":
        return int(value)
    return value


RANGED = [path for path, spec in KEYS.items()
          if "requirement" in spec and (math.isfinite(spec["min"]) or math.isfinite(spec["max"]))]


def sim_read(path: pathlib.Path) -> str:
    """cdro-sim's reader on the file: "" if it reads it, else its message."""
    try:
        load_scenario(str(path))
    except ScenarioError as error:
        return str(error)
    return ""


def fil_read(binary: pathlib.Path, path: pathlib.Path) -> str:
    done = subprocess.run([str(binary), "--print-scenario", "--scenario", str(path)], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode in (0, 2), done.stderr
    return done.stderr if done.returncode else ""


@pytest.mark.parametrize("path", RANGED)
def test_both_tools_refuse_a_value_just_outside_the_range_naming_the_key(fil_binary, tmp_path, path):
    spec = KEYS[path]
    tools = {"cdro-sim": sim_read, "cdro-fil": lambda p: fil_read(fil_binary, p)}
    acting = [tool for tool in tools if spec["tool"] in ("both", tool)]
    file = tmp_path / "scenario.yaml"
    for tool in acting:  # the same file with a value inside the range reads: the refusals below are the range's
        file.write_text(yaml.safe_dump(document(path, as_given(path, spec, inside(path, spec)), tool)))
        assert tools[tool](file) == "", f"{tool} refuses an in-range {path}"
    for value in outside(spec):
        given = as_given(path, spec, value)
        for tool, read in tools.items():
            if path.startswith("faults[]") and tool not in acting:
                continue  # the other tool's fault kinds are refused as such (test_scenario_format.py)
            file.write_text(yaml.safe_dump(document(path, given, tool if tool in acting else acting[0])))
            message = read(file)
            if tool not in acting:
                assert f"only {acting[0]} supports" in message, message
                continue
            words = f"the number of entries must be {spec['requirement']}" if spec["type"] == "LIST" \
                else f"must be {spec['requirement']}"
            if path == "seed" and value > spec["max"] and tool == "cdro-fil":
                words = "expected an integer"  # beyond int64: yaml-cpp cannot read it as an integer at all
            assert shown(path) in message and words in message, f"{tool}, {path} = {given}: {message!r}"


def test_the_fault_kinds_the_table_names_are_each_tools():
    """faults[].kind's meaning lists each tool's kinds; the kinds themselves are each reader's code."""
    sim_part, fil_part = KEYS["faults[].kind"]["meaning"].split("; cdro-fil's: ")
    named = [part.split(" (")[0].split(", ") for part in (sim_part.removeprefix("cdro-sim's: "), fil_part)]
    assert named == [list(FAULT_KINDS), list(FIL_FAULT_KINDS)]
