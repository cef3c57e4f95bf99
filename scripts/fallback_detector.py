#!/usr/bin/env python3
"""The fallback detector's figures of docs/results.md ("How late the fallback detector sees the
motion"), on their own: how late it sees a carried node start and stop from the ranges alone, and
whether it calls a still node moving.

- demo: the carried node 0x6006 of scenario `demo` (as scripts/results.py's step
  `fallback_detector`): start_seen_after_s, stop_seen_after_s, the track's p95;
- hall: scripts/scenarios/carried-hall.yaml, a carry not used to choose the detector's settings;
- still: scripts/scenarios/still-room.yaml, where nothing moves: every node the detector calls
  moving (a false start), when and for how long.

The simulated ranges do not depend on the engine: they are made once per scenario and seed in
--data (with cdro-sim of the Python environment that runs this script) and reused; only
cdro-hostd (--hostd) runs again. Deterministic: seeded.

    .venv/bin/python scripts/fallback_detector.py --hostd build/bin/cdro-hostd [--steps demo still]
"""
from __future__ import annotations

import argparse
import csv
import json
import pathlib
import statistics
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent
BIN = pathlib.Path(sys.executable).parent  # cdro-sim and cdro-eval-motion of the same environment
SCENARIOS = {"demo": ("demo", "0x6006"),
             "hall": (str(ROOT / "scripts" / "scenarios" / "carried-hall.yaml"), "0x6206"),
             "still": (str(ROOT / "scripts" / "scenarios" / "still-room.yaml"), None)}
WITHIN_S = 1.0  # s, issue 19's goal


def run(args: list) -> str:
    result = subprocess.run([str(a) for a in args], capture_output=True, text=True)
    if result.returncode != 0:
        sys.stderr.write(result.stdout + result.stderr)
        raise SystemExit(f"fallback_detector: failed: {' '.join(map(str, args))}")
    return result.stdout


def simulate(step: str, seed: int, data: pathlib.Path) -> dict[str, pathlib.Path]:
    scenario, _ = SCENARIOS[step]
    paths = {name: data / f"{step}-{seed}-{name}.csv" for name in ("ranges", "truth", "heights", "tracks", "motion")}
    if not all(path.is_file() for path in paths.values()):
        args = [BIN / "cdro-sim", "--scenario", scenario, "--seed", seed]
        for name, path in paths.items():
            args += [f"--{name}-csv", path]
        run(args)
    return paths


def hostd(binary: pathlib.Path, paths: dict, trace: pathlib.Path) -> None:
    run([binary, "--ranges-csv", paths["ranges"], "--heights-csv", paths["heights"], "--out-csv",
         trace.with_suffix(".estimates.csv"), "--trace-csv", trace, "--trace-every", "1"])


def carried(step: str, seeds: list[int], binary: pathlib.Path, data: pathlib.Path, out: pathlib.Path) -> list:
    node = SCENARIOS[step][1]
    runs = []
    for seed in seeds:
        paths = simulate(step, seed, data)
        trace = out / f"{step}-{seed}-trace.csv"
        hostd(binary, paths, trace)
        report = json.loads(run([BIN / "cdro-eval-motion", "--trace", trace, "--tracks", paths["tracks"], "--truth",
                                 paths["truth"], "--motion", paths["motion"], "--node", node, "--json", "-"]))["track"]
        runs.append({"seed": seed, "start_seen_after_s": report["start_seen_after_s"][0],
                     "stop_seen_after_s": report["stop_seen_after_s"][0], "p95_m": report["p95_m"],
                     "rmse_m": report["rmse_m"], "reconverged_after_s": report["reconverged_after_s"][0]})
    return runs


def moving_stretches(trace: pathlib.Path) -> list[dict]:
    """Every stretch of a node's trace rows in state `moving`: node, first and last time (s)."""
    stretches, open_ = [], {}
    with open(trace, newline="") as f:
        for row in csv.DictReader(f):
            if row.get("x", "") == "":
                continue
            node, t_s, moving = row["id"], float(row["t"]), row.get("status") == "moving"
            if moving and node not in open_:
                open_[node] = {"node": node, "from_s": t_s, "to_s": t_s}
            elif moving:
                open_[node]["to_s"] = t_s
            elif node in open_:
                stretches.append(open_.pop(node))
    stretches.extend(open_.values())
    return sorted(stretches, key=lambda s: (s["from_s"], s["node"]))


def still(seeds: list[int], binary: pathlib.Path, data: pathlib.Path, out: pathlib.Path) -> list:
    runs = []
    for seed in seeds:
        paths = simulate("still", seed, data)
        trace = out / f"still-{seed}-trace.csv"
        hostd(binary, paths, trace)
        runs.append({"seed": seed, "false_starts": moving_stretches(trace)})
    return runs


def shown(runs: list, key: str) -> str:
    return ", ".join("never" if r[key] is None else f"{r[key]:.2f}" for r in runs)


def within(runs: list, key: str) -> int:
    return sum(1 for r in runs if r[key] is not None and r[key] <= WITHIN_S)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--hostd", type=pathlib.Path, default=ROOT / "build" / "bin" / "cdro-hostd")
    parser.add_argument("--data", type=pathlib.Path, default=ROOT / "out" / "fallback-detector" / "sim",
                        help="where the simulated ranges are made once and kept")
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "out" / "fallback-detector",
                        help="traces and summary.json")
    parser.add_argument("--steps", nargs="+", choices=list(SCENARIOS), default=list(SCENARIOS))
    parser.add_argument("--seeds", type=int, nargs="+", default=list(range(1, 11)))
    args = parser.parse_args()
    args.data.mkdir(parents=True, exist_ok=True)
    args.out.mkdir(parents=True, exist_ok=True)
    summary: dict = {"seeds": args.seeds}
    for step in args.steps:
        if step == "still":
            runs = still(args.seeds, args.hostd, args.data, args.out)
            summary[step] = runs
            starts = [(r["seed"], s) for r in runs for s in r["false_starts"]]
            print(f"still: {len(starts)} false start(s) in {sum(1 for r in runs if r['false_starts'])} of "
                  f"{len(runs)} seeds")
            for seed, s in starts:
                print(f"  seed {seed}: node {s['node']} moving at {s['from_s']:.2f} s for "
                      f"{s['to_s'] - s['from_s']:.2f} s")
            continue
        runs = carried(step, args.seeds, args.hostd, args.data, args.out)
        summary[step] = runs
        p95 = [r["p95_m"] for r in runs if r["p95_m"] is not None]
        print(f"{step}: start seen after (s): {shown(runs, 'start_seen_after_s')}; within 1 s: "
              f"{within(runs, 'start_seen_after_s')}/{len(runs)}")
        print(f"{step}: stop seen after (s):  {shown(runs, 'stop_seen_after_s')}; within 1 s: "
              f"{within(runs, 'stop_seen_after_s')}/{len(runs)}")
        print(f"{step}: track p95 (m): {', '.join(f'{v:.2f}' for v in (r['p95_m'] for r in runs))}; median "
              f"{statistics.median(p95):.3f}; converged again after (s): {shown(runs, 'reconverged_after_s')}")
    with open(args.out / "summary.json", "w") as f:
        json.dump(summary, f, indent=2, sort_keys=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
