"""cdro-sim offline, run as a user runs it: CSV and capture outputs, determinism, the shipped
scenarios, fault counts in a capture, and errors."""
import collections
import csv
import json
import math
import subprocess
import sys

import pytest

from cdro_tools import codec
from cdro_tools.simulation import host_device
from cdro_tools.simulation.scenario import builtin_names, load_scenario


def sim(*args, check=True):
    result = subprocess.run([sys.executable, "-m", "cdro_tools.sim", *map(str, args)], capture_output=True, text=True,
                            timeout=120)
    if check:
        assert result.returncode == 0, result.stderr
    return result


def rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_that_the_same_seed_gives_identical_bytes_and_another_seed_does_not(tmp_path):
    # Fixture
    outputs = {}
    for name, seed in (("a", 5), ("b", 5), ("c", 6)):
        base = tmp_path / name
        sim("--scenario", "demo", "--seed", seed, "--duration", 20, "--ranges-csv", f"{base}.ranges.csv",
            "--capture", f"{base}.cdrocap", "--motion-csv", f"{base}.motion.csv")
        outputs[name] = [(tmp_path / f"{name}.{ext}").read_bytes() for ext in ("ranges.csv", "cdrocap", "motion.csv")]

    # Assert
    assert outputs["a"] == outputs["b"]
    assert outputs["a"][0] != outputs["c"][0] and outputs["a"][1] != outputs["c"][1]
    assert outputs["a"][2] == outputs["c"][2]                       # the truth does not depend on the seed


def test_that_the_csv_files_have_the_documented_columns(tmp_path):
    files = {k: tmp_path / f"{k}.csv" for k in ("ranges", "truth", "heights", "tracks", "motion", "odometry", "robot")}
    result = sim("--scenario", "plaza-like", "--duration", 40,
                 "--ranges-csv", files["ranges"], "--truth-csv", files["truth"], "--heights-csv", files["heights"],
                 "--tracks-csv", files["tracks"], "--motion-csv", files["motion"],
                 "--odometry-csv", files["odometry"], "--robot-truth-csv", files["robot"])
    headers = {k: p.read_text().splitlines()[0] for k, p in files.items()}
    assert headers == {"ranges": "t,from,to,range_m", "truth": "id,x,y,z", "heights": "id,z", "tracks": "t,id,x,y",
                       "motion": "t,id,moving", "odometry": "t,distance_m,dheading_rad", "robot": "t,x,y,heading_rad"}
    assert len(rows(files["odometry"])) == 400 and len(rows(files["robot"])) == 401
    assert {r["id"] for r in rows(files["tracks"])} == {str(0x6001)}
    assert "ranges" in result.stderr and "seed 1" in result.stderr


def test_that_paper_fig3_is_five_static_nodes_all_in_range_with_the_papers_noise(tmp_path):
    # Fixture
    scenario = load_scenario("paper-fig3")
    sim("--scenario", "paper-fig3", "--ranges-csv", tmp_path / "r.csv", "--truth-csv", tmp_path / "t.csv")

    # Assert: the layout
    truth = {int(r["id"]): (float(r["x"]), float(r["y"]), float(r["z"])) for r in rows(tmp_path / "t.csv")}
    assert len(truth) == 5 and not scenario.motion and scenario.robot is None
    xs, ys = [p[0] for p in truth.values()], [p[1] for p in truth.values()]
    assert max(xs) - min(xs) <= 20 and max(ys) - min(ys) <= 20
    assert scenario.uwb.noise_variance_m2 == (0.3, 0.8) and scenario.uwb.dropout_probability == 0
    # the ranges: all 10 pairs, errors with the paper's variance range
    errors = collections.defaultdict(list)
    for r in rows(tmp_path / "r.csv"):
        a, b = int(r["from"]), int(r["to"])
        errors[(a, b)].append(float(r["range_m"]) - math.dist(truth[a], truth[b]))
    assert len(errors) == 10
    variances = [sum(e * e for e in v) / len(v) for v in errors.values()]
    assert all(0.15 < v < 1.2 for v in variances), variances
    assert min(len(v) for v in errors.values()) > 100


