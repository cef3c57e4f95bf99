#!/usr/bin/env python3
"""PLANT fed one range at a time to GTSAM iSAM2, next to the CDRO engine in the same run.

The same stream as cdro-bench-engine's first pass: PLANT's 1205 ranges in file order, 3D
ranges projected to the plane with the surveyed heights (sqrt(r^2 - dz^2)). Each range is one
iSAM2 update with one RangeFactor2 (GTSAM's RangeFactor<Point2, Point2>; the Python name
RangeFactor2D is the Pose2-to-Point2 factor) between two Point2 unknowns. There is no global
initializer, as in a streaming system that sees one range at a time:

- the first node starts at (0, 0);
- a node seen for the first time starts at its partner's current estimate plus an offset of
  the measured range in a uniformly random direction (the ring of positions the range allows,
  one point drawn from it); if neither end is known yet, the first end starts at a uniformly
  random point of the current map's bounding box and the second as above;
- every node also gets a weak prior at its starting point (isotropic, --prior-sigma-m, 100 m by
  default). It keeps the system solvable while a node has one range (a circle of solutions)
  and fixes the map's gauge (translation, rotation), and at 100 m against the range's 0.13 m it
  weighs ~1e-6 of one range, so the solution is that of the ranges.

The noise model is robust: Huber (k = 1.345) on sigma 0.13 m (PLANT's robust range sigma,
shared/data/README.md) by default, --loss cauchy|gaussian otherwise. iSAM2 keeps GTSAM's
default parameters (Gauss-Newton, relinearizeThreshold 0.1, relinearizeSkip 10), and runs again
relinearizing at every update (threshold 0.01, skip 1), the costlier setting that range-only
problems are often given; --relinearize THRESHOLD:SKIP chooses others.

Reported per seed: microseconds per range spent in ISAM2.update() (the solver's own cost), the
same including this script's work per range (building the factor, reading an estimate for an
initial value), and the aligned RMSE (rigid fit with reflection, cdro_tools.evaluation) of
calculateEstimate() at the end of the stream, and after --extra-updates further update() calls
with no new factor (iSAM2 given time to converge, like the engine's settle()).

Run on purpose (scripts/bench-engine.sh): needs the optional `gtsam` (tools/pyproject.toml extra
`bench`), never the tests.
"""
from __future__ import annotations

import argparse
import importlib.metadata
import json
import math
import os
import pathlib
import platform
import statistics
import subprocess
import sys
import time

import numpy as np

from cdro_tools.evaluation.alignment import align
from cdro_tools.evaluation.inputs import project_ranges, read_ranges, read_truth

REPO_ROOT = pathlib.Path(__file__).resolve().parents[2]


def find_plant(data_dir: str | None) -> pathlib.Path:
    """--data-dir or $CDRO_DATA_DIR name the folder that holds plant/ (as for the tests and the
    C++ benchmark); a folder holding ranges.csv itself is taken too."""
    base = pathlib.Path(data_dir or os.environ.get("CDRO_DATA_DIR") or REPO_ROOT.parent / "shared" / "data")
    return base if (base / "ranges.csv").exists() else base / "plant"


def noise_model(gtsam, loss: str, sigma_m: float):
    gaussian = gtsam.noiseModel.Isotropic.Sigma(1, sigma_m)
    if loss == "gaussian":
        return gaussian
    if loss == "huber":
        return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.345), gaussian)
    return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(1.0), gaussian)


