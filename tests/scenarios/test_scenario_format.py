"""One scenario format for cdro-sim (Python) and cdro-fil (C++): both read every scenario file of
the repository alike, or one of them refuses it naming the tool that supports what it cannot act
on; an earlier spelling is refused by both with the name it has now (docs/tools.md, "Scenario
files")."""
from __future__ import annotations

import json
import math
import pathlib
import subprocess
import sys

import pytest

from cdro_tools.simulation.scenario import (FAULT_KINDS, FIL_FAULT_KINDS, KEYS, ScenarioError, from_shared_view,
                                            parse_scenario, shared_view)

REPO = pathlib.Path(__file__).resolve().parents[2]
SHARED = REPO / "tests" / "scenarios" / "shared_office.yaml"
SCENARIO_FILES = sorted([*(REPO / "tools" / "cdro_tools" / "scenarios").glob("*.yaml"),
                         *(REPO / "tests" / "fil").glob("*.yaml"),
                         *(REPO / "tests" / "scenarios").glob("*.yaml")])
MINIMAL = "own_id: 0x6000\nduration_s: 10\nnodes:\n  - {id: 0x6000, x_m: 0, y_m: 0}\n  - {id: 0x6A01, x_m: 4, y_m: 0}\n"


def fil_view(binary: pathlib.Path, path: pathlib.Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(binary), "--print-scenario", "--scenario", str(path)], capture_output=True, text=True,
                          timeout=60)


def sim_view(path: pathlib.Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cdro_tools.sim", "--print-scenario", "--scenario", str(path)],
                          capture_output=True, text=True, timeout=60)