def test_that_demo_has_heights_a_carried_node_nlos_and_plausible_rates(tmp_path):
    scenario = load_scenario("demo")
    sim("--scenario", "demo", "--ranges-csv", tmp_path / "r.csv", "--motion-csv", tmp_path / "m.csv",
        "--tracks-csv", tmp_path / "tr.csv")
    heights = [n.z_m for n in scenario.nodes]
    assert 6 <= len(heights) <= 8 and len(set(heights)) == len(heights)
    assert 50 <= scenario.duration_s <= 70 and scenario.uwb.nlos.links
    moves = [r for r in rows(tmp_path / "m.csv") if float(r["t"]) > 0]
    assert [(r["moving"]) for r in moves] == ["1", "0"]
    start, stop = float(moves[0]["t"]), float(moves[1]["t"])
    assert 0.4 * scenario.duration_s < start < 0.6 * scenario.duration_s
    track = [r for r in rows(tmp_path / "tr.csv") if start <= float(r["t"]) <= stop + 0.1]
    carried_m = math.dist((float(track[0]["x"]), float(track[0]["y"])), (float(track[-1]["x"]), float(track[-1]["y"])))
    assert 4.5 < carried_m < 6.0 and 0.8 < carried_m / (stop - start) < 1.8      # walking pace
    ranges_per_s = len(rows(tmp_path / "r.csv")) / scenario.duration_s
    assert 10 < ranges_per_s < 30


def test_that_every_builtin_scenario_loads_and_runs(tmp_path):
    assert {"paper-fig3", "demo", "plaza-like"} <= set(builtin_names())
    listing = sim("--list-scenarios").stdout
    for name in builtin_names():
        assert name in listing
        sim("--scenario", name, "--duration", 10, "--ranges-csv", tmp_path / f"{name}.csv")
        # robot-corridor: some pairs out of range (the firmware waits out its reply and result
        # timeouts on each of their attempts until they back off); 78 ranges in its first 10 s
        assert len(rows(tmp_path / f"{name}.csv")) > 20, name


def test_that_random_network_mode_writes_ranges_and_truth(tmp_path):
    result = sim("--random-network", 30, "--degree", 5, "--noise-m", 0.2, "--seed", 4,
                 "--ranges-csv", tmp_path / "r.csv", "--truth-csv", tmp_path / "t.csv")
    truth = rows(tmp_path / "t.csv")
    links = {(r["from"], r["to"]) for r in rows(tmp_path / "r.csv")}
    assert len(truth) == 30 and len(links) == 75                     # mean degree 5 = 2 x 75 / 30
    assert "mean degree 5.00" in result.stderr and "seed 4" in result.stderr


def test_that_faults_in_a_capture_are_counted_as_a_host_decoder_counts_them(tmp_path):
    # Fixture: a scenario file with a faults list, plus faults from the command line
    scenario = tmp_path / "faulty.yaml"
    scenario.write_text("""
own_id: 0x6001
duration_s: 30
nodes:
  - {id: 0x6001, x_m: 0, y_m: 0, accelerometer: true}
  - {id: 0x6002, x_m: 6, y_m: 0}
  - {id: 0x6003, x_m: 3, y_m: 5}
faults:
  - {at_s: 5, kind: bit_flip, frames: 3}
  - {at_s: 8, kind: cut_frame, frames: 2}
  - {at_s: 11, kind: absurd, frames: 6}
  - {at_s: 14, kind: reset}
""")
    capture, report = tmp_path / "run.cdrocap", tmp_path / "faults.json"

    # Test
    result = sim("--scenario", scenario, "--seed", 3, "--capture", capture, "--fault-report", report,
                 "--fault", "garbage@3,bytes=1", "--fault", "vanish@20,duration_s=2")

    # Assert: the counts
    counts = json.loads(report.read_text())["counts"]
    assert counts["bit_flip"]["injected"] == 3 and counts["cut_frame"]["injected"] == 2
    assert counts["absurd"] == {"injected": 6, "distance": 2, "self_range": 2, "unknown_node": 2}
    assert counts["reset"]["injected"] == 1 and counts["garbage"] == {"injected": 1, "bytes": 1}
    assert counts["vanish"]["injected"] == 1 and counts["vanish"]["seconds"] == 2.0
    assert "faults injected: garbage 1" in result.stderr
    # what the host decoder must see, by decoding the capture independently
    link = json.loads(report.read_text())["link"]
    decoder = codec.StreamDecoder()
    contents = codec.read_capture(capture)
    hellos = []
    for record in contents.records:
        if not record.to_device:
            for event in decoder.feed(record.data + b"\x00"):
                if event.frame is not None and event.frame.type == "HELLO" and str(event.result) == "ok":
                    hellos.append(event.frame)
    counters = link["host_decoder"]
    assert {k: counters[k] for k in decoder.counters} == decoder.counters
    # 3 flipped frames; the 2 cut frames are consecutive, so they and the frame after them make one
    # chunk; the garbage byte merges with the next frame; 4 absurd frames fail validation (value)
    rejected = sum(v for k, v in decoder.counters.items() if k.endswith("_errors"))
    assert rejected == 3 + 1 + 1 + 4
    assert decoder.counters["value_errors"] == 4
    assert [h["reset_cause"] for h in hellos] == [1, 8]  # power on, then the watchdog reset
    assert link["frames_lost_while_gone"] > 20
    # the simulated host configured the device again after the reset: ranging resumed
    records = [r.host_time_us for r in contents.records if r.to_device]
    assert len(records) == 6