def run_isam2(gtsam, stream, truth_m, seed: int, loss: str, sigma_m: float, prior_sigma_m: float,
              extra_updates: int, relinearize_threshold: float, relinearize_skip: int) -> dict:
    rng = np.random.default_rng(seed)
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(relinearize_threshold)
    params.relinearizeSkip = relinearize_skip
    isam = gtsam.ISAM2(params)
    range_noise = noise_model(gtsam, loss, sigma_m)
    prior_noise = gtsam.noiseModel.Isotropic.Sigma(2, prior_sigma_m)
    known: set[int] = set()
    update_ns = 0
    update_cpu_ns = 0  # process CPU time: all of GTSAM's threads, if it runs any
    total_ns = 0
    failures = 0

    def random_offset(range_m: float) -> np.ndarray:
        angle = rng.uniform(0.0, 2.0 * math.pi)
        return range_m * np.array([math.cos(angle), math.sin(angle)])

    for a, b, r in stream:
        start = time.perf_counter_ns()
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        new: dict[int, np.ndarray] = {}
        if a not in known and b not in known:
            if not known:
                new[a] = np.zeros(2)
            else:
                current = np.array([isam.calculateEstimatePoint2(k) for k in sorted(known)])
                new[a] = rng.uniform(current.min(axis=0), current.max(axis=0))
            new[b] = new[a] + random_offset(r)
        elif a not in known:
            new[a] = isam.calculateEstimatePoint2(b) + random_offset(r)
        elif b not in known:
            new[b] = isam.calculateEstimatePoint2(a) + random_offset(r)
        for key, start_m in new.items():
            values.insert(key, start_m)
            graph.add(gtsam.PriorFactorPoint2(key, start_m, prior_noise))
            known.add(key)
        graph.add(gtsam.RangeFactor2(a, b, r, range_noise))
        before_update = time.perf_counter_ns()
        before_update_cpu = time.process_time_ns()
        try:
            isam.update(graph, values)
        except RuntimeError:
            # An indeterminate system (not expected with the priors): counted, the stream goes on
            # without this range.
            failures += 1
        update_cpu_ns += time.process_time_ns() - before_update_cpu
        end = time.perf_counter_ns()
        update_ns += end - before_update
        total_ns += end - start

    def rmse_now() -> tuple[float, int]:
        estimate = isam.calculateEstimate()
        positions = {k: estimate.atPoint2(k) for k in known}
        alignment = align(positions, truth_m)
        return alignment.rmse_m, alignment.nodes

    rmse_m, nodes = rmse_now()
    extra_ns = 0
    for _ in range(extra_updates):
        start = time.perf_counter_ns()
        isam.update()
        extra_ns += time.perf_counter_ns() - start
    rmse_extra_m, _ = rmse_now()
    n = len(stream)
    return {
        "seed": seed,
        "ranges": n,
        "nodes": nodes,
        "update_us_per_range": update_ns / n / 1e3,
        "update_cpu_us_per_range": update_cpu_ns / n / 1e3,
        "total_us_per_range": total_ns / n / 1e3,
        "stream_s": total_ns / 1e9,
        "failed_updates": failures,
        "rmse_m": rmse_m,
        "rmse_after_extra_updates_m": rmse_extra_m,
        "extra_updates": extra_updates,
        "extra_updates_s": extra_ns / 1e9,
    }


