#!/usr/bin/env python3
"""Every figure of docs/results.md, from the data and the simulator, with the same binaries a
user has (build/bin/cdro-hostd, the Python tools in .venv). Run through scripts/results.sh.

Writes out/results/ (every intermediate file), docs/results/*.png (the plots the doc shows) and
out/results/summary.json (every number), and prints the tables. Deterministic: the simulator and
the shuffles are seeded, the seeds are printed.
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import pathlib
import random
import statistics
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent
DATA = pathlib.Path(os.environ.get("CDRO_DATA_DIR", ROOT.parent / "shared" / "data"))
OUT = ROOT / "out" / "results"
PNG = ROOT / "docs" / "results"
HOSTD = ROOT / "build" / "bin" / "cdro-hostd"
# The Python tools: the repository's environment, else the one running this script (a worktree
# without its own .venv).
BIN = ROOT / ".venv" / "bin" if (ROOT / ".venv" / "bin").is_dir() else pathlib.Path(sys.executable).parent
SEEDS = list(range(1, 11))


def run(args: list, quiet: bool = True) -> str:
    result = subprocess.run([str(a) for a in args], capture_output=True, text=True)
    if result.returncode != 0:
        sys.stderr.write(result.stdout + result.stderr)
        raise SystemExit(f"results: failed: {' '.join(map(str, args))}")
    return result.stdout if quiet else result.stdout + result.stderr


def hostd(*args) -> str:
    result = subprocess.run([str(HOSTD), *map(str, args)], capture_output=True, text=True)
    if result.returncode != 0:
        sys.stderr.write(result.stderr)
        raise SystemExit(f"results: cdro-hostd failed: {' '.join(map(str, args))}")
    return result.stderr


def eval_json(*args) -> dict:
    return json.loads(run([BIN / "cdro-eval", *args, "--json", "-"]))


def motion_json(*args) -> dict:
    return json.loads(run([BIN / "cdro-eval-motion", *args, "--json", "-"]))


def sim(scenario: str, seed: int, prefix: pathlib.Path, *files: str) -> None:
    args = [BIN / "cdro-sim", "--scenario", scenario, "--seed", seed]
    for name in files:
        args += [f"--{name}-csv", f"{prefix}-{name}.csv"]
    run(args)


def steady(trace: pathlib.Path, truth: pathlib.Path, fraction: float = 0.5) -> float:
    """Mean aligned RMSE over the last `fraction` of a trace's snapshots."""
    report = eval_json("--truth", truth, "--trace", trace, "--no-baselines")
    points = report["convergence"][0]["rmse_over_ranges"]
    tail = points[int(len(points) * (1 - fraction)):]
    return statistics.mean(p["rmse_m"] for p in tail)


HALL = ("--set", "engine.convergence.room_excess_m=0")