@pytest.mark.parametrize("args, message", [
    (["--scenario", "no-such-scenario", "--ranges-csv", "x.csv"], "neither a built-in scenario"),
    (["--scenario", "demo"], "nothing to do"),
    (["--random-network", "10"], "needs --degree"),
    (["--scenario", "demo", "--ranges-csv", "x.csv", "--fault", "earthquake@3"], "is not one of"),
    (["--scenario", "demo", "--ranges-csv", "x.csv", "--speed", "fast"], "neither a number nor max"),
    (["--scenario", "demo", "--ranges-csv", "no/such/dir/x.csv"], "no such directory"),
    (["--scenario", "demo", "--pty", "no/such/dir/dev"], "is not a directory"),
])
def test_that_bad_input_exits_non_zero_with_a_clear_message(tmp_path, args, message):
    result = sim(*args, check=False)
    assert result.returncode == 2
    assert message in result.stderr


def test_that_a_scenario_with_a_wrong_key_names_the_key(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("own_id: 0x6001\nnodes:\n  - {id: 0x6001, x_m: 0, y_m: 0, hieght: 2}\n"
                    "  - {id: 0x6002, x_m: 4, y_m: 0}\n")
    result = sim("--scenario", path, "--ranges-csv", tmp_path / "r.csv", check=False)
    assert result.returncode == 2 and "nodes[0]: unknown key(s) hieght" in result.stderr


def test_that_help_has_an_example():
    assert "example" in sim("--help").stdout


def test_that_a_vanish_with_reboot_boots_the_device_again_when_it_returns(tmp_path):
    capture, report = tmp_path / "run.cdrocap", tmp_path / "faults.json"
    sim("--scenario", "demo", "--duration", 12, "--capture", capture, "--fault-report", report,
        "--fault", "vanish@5,duration_s=1.5,reboot=true")
    hellos = []
    decoder = codec.StreamDecoder()
    for record in codec.read_capture(capture).records:
        if not record.to_device:
            for event in decoder.feed(record.data + b"\x00"):
                if event.frame is not None and event.frame.type == "HELLO":
                    hellos.append((record.host_time_us, event.frame["reset_cause"], event.frame.sequence))
    epoch_us = int(load_scenario("demo").epoch_unix_s * 1e6)
    assert [(cause, seq) for _, cause, seq in hellos] == [(1, 0), (2, 0)]        # power on, then external
    # back at 6.5 s (the firmware restarts at the end of the step under way, which is at most a
    # remote range with its timeouts), HELLO POZYX_BOOT_MS after the restart
    boot_ms = host_device.constant("POZYX_BOOT_MS")
    longest_ms = host_device.constant("LONGEST_OPERATION_MS")
    assert (6_500 + boot_ms) * 1000 <= hellos[1][0] - epoch_us <= (6_500 + boot_ms + longest_ms) * 1000
    counts = json.loads(report.read_text())["counts"]["vanish"]
    assert counts == {"injected": 1, "seconds": 1.5, "reboots": 1}