def cpu_model() -> str:
    try:
        for line in pathlib.Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def write_json(report: dict, path: str) -> None:
    """A report as indented JSON: to stdout for '-', else into the file `path`."""
    text = json.dumps(report, indent=2)
    if path == "-":
        print(text)
    else:
        pathlib.Path(path).write_text(text + "\n")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--engine-bin", default=str(REPO_ROOT / "build-bench" / "bin" / "cdro-bench-engine"),
                        help="the C++ benchmark, run first in this invocation (default: %(default)s)")
    parser.add_argument("--data-dir", help="folder that holds plant/ (default $CDRO_DATA_DIR, else ../shared/data)")
    parser.add_argument("--passes", type=int, default=100, help="engine: PLANT passes per repeat (%(default)s)")
    parser.add_argument("--repeat", type=int, default=5, help="engine: repeats, median reported (%(default)s)")
    parser.add_argument("--seed", type=int, default=1, help="iSAM2: seed of the first run's starting points")
    parser.add_argument("--seeds", type=int, default=5, help="iSAM2: runs, seeds seed..seed+N-1 (%(default)s)")
    parser.add_argument("--loss", choices=["huber", "cauchy", "gaussian"], default="huber")
    parser.add_argument("--sigma-m", type=float, default=0.13, help="m, range sigma of the factors (%(default)s)")
    parser.add_argument("--prior-sigma-m", type=float, default=100.0,
                        help="m, the weak prior on each node's starting point (%(default)s)")
    parser.add_argument("--relinearize", metavar="THRESHOLD:SKIP", action="append",
                        help="an iSAM2 configuration: relinearizeThreshold and relinearizeSkip; repeat for more "
                             "(default: GTSAM's own 0.1:10, and 0.01:1, relinearizing at every update)")
    parser.add_argument("--extra-updates", type=int, default=20,
                        help="update() calls without new factors after the stream (%(default)s)")
    parser.add_argument("--json", metavar="PATH", help="write every figure here ('-' for stdout, the table to stderr)")
    args = parser.parse_args(argv)
    out = sys.stderr if args.json == "-" else sys.stdout

    try:
        import gtsam
    except ImportError:
        print("isam2_compare: needs gtsam (the optional extra `bench`: .venv/bin/pip install gtsam, "
              "or scripts/bench-engine.sh, which installs it)", file=sys.stderr)
        return 2

    plant = find_plant(args.data_dir)
    bad: list = []
    truth_m, heights_m = read_truth(str(plant / "nodes.csv"), bad)
    projection = project_ranges(read_ranges(str(plant / "ranges.csv"), bad), heights_m)
    if bad:
        for row in bad:
            print(f"isam2_compare: {row.path}:{row.line}: {row.message}", file=sys.stderr)
        return 2
    ranges = projection.ranges
    stream = list(zip(ranges.from_ids.tolist(), ranges.to_ids.tolist(), ranges.range_m.tolist()))

    # Our engine first, in this same invocation, on the same data.
    command = [args.engine_bin, "--plant-only", "--json", "--passes", str(args.passes), "--repeat", str(args.repeat),
               "--data-dir", str(plant)]
    print("running: " + " ".join(command), file=out, flush=True)
    engine = json.loads(subprocess.run(command, check=True, stdout=subprocess.PIPE, text=True).stdout)
    engine_plant = engine["plant"]

    configurations = []
    for text in args.relinearize or ["0.1:10", "0.01:1"]:
        threshold, _, skip = text.partition(":")
        configurations.append({"relinearize_threshold": float(threshold), "relinearize_skip": int(skip or 1)})
    for config in configurations:
        runs = []
        for seed in range(args.seed, args.seed + args.seeds):
            run = run_isam2(gtsam, stream, truth_m, seed, args.loss, args.sigma_m, args.prior_sigma_m,
                            args.extra_updates, config["relinearize_threshold"], config["relinearize_skip"])
            runs.append(run)
            print(f"iSAM2 {config['relinearize_threshold']}:{config['relinearize_skip']} seed {seed}: "
                  f"{run['update_us_per_range']:.0f} us/range in update() "
                  f"({run['total_us_per_range']:.0f} with the script's own work), RMSE {run['rmse_m']:.2f} m "
                  f"({run['rmse_after_extra_updates_m']:.2f} m after {args.extra_updates} more updates)"
                  + (f", {run['failed_updates']} failed updates" if run["failed_updates"] else ""),
                  file=out, flush=True)
        rmses = [r["rmse_m"] for r in runs]
        extra = [r["rmse_after_extra_updates_m"] for r in runs]
        config.update({
            "update_us_per_range_median": statistics.median(r["update_us_per_range"] for r in runs),
            "update_cpu_us_per_range_median": statistics.median(r["update_cpu_us_per_range"] for r in runs),
            "total_us_per_range_median": statistics.median(r["total_us_per_range"] for r in runs),
            "rmse_m_min": min(rmses), "rmse_m_median": statistics.median(rmses), "rmse_m_max": max(rmses),
            "rmse_after_extra_updates_m_min": min(extra), "rmse_after_extra_updates_m_max": max(extra),
            "runs": runs,
        })

    def fmt(accuracy: dict) -> str:
        value = accuracy["rmse_m"]
        text = "n/a" if value is None or not math.isfinite(value) else f"{value:.3f}"
        if accuracy["placed"] != accuracy["nodes"]:
            text += f" ({accuracy['placed']}/{accuracy['nodes']} placed)"
        return text

    machine = engine["machine"]
    try:
        gtsam_version = importlib.metadata.version("gtsam")
    except importlib.metadata.PackageNotFoundError:
        gtsam_version = "(version unknown)"
    print(f"\nPLANT, {len(stream)} ranges in file order, heights known; {machine['cpu']}, {machine['nproc']} cores; "
          f"engine {machine['build_type']} build; GTSAM {gtsam_version} from PyPI, {args.loss} loss on "
          f"sigma {args.sigma_m} m, {args.seeds} seeds of starting points",
          file=out)
    rows = [
        ("CDRO engine, one pass (builds the map)",
         f"{engine_plant['first_pass_us_per_range_median']:.1f}",
         f"{engine_plant['first_pass_cpu_us_per_range_median']:.1f}",
         f"{fmt(engine_plant['accuracy_after_first_pass'])} live, "
         f"{fmt(engine_plant['accuracy_after_first_pass_settled'])} settled"),
        (f"CDRO engine, steady state (passes 2..{engine_plant['passes']})",
         f"{engine_plant['steady_us_per_range_median']:.2f}", f"{engine_plant['steady_cpu_us_per_range_median']:.2f}",
         f"{fmt(engine_plant['accuracy_end'])} at the end"),
    ]
    for config in configurations:
        rows.append((f"GTSAM iSAM2, one pass, relinearize {config['relinearize_threshold']}:"
                     f"{config['relinearize_skip']}",
                     f"{config['update_us_per_range_median']:.0f} ({config['total_us_per_range_median']:.0f})",
                     f"{config['update_cpu_us_per_range_median']:.0f}",
                     f"{config['rmse_m_min']:.2f}-{config['rmse_m_max']:.2f} (median {config['rmse_m_median']:.2f}); "
                     f"{config['rmse_after_extra_updates_m_min']:.2f}-{config['rmse_after_extra_updates_m_max']:.2f} "
                     f"after {args.extra_updates} more updates"))
    width = max(len(r[0]) for r in rows)
    print(f"{'method':<{width}}  {'us/range':>11}  {'CPU us':>7}  aligned RMSE (m)", file=out)
    for name, us, cpu_us, rmse in rows:
        print(f"{name:<{width}}  {us:>11}  {cpu_us:>7}  {rmse}", file=out)

    first_us = engine_plant["first_pass_us_per_range_median"]
    steady_us = engine_plant["steady_us_per_range_median"]
    first_cpu_us = engine_plant["first_pass_cpu_us_per_range_median"]
    steady_cpu_us = engine_plant["steady_cpu_us_per_range_median"]
    ratios = "; ".join(
        f"{c['relinearize_threshold']}:{c['relinearize_skip']} {c['update_us_per_range_median'] / first_us:.0f}x / "
        f"{c['update_us_per_range_median'] / steady_us:.0f}x (CPU time "
        f"{c['update_cpu_us_per_range_median'] / first_cpu_us:.0f}x / "
        f"{c['update_cpu_us_per_range_median'] / steady_cpu_us:.0f}x)" for c in configurations)
    print(f"us/range: wall clock; CPU us: process CPU time per range. Engine: median of {engine_plant['repeats']} "
          f"repeats; iSAM2: median of the seeds, in update() (in parentheses with this script's own work per range). "
          f"relinearize T:S = relinearizeThreshold T, relinearizeSkip S (0.1:10 is GTSAM's default). iSAM2 per range "
          f"against the engine's first pass / steady state: {ratios}.", file=out)

    if args.json:
        report = {
            "machine": machine,
            "gtsam": gtsam_version,
            "settings": {"loss": args.loss, "sigma_m": args.sigma_m, "prior_sigma_m": args.prior_sigma_m,
                         "seeds": list(range(args.seed, args.seed + args.seeds)),
                         "extra_updates": args.extra_updates},
            "isam2": configurations,
            "engine": engine_plant,
        }
        write_json(report, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