def plant(summary: dict) -> None:
    print("== PLANT (real, 28 nodes, heights known)")
    ranges, nodes = DATA / "plant" / "ranges.csv", DATA / "plant" / "nodes.csv"
    est, trace = OUT / "plant-estimates.csv", OUT / "plant-trace.csv"
    # PLANT is one hall of a plant, and a user says so: no room's walls on its links (docs/results.md).
    log = hostd("--ranges-csv", ranges, "--heights-csv", nodes, *HALL, "--out-csv", est, "--trace-csv", trace)
    report = eval_json("--truth", nodes, "--ranges", ranges, "--heights-from-truth", "--estimates", est,
                       "--trace", trace, "--label", "file order", "--crb-per-link", "--sigma-m", "0.13",
                       "--map-png", PNG / "plant-map.png", "--rmse-png", PNG / "plant-rmse.png",
                       "--title", "PLANT: CDRO-SLAM, ranges in file order")
    methods = {name: m["rmse_m"] for name, m in report["methods"].items()}
    engine = report["methods"]["engine"]
    summary["plant"] = {"file_order": {"rmse_m": engine["rmse_m"], "converged": engine["converged"],
                                       "nodes": engine["estimates"], "log": log.strip().splitlines(),
                                       "all_converged_at_ranges": report["convergence"][0]["all_converged_at_ranges"]},
                        "baselines": methods, "crb_m": report.get("crb", {}).get("rmse_m")}
    print(f"file order: RMSE {engine['rmse_m']:.3f} m, converged {engine['converged']}/{engine['estimates']}")
    for name, value in methods.items():
        print(f"  {name:18s} {value:.3f} m")
    print(f"  {'CRB':18s} {summary['plant']['crb_m']:.3f} m")
    rows = list(csv.DictReader(open(ranges)))
    shuffled = []
    for seed in SEEDS:
        order = list(rows)
        random.Random(seed).shuffle(order)
        path = OUT / f"plant-shuffled-{seed}.csv"
        with open(path, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=["from", "to", "range_m"])
            writer.writeheader()
            writer.writerows(order)
        out = OUT / f"plant-shuffled-{seed}-estimates.csv"
        hostd("--ranges-csv", path, "--heights-csv", nodes, *HALL, "--out-csv", out)
        r = eval_json("--truth", nodes, "--estimates", out, "--no-baselines")["methods"]["engine"]
        shuffled.append({"seed": seed, "rmse_m": r["rmse_m"], "converged": r["converged"]})
    values = [s["rmse_m"] for s in shuffled]
    summary["plant"]["shuffled"] = {"runs": shuffled, "min_m": min(values), "median_m": statistics.median(values),
                                    "max_m": max(values), "all_converged": all(s["converged"] == 28 for s in shuffled)}
    print(f"shuffled (seeds {SEEDS[0]}..{SEEDS[-1]}): RMSE min {min(values):.3f} / median "
          f"{statistics.median(values):.3f} / max {max(values):.3f} m; every node converged in every run: "
          f"{summary['plant']['shuffled']['all_converged']}")


def fig3(summary: dict) -> None:
    print("== Paper Fig. 3 (5 nodes, per-link noise variance U(0.3, 0.8) m^2)")
    modes = {"engine": [], "engine, no weight transfer": ["--no-weight-transfer"],
             "paper's filter": ["--no-refinement"],
             "paper's filter, no weight transfer": ["--no-refinement", "--no-weight-transfer"]}
    table = {name: [] for name in modes}
    for seed in SEEDS:
        prefix = OUT / f"fig3-{seed}"
        sim("paper-fig3", seed, prefix, "ranges", "truth")
        for name, flags in modes.items():
            trace = OUT / f"fig3-{seed}-{name.replace(' ', '_').replace(',', '').replace(chr(39), '')}.csv"
            hostd("--ranges-csv", f"{prefix}-ranges.csv", "--out-csv", OUT / "fig3-estimates.csv", "--trace-csv", trace,
                  "--trace-every", "10", "--set", "engine.range.sigma_m=0.75", *flags)
            table[name].append(steady(trace, pathlib.Path(f"{prefix}-truth.csv")))
    seed = SEEDS[0]
    traces = []
    for name in ("paper's filter", "paper's filter, no weight transfer", "engine", "engine, no weight transfer"):
        traces += ["--trace", OUT / f"fig3-{seed}-{name.replace(' ', '_').replace(',', '').replace(chr(39), '')}.csv",
                   "--label", name]
    eval_json("--truth", OUT / f"fig3-{seed}-truth.csv", *traces, "--no-baselines",
              "--rmse-png", PNG / "fig3-rmse.png", "--title", f"Paper Fig. 3 setting, seed {seed}")
    summary["fig3"] = {name: {"mean_m": statistics.mean(v), "per_seed_m": v} for name, v in table.items()}
    for name, values in table.items():
        print(f"  {name:36s} steady-state RMSE {statistics.mean(values):.3f} m (mean of {len(values)} seeds)")