def assert_same(a, b, where: str = "") -> None:
    """Equal structure and values; numbers to 1e-9 (the two print their doubles each its own way)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and list(a) == list(b), (where, a, b)
        for key in a:
            assert_same(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), (where, a, b)
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{where}[{i}]")
    elif isinstance(a, bool) or isinstance(a, str):
        assert a == b, (where, a, b)
    else:
        assert math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-9), (where, a, b)


def test_that_both_read_the_shared_scenario_alike(fil_binary):
    fil, sim = fil_view(fil_binary, SHARED), sim_view(SHARED)
    assert fil.returncode == 0, fil.stderr
    assert sim.returncode == 0, sim.stderr
    fil_json, sim_json = json.loads(fil.stdout), json.loads(sim.stdout)
    assert_same(fil_json, sim_json)
    # What the file says, so that two readers that agree on something else fail here.
    assert (sim_json["name"], sim_json["seed"], sim_json["duration_s"], sim_json["own_id"]) == \
        ("shared-office", 4242, 40.0, 0x6000)
    assert [(n["id"], n["accelerometer"]) for n in sim_json["nodes"]] == \
        [(0x6000, True), (0x6A01, False), (0x6A02, False), (0x6A03, False), (0x6B04, True), (0x6B05, True)]
    assert sim_json["nodes"][5]["z_m"] == 0.0 and sim_json["nodes"][1]["x_m"] == 7.5
    first, second, third = sim_json["motion"]
    assert first["end_s"] == pytest.approx(10 + 5.0 / 1.2)                # 3 m + 2 m at 1.2 m/s
    assert second["speed_mps"] == pytest.approx(1.0)                       # 3 m + 1 m in 4 s
    assert third["speed_mps"] == pytest.approx(math.hypot(3, 2) / 5.0)     # from where the first one ended
    assert third["waypoints_m"] == [[3.0, 3.0, 1.1]]                       # the height the node keeps
    assert sim_json["uwb"] == {"noise_std_m": 0.05, "max_range_m": 30.0}
    assert sim_json["accelerometer"]["noise_std_mg"] == 6.0 and sim_json["pozyx"] == {"firmware_version": 0x12}


# Only the required keys: every default of the keys both tools read applies.
BARE = "own_id: 0x6000\nnodes:\n  - {id: 0x6000, x_m: 0, y_m: 0}\n  - {id: 0x6A01, x_m: 4, y_m: 0}\n"


def documented_defaults() -> dict[str, float]:
    """The defaults sim/scenario_keys.def gives the numeric keys both tools read (docs/tools.md's
    table is generated from it: tests/scenarios/test_scenario_keys.py)."""
    out = {key: KEYS[key]["default"] for key in ("duration_s", "seed", "uwb.noise_std_m", "uwb.max_range_m",
                                                  "pozyx.firmware_version", "accelerometer.noise_std_mg",
                                                  "accelerometer.moving_amplitude_mg",
                                                  "accelerometer.moving_frequency_hz")}
    assert all(KEYS[key]["tool"] == "both" for key in out), out
    return out


def test_that_both_tools_give_a_key_left_out_the_documented_default(fil_binary, tmp_path):
    path = tmp_path / "bare-office.yaml"
    path.write_text(BARE)
    fil, sim = fil_view(fil_binary, path), sim_view(path)
    assert fil.returncode == 0, fil.stderr
    assert sim.returncode == 0, sim.stderr
    fil_json, sim_json = json.loads(fil.stdout), json.loads(sim.stdout)
    assert_same(fil_json, sim_json)
    # The one definition of the keys, so that both tools moving together fail too.
    docs = documented_defaults()
    assert_same(sim_json, {
        "name": "bare-office", "seed": docs["seed"], "duration_s": docs["duration_s"], "own_id": 0x6000,
        "nodes": [{"id": 0x6000, "x_m": 0.0, "y_m": 0.0, "z_m": 0.0, "accelerometer": False},
                  {"id": 0x6A01, "x_m": 4.0, "y_m": 0.0, "z_m": 0.0, "accelerometer": False}],
        "motion": [],
        "uwb": {"noise_std_m": docs["uwb.noise_std_m"], "max_range_m": docs["uwb.max_range_m"]},
        "accelerometer": {k: docs[f"accelerometer.{k}"]
                          for k in ("noise_std_mg", "moving_amplitude_mg", "moving_frequency_hz")},
        "pozyx": {"firmware_version": docs["pozyx.firmware_version"]},
    })
    assert (docs["duration_s"], docs["uwb.noise_std_m"], docs["pozyx.firmware_version"]) == (60.0, 0.1, 0x11)


def test_that_a_view_read_back_is_the_same_scenario(fil_binary):
    # fil_support builds the world model of a cdro-fil run from this view (from_shared_view).
    view = json.loads(fil_view(fil_binary, SHARED).stdout)
    assert_same(shared_view(from_shared_view(view, "view")), view)


def test_that_a_seed_and_duration_given_on_the_command_line_reach_both_views(fil_binary):
    fil = subprocess.run([str(fil_binary), "--print-scenario", "--scenario", str(SHARED), "--seed", "7",
                          "--duration-s", "12"], capture_output=True, text=True, timeout=60)
    sim = subprocess.run([sys.executable, "-m", "cdro_tools.sim", "--print-scenario", "--scenario", str(SHARED),
                          "--seed", "7", "--duration", "12"], capture_output=True, text=True, timeout=60)
    assert fil.returncode == 0 and sim.returncode == 0, fil.stderr + sim.stderr
    for view in (json.loads(fil.stdout), json.loads(sim.stdout)):
        assert (view["seed"], view["duration_s"]) == (7, 12.0)


@pytest.mark.parametrize("path", SCENARIO_FILES, ids=lambda p: str(p.relative_to(REPO)))
def test_that_every_scenario_file_is_read_alike_or_refused_naming_the_tool(fil_binary, path):
    fil, sim = fil_view(fil_binary, path), sim_view(path)
    assert fil.returncode == 0 or sim.returncode == 0, f"neither tool reads {path}:\n{fil.stderr}{sim.stderr}"
    if fil.returncode == 0 and sim.returncode == 0:
        assert_same(json.loads(fil.stdout), json.loads(sim.stdout))
    elif fil.returncode != 0:
        assert fil.returncode == 2 and "only cdro-sim supports" in fil.stderr, fil.stderr
    else:
        assert sim.returncode == 2 and "only cdro-fil supports" in sim.stderr, sim.stderr


def test_that_the_repository_has_a_scenario_both_tools_read():
    assert SHARED in SCENARIO_FILES


# (a scenario file, the key the message names)
FIL_ONLY = [
    (MINIMAL + "uwb: {bias_m: 0.1}\n", "uwb.bias_m"),
    (MINIMAL + "uwb: {ranging_us: 20000}\n", "uwb.ranging_us"),
    (MINIMAL + "pozyx: {model: ideal}\n", "pozyx.model"),
    (MINIMAL + "pozyx: {who_am_i: 0x42}\n", "pozyx.who_am_i"),
    (MINIMAL + "faults:\n  - {kind: nack_address, at_s: 2, count: 3}\n", "faults[0].kind"),
    (MINIMAL + "faults:\n  - {kind: power_off, node: 0x6A01, at_s: 2, duration_s: 3}\n", "faults[0].kind"),
    (MINIMAL + "motion:\n  - {node: 0x6A01, start_s: 1, speed_mps: 1, waypoints_m: [[4, 2, 1.5]]}\n",
     "motion[0].waypoints_m[0]"),
]
SIM_ONLY = [
    (MINIMAL + "schedule: {mode: direct_only}\n", "scenario.schedule"),
    (MINIMAL + "robot: {id: 0x6000, waypoints_m: [[2, 2]]}\n", "scenario.robot"),
    (MINIMAL + "device: {free_ram_bytes: 400}\n", "scenario.device"),
    (MINIMAL + "epoch_unix_s: 1800000000\n", "scenario.epoch_unix_s"),
    (MINIMAL + "uwb: {scale: 1.02}\n", "uwb.scale"),
    (MINIMAL + "uwb: {dropout_probability: 0.1}\n", "uwb.dropout_probability"),
    (MINIMAL + "uwb: {noise_variance_m2: [0.1, 0.2]}\n", "uwb.noise_variance_m2"),
    (MINIMAL + "uwb: {nlos: {random_links: 1}}\n", "uwb.nlos"),
    (MINIMAL + "pozyx: {present: false}\n", "pozyx.present"),
    (MINIMAL.replace("x_m: 0, y_m: 0}", "x_m: 0, y_m: 0, moving_amplitude_mg: 100}"), "nodes[0].moving_amplitude_mg"),
    (MINIMAL + "faults:\n  - {kind: vanish, at_s: 2, duration_s: 1}\n", "faults[0].kind"),
    (MINIMAL + "faults:\n  - {kind: garbage, at_s: 2}\n", "faults[0].kind"),
]


def test_that_each_tools_fault_kinds_are_refused_by_the_other_naming_it(fil_binary, tmp_path):
    path = tmp_path / "fault.yaml"
    for kind in FAULT_KINDS:
        path.write_text(MINIMAL + f"faults:\n  - {{kind: {kind}, at_s: 1}}\n")
        assert sim_view(path).returncode == 0, kind
        fil = fil_view(fil_binary, path)
        assert fil.returncode == 2 and f"only cdro-sim supports the fault kind '{kind}'" in fil.stderr, fil.stderr
    for kind in FIL_FAULT_KINDS:
        extra = ", node: 0x6A01, duration_s: 2" if kind == "power_off" else ""
        path.write_text(MINIMAL + f"faults:\n  - {{kind: {kind}, at_s: 1{extra}}}\n")
        assert fil_view(fil_binary, path).returncode == 0, kind
        sim = sim_view(path)
        assert sim.returncode == 2 and f"only cdro-fil supports the fault kind '{kind}'" in sim.stderr, sim.stderr


@pytest.mark.parametrize(("text", "key"), FIL_ONLY, ids=[k for _, k in FIL_ONLY])
def test_that_a_key_only_cdro_fil_acts_on_is_refused_by_cdro_sim_saying_so(fil_binary, tmp_path, text, key):
    path = tmp_path / "fil-only.yaml"
    path.write_text(text)
    assert fil_view(fil_binary, path).returncode == 0, "cdro-fil reads it"
    sim = sim_view(path)
    assert sim.returncode == 2
    assert f"{path}: {key}: only cdro-fil supports" in sim.stderr, sim.stderr


@pytest.mark.parametrize(("text", "key"), SIM_ONLY, ids=[k for _, k in SIM_ONLY])
def test_that_a_key_only_cdro_sim_acts_on_is_refused_by_cdro_fil_saying_so(fil_binary, tmp_path, text, key):
    path = tmp_path / "sim-only.yaml"
    path.write_text(text)
    assert sim_view(path).returncode == 0, "cdro-sim reads it"
    fil = fil_view(fil_binary, path)
    assert fil.returncode == 2
    assert f"{key}: only cdro-sim supports" in fil.stderr and str(path) in fil.stderr, fil.stderr


# (a file in an earlier spelling, the key named, what it is called now)
RENAMED = [
    (MINIMAL.replace("own_id:", "own:"), "own", "own_id"),
    (MINIMAL.replace("{id: 0x6000, x_m:", "{id: 0x6000, x:"), "nodes[0].x", "x_m"),
    (MINIMAL.replace("{id: 0x6000,", "{id: 0x6000, tag: true,"), "nodes[0].tag", "accelerometer"),
    (MINIMAL + "motion:\n  - {node: 0x6A01, start_s: 1, speed_mps: 1, waypoints: [[4, 2]]}\n",
     "motion[0].waypoints", "waypoints_m"),
    (MINIMAL + "uwb: {noise_std_mm: 30}\n", "uwb.noise_std_mm", "noise_std_m (in metres)"),
    (MINIMAL + "accelerometer: {noise_mg: 8}\n", "accelerometer.noise_mg", "noise_std_mg"),
]


@pytest.mark.parametrize(("text", "key", "now"), RENAMED, ids=[k for _, k, _ in RENAMED])
def test_that_both_say_what_an_earlier_spelling_is_called_now(fil_binary, tmp_path, text, key, now):
    path = tmp_path / "old.yaml"
    path.write_text(text)
    for result in (fil_view(fil_binary, path), sim_view(path)):
        assert result.returncode == 2
        assert f"{key}: this key is now called {now}" in result.stderr, result.stderr


def test_that_cdro_sim_refuses_a_duration_of_zero_saying_which_tool_runs_until_stopped():
    with pytest.raises(ScenarioError, match=r"duration_s: only cdro-fil supports 0 \(run until stopped\)"):
        parse_scenario({"own_id": 1, "duration_s": 0, "nodes": [{"id": 1, "x_m": 0, "y_m": 0},
                                                                {"id": 2, "x_m": 4, "y_m": 0}]}, "test")