def fig3_batch(summary: dict) -> None:
    """The paper's Algorithm 1 as written (batch), on the same setting, under each reading of what
    the paper leaves open: 30 draws, 100 iterations."""
    from cdro_tools.evaluation import paper_algorithm1 as paper  # numpy: the venv this script runs in

    print("== Paper Fig. 3, the paper's Algorithm 1 as written (cdro_tools.evaluation.paper_algorithm1)")
    seeds = list(range(1, 31))
    table = {}
    for name, _, result in paper.sweep(seeds):
        table[name] = {"with_transfer_m": statistics.mean(result.with_transfer_m),
                       "without_transfer_m": statistics.mean(result.without_transfer_m),
                       "draws_transfer_better": result.draws_where_transfer(better=True),
                       "draws_transfer_worse": result.draws_where_transfer(better=False)}
        print(f"  {name:70s} steady-state RMSE with transfer {table[name]['with_transfer_m']:.3f} m, without "
              f"{table[name]['without_transfer_m']:.3f} m; transfer better in {table[name]['draws_transfer_better']}"
              f", worse in {table[name]['draws_transfer_worse']} of {len(seeds)} draws")
    summary["fig3_batch"] = table


def renumbered(name: str) -> pathlib.Path:
    """A copy of a Plaza data set with its beacon 0 as 100: 0 is not a node id for cdro-hostd."""
    copy = OUT / f"{name}-data"
    copy.mkdir(parents=True, exist_ok=True)
    for file in ("ranges.csv", "odometry.csv", "groundtruth.csv", "beacons.csv"):
        with open(DATA / name / file, newline="") as f:
            rows = list(csv.reader(f))
        ids = [i for i, column in enumerate(rows[0]) if column in ("from", "to", "id")]
        for row in rows[1:]:
            for i in ids:
                row[i] = "100" if row[i] == "0" else row[i]
        with open(copy / file, "w", newline="") as f:
            csv.writer(f, lineterminator="\n").writerows(rows)
    return copy


def plaza(summary: dict) -> None:
    print("== Plaza1 / Plaza2 (real robot, odometry, 4 beacons, no inter-beacon ranges)")
    summary["plaza"] = {}
    for name in ("plaza1", "plaza2"):
        d = renumbered(name)
        results = {}
        for label, flags in (("scale estimated", []), ("raw ranges", ["--set", "movement.estimate_scale=false",
                                                                       "--set", "movement.estimate_offset=false"])):
            traj, nodes = OUT / f"{name}-{label[:3]}-trajectory.csv", OUT / f"{name}-{label[:3]}-nodes.csv"
            log = hostd("--ranges-csv", d / "ranges.csv", "--odometry-csv", d / "odometry.csv", "--robot-id", 2,
                        "--out-csv", nodes, "--out-trajectory", traj, *flags)
            png = ["--path-png", PNG / f"{name}-path.png", "--title", f"{name}: causal robot path and beacons"] \
                if label == "scale estimated" else []
            r = motion_json("--trajectory", traj, "--robot-truth", d / "groundtruth.csv", "--nodes", nodes,
                            "--beacon-truth", d / "beacons.csv", "--exclude", "2", *png)
            calibration = [line for line in log.splitlines() if "calibration" in line]
            results[label] = {"path_m": r["path"]["rmse_m"], "path_p95_m": r["path"]["p95_m"],
                              "beacons_m": r["beacons"]["own_fit_rmse_m"],
                              "beacons_through_path_m": r["beacons"]["path_fit_rmse_m"],
                              "calibration": calibration[0].split("calibration: ")[1] if calibration else ""}
            print(f"  {name} {label:16s} path {results[label]['path_m']:.3f} m "
                  f"(p95 {results[label]['path_p95_m']:.3f}), "
                  f"beacons {results[label]['beacons_m']:.3f} m (through the path's fit "
                  f"{results[label]['beacons_through_path_m']:.3f} m) {results[label]['calibration']}")
        summary["plaza"][name] = results


def cooperative_robot(summary: dict) -> None:
    summary["cooperative_robot"] = {}
    for scenario, start_s, what in (
            ("robot-corridor", 15.0, "8 anchors in a corridor, each in range of its 3 nearest on each side"),
            ("plaza-like", 20.0, "8 anchors that all range each other")):
        print(f"== Simulated robot, {scenario}: {what}")
        runs = []
        for seed in SEEDS[:5]:
            prefix = OUT / f"{scenario}-{seed}"
            sim(scenario, seed, prefix, "ranges", "truth", "heights", "odometry", "robot-truth")
            ranges = list(csv.DictReader(open(f"{prefix}-ranges.csv")))
            standing = OUT / f"{scenario}-{seed}-standing-ranges.csv"
            with open(standing, "w", newline="") as f:
                writer = csv.DictWriter(f, fieldnames=list(ranges[0].keys()))
                writer.writeheader()
                writer.writerows(r for r in ranges if float(r["t"]) < start_s)   # before the robot moves
            init = OUT / f"{scenario}-{seed}-init.csv"
            hostd("--ranges-csv", standing, "--heights-csv", f"{prefix}-heights.csv", "--out-csv", init)
            nodes, traj = OUT / f"{scenario}-{seed}-nodes.csv", OUT / f"{scenario}-{seed}-trajectory.csv"
            log = hostd("--ranges-csv", f"{prefix}-ranges.csv", "--heights-csv", f"{prefix}-heights.csv",
                        "--odometry-csv", f"{prefix}-odometry.csv", "--robot-id", "0x6001", "--out-csv", nodes,
                        "--out-trajectory", traj)
            before = motion_json("--nodes", init, "--beacon-truth", f"{prefix}-truth.csv", "--exclude", "0x6001")
            png = ["--path-png", PNG / f"{scenario}-path.png", "--title", f"simulated robot: {scenario}"] \
                if seed == SEEDS[0] else []
            after = motion_json("--trajectory", traj, "--robot-truth", f"{prefix}-robot-truth.csv", "--nodes", nodes,
                                "--beacon-truth", f"{prefix}-truth.csv", "--exclude", "0x6001", *png)
            calibration = [line.split("calibration: ")[1] for line in log.splitlines() if "calibration" in line]
            runs.append({"seed": seed, "map_initialization_m": before["beacons"]["own_fit_rmse_m"],
                         "map_with_robot_m": after["beacons"]["own_fit_rmse_m"], "path_m": after["path"]["rmse_m"],
                         "path_p95_m": after["path"]["p95_m"], "calibration": calibration[0] if calibration else ""})
            print(f"  seed {seed}: map {runs[-1]['map_initialization_m']:.3f} m after initialization alone, "
                  f"{runs[-1]['map_with_robot_m']:.3f} m with the robot driving; robot path {runs[-1]['path_m']:.3f} m "
                  f"(p95 {runs[-1]['path_p95_m']:.3f}); {runs[-1]['calibration']}")
        summary["cooperative_robot"][scenario] = runs


def carried_node(summary: dict) -> None:
    print("== A node carried 5.2 m at 1.3 m/s while the others stay (demo scenario)")
    modes = {"motion reports (Fig. 4 + track)": ["--motion-csv", "{motion}"],
             "no reports (fallback detector)": [],
             "--no-motion-reset": ["--motion-csv", "{motion}", "--no-motion-reset"]}
    table = {name: [] for name in modes}
    for seed in SEEDS[:5]:
        prefix = OUT / f"carry-{seed}"
        sim("demo", seed, prefix, "ranges", "truth", "heights", "tracks", "motion")
        for name, flags in modes.items():
            trace = OUT / f"carry-{seed}-{len(table[name])}-{name[:6].strip()}.csv"
            hostd("--ranges-csv", f"{prefix}-ranges.csv", "--heights-csv", f"{prefix}-heights.csv",
                  *[f.format(motion=f"{prefix}-motion.csv") for f in flags], "--out-csv", OUT / "carry-estimates.csv",
                  "--trace-csv", trace, "--trace-every", "1")
            png = ["--track-png", PNG / "carried-node.png"] if seed == SEEDS[0] and name.startswith("motion") else []
            r = motion_json("--trace", trace, "--tracks", f"{prefix}-tracks.csv", "--truth", f"{prefix}-truth.csv",
                            "--motion", f"{prefix}-motion.csv", "--node", "0x6006", *png)["track"]
            table[name].append(r)
    summary["carried_node"] = {}
    for name, reports in table.items():
        p95 = [r["p95_m"] for r in reports]
        rmse = [r["rmse_m"] for r in reports]
        again = [r["reconverged_after_s"][0] for r in reports]
        summary["carried_node"][name] = {"p95_m": p95, "rmse_m": rmse, "reconverged_after_s": again}
        shown = ", ".join("never" if a is None else f"{a:.2f}" for a in again)
        print(f"  {name:34s} p95 {statistics.median(p95):.3f} m (median of {len(p95)} seeds; max {max(p95):.3f}), "
              f"RMSE {statistics.median(rmse):.3f} m; converged again after stopping: {shown} s")


def fallback_detector(summary: dict) -> None:
    print("== The fallback detector (no motion reports) on the carried node, 10 seeds: how late it sees the start "
          "and the stop")
    runs = []
    for seed in SEEDS:
        prefix = OUT / f"carry-{seed}"
        sim("demo", seed, prefix, "ranges", "truth", "heights", "tracks", "motion")
        trace = OUT / f"carry-{seed}-fallback.csv"
        hostd("--ranges-csv", f"{prefix}-ranges.csv", "--heights-csv", f"{prefix}-heights.csv", "--out-csv",
              OUT / "carry-estimates.csv", "--trace-csv", trace, "--trace-every", "1")
        r = motion_json("--trace", trace, "--tracks", f"{prefix}-tracks.csv", "--truth", f"{prefix}-truth.csv",
                        "--motion", f"{prefix}-motion.csv", "--node", "0x6006")["track"]
        runs.append({"seed": seed, "start_seen_after_s": r["start_seen_after_s"][0],
                     "stop_seen_after_s": r["stop_seen_after_s"][0], "p95_m": r["p95_m"]})
    summary["fallback_detector"] = runs

    def shown(key: str) -> str:
        return ", ".join("never" if run[key] is None else f"{run[key]:.2f}" for run in runs)

    def within(key: str) -> int:
        return sum(1 for run in runs if run[key] is not None and run[key] <= 1.0)

    print(f"  start seen after (s): {shown('start_seen_after_s')}; within 1 s: {within('start_seen_after_s')}/10")
    print(f"  stop seen after (s):  {shown('stop_seen_after_s')}; within 1 s: {within('stop_seen_after_s')}/10")


STEPS = (plant, fig3, fig3_batch, plaza, cooperative_robot, carried_node, fallback_detector)


def main() -> int:
    parser = argparse.ArgumentParser(description="Every figure of docs/results.md (or the steps named).")
    parser.add_argument("--steps", nargs="+", choices=[step.__name__ for step in STEPS],
                        help="only these steps (summary.json then holds only theirs)")
    args = parser.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    PNG.mkdir(parents=True, exist_ok=True)
    if not DATA.is_dir():
        raise SystemExit(f"results: no data at {DATA} (set CDRO_DATA_DIR)")
    summary: dict = {"seeds": SEEDS}
    for step in STEPS:
        if args.steps is None or step.__name__ in args.steps:
            step(summary)
    with open(OUT / "summary.json", "w") as f:
        json.dump(summary, f, indent=2, sort_keys=True)
    print(f"results: every number in {OUT / 'summary.json'}, the plots in {PNG}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
