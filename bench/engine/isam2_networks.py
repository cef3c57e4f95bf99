#!/usr/bin/env python3
"""Random networks fed one range at a time to GTSAM iSAM2 and solved in batch by GTSAM's
Levenberg-Marquardt, next to the CDRO engine on the same stream in the same run (issue 18).

For each size (--sizes, 100 and 1000 nodes by default) the engine runs first, as
`cdro-bench-engine --one-network N --seed S --write-csv DIR`: one random geometric network (mean
degree 10, 0.1 m Gaussian range noise, planar), every link ranged once per sweep in the same
order, sweep after sweep. It reports its warm-up (the first --warmup-sweeps sweeps, 4 by default:
where the map is built) and its steady state (the sweeps after, up to --min-sweeps /
--steady-ranges) in us per range, wall clock and CPU time, and its aligned RMSE at the end. The
stream it was fed comes back as DIR/ranges.csv, the truth as DIR/truth.csv. A second, short engine
run on the same seed (--warmup-sweeps K --min-sweeps K --steady-ranges 0; off with
--no-engine-short-run) stops after the K sweeps the GTSAM solvers get, so that its RMSE is over
exactly the ranges they saw (the stream is drawn from the seed: the short run's ranges are the
first K sweeps of the long run's, which is checked).

The GTSAM side gets the first --isam2-sweeps K sweeps of that stream (K x links ranges; K = 4 by
default, the engine's warm-up), at most --isam2-max-ranges of them when that cap is set (printed):

- iSAM2: isam2_compare.run_isam2, unchanged (imported from this folder): one ISAM2.update() per
  range with one RangeFactor2 between two Point2 unknowns, its streaming initialization (a new
  node at its partner's current estimate plus the measured range in a random direction, seeded by
  --isam2-seed .. + --seeds - 1), a weak prior (--prior-sigma-m, 100 m) at every node's starting
  point, Huber (k = 1.345) on sigma 0.1 m (--sigma-m: the networks' noise), GTSAM's default
  parameters (relinearizeThreshold 0.1, relinearizeSkip 10; --relinearize THRESHOLD:SKIP for
  others). Reported: us per range in update() (wall and process CPU time; in parentheses with the
  script's own work per range), the aligned RMSE of calculateEstimate() at the end of the ranges
  and after --extra-updates more update() calls without new factors. The ISAM2 object is an
  instance of a subclass that only records itself (the methods are GTSAM's, nothing is wrapped),
  so that its factors and estimate can be read after the run: the priors it holds are at the
  starting points the streaming initialization chose, which is how the batch runs get them.
- Batch LM: LevenbergMarquardtOptimizer (GTSAM's default parameters) over one RangeFactor2 per
  range fed to iSAM2 (the same robust noise model) plus the same weak priors at the same starting
  points; once from those starting points (what iSAM2 started from), once from iSAM2's final
  estimate (after the extra updates). Reported: wall and CPU time of building the optimizer and
  optimize(), as a total and per range fed, the iterations, and the aligned RMSE. For reference
  (not a contender: no streaming system knows it; off with --no-lm-from-truth), the same
  ranges with the weak priors at the true positions, started there: the maximum-likelihood map
  next to the truth, what these ranges allow at best.

Accuracy is the rigid fit with reflection of cdro_tools.evaluation.alignment.align over every node
a method placed (iSAM2 and LM place every node that has a range, also a node with one link, which
its ranges cannot fix; the engine leaves such a node out), with the median error beside it. The
ratios are iSAM2's us per range against the engine's warm-up and steady state, and LM's time
against the engine's warm-up (the same ranges, or as many sweeps) and against iSAM2's stream.

--tables-from PATH prints the tables and ratios of a report written by --json again, running nothing.

Run on purpose, pinned to one CPU (taskset -c 1 .venv/bin/python bench/engine/isam2_networks.py):
needs the optional `gtsam` (tools/pyproject.toml extra `bench`), never the tests.
"""
from __future__ import annotations

import argparse
import csv
import hashlib
import importlib.metadata
import json
import math
import os
import pathlib
import platform
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

from cdro_tools.evaluation.alignment import align
from cdro_tools.evaluation.inputs import read_truth

HERE = pathlib.Path(__file__).resolve().parent
REPO_ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE))
from isam2_compare import cpu_model, noise_model, run_isam2, write_json  # noqa: E402


class KeepingGtsam:
    """The gtsam module as run_isam2 sees it, except that every ISAM2 it builds is kept (in
    .made): a subclass whose only addition is recording itself. update() and the estimates are
    GTSAM's own methods, timed exactly as in isam2_compare."""

    def __init__(self, gtsam):
        self._gtsam = gtsam
        self.made: list = []
        keeper = self

        class KeptISAM2(gtsam.ISAM2):
            def __init__(self, params):
                super().__init__(params)
                keeper.made.append(self)

        self.ISAM2 = KeptISAM2

    def __getattr__(self, name: str):
        return getattr(self._gtsam, name)


def per_size(text: str | None, sizes: list[int], name: str, kind=int) -> list | None:
    """A comma list with one value for every size, or one value for all; None when not given."""
    if text is None:
        return None
    values = [kind(v) for v in text.split(",")]
    if len(values) == 1:
        return values * len(sizes)
    if len(values) != len(sizes):
        raise SystemExit(f"isam2_networks: {name} has {len(values)} values for {len(sizes)} sizes")
    return values


def read_stream(path: pathlib.Path, limit: int) -> list[tuple[int, int, float]]:
    """The first `limit` rows of a `from,to,range_m` file (the engine writes %.17g: exact doubles)."""
    stream = []
    with path.open(newline="") as file:
        rows = csv.reader(file)
        if next(rows) != ["from", "to", "range_m"]:
            raise SystemExit(f"isam2_networks: {path}: not the engine's from,to,range_m")
        for row in rows:
            if len(stream) >= limit:
                break
            stream.append((int(row[0]), int(row[1]), float(row[2])))
    return stream


def accuracy(positions_m: dict[int, np.ndarray], truth_m: dict[int, np.ndarray],
             stream: list[tuple[int, int, float]]) -> dict:
    """Aligned RMSE and median error over the nodes given, nodes over 1 m off, and how well the map
    explains the ranges it was given (RMS of measured range - distance in the map)."""
    alignment = align(positions_m, truth_m)
    errors = list(alignment.errors_m.values())
    residuals = [r - float(np.linalg.norm(positions_m[a] - positions_m[b])) for a, b, r in stream
                 if a in positions_m and b in positions_m]
    return {
        "rmse_m": alignment.rmse_m,
        "median_error_m": statistics.median(errors) if errors else None,
        "nodes_over_1m": sum(e > 1.0 for e in errors),
        "placed": alignment.nodes,
        "nodes": len(truth_m),
        "range_residual_rms_m": math.sqrt(sum(x * x for x in residuals) / len(residuals)) if residuals else None,
        "ranges_residual_over_0_5m": sum(abs(x) > 0.5 for x in residuals),
    }


def estimate_positions(gtsam, values) -> dict[int, np.ndarray]:
    return {key: np.asarray(values.atPoint2(key)) for key in values.keys()}


def run_lm(gtsam, graph, initial, max_iterations: int, truth_m, stream) -> dict:
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    start = time.perf_counter_ns()
    start_cpu = time.process_time_ns()
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    result = optimizer.optimize()
    cpu_ns = time.process_time_ns() - start_cpu
    wall_ns = time.perf_counter_ns() - start
    n = len(stream)
    return {
        "wall_s": wall_ns / 1e9,
        "cpu_s": cpu_ns / 1e9,
        "wall_us_per_range": wall_ns / n / 1e3,
        "cpu_us_per_range": cpu_ns / n / 1e3,
        "iterations": optimizer.iterations(),
        "error_initial": graph.error(initial),
        "error_final": graph.error(result),
        "accuracy": accuracy(estimate_positions(gtsam, result), truth_m, stream),
    }


def gtsam_side(gtsam, stream, truth_m, config: dict, seed: int, args, out) -> dict:
    """One iSAM2 run (run_isam2), then the two LM runs on the same factors."""
    keeper = KeepingGtsam(gtsam)
    label = f"iSAM2 {config['relinearize_threshold']}:{config['relinearize_skip']} seed {seed}"
    print(f"  {label}: {len(stream)} ranges ...", file=out, flush=True)
    run = run_isam2(keeper, stream, truth_m, seed, args.loss, args.sigma_m, args.prior_sigma_m,
                    args.extra_updates, config["relinearize_threshold"], config["relinearize_skip"])
    isam = keeper.made[-1]
    estimate = isam.calculateEstimate()
    run["accuracy_after_extra_updates"] = accuracy(estimate_positions(gtsam, estimate), truth_m, stream)
    print(f"  {label}: {run['update_us_per_range']:.0f} us/range in update() "
          f"({run['update_cpu_us_per_range']:.0f} CPU, {run['total_us_per_range']:.0f} with the script's own work), "
          f"{run['stream_s']:.1f} s; RMSE {run['rmse_m']:.3f} m at the end, "
          f"{run['rmse_after_extra_updates_m']:.3f} m after {args.extra_updates} more updates"
          + (f"; {run['failed_updates']} failed updates" if run["failed_updates"] else ""), file=out, flush=True)

    # The starting points: the priors iSAM2 was given sit at them (one per node, added with it).
    held = isam.getFactorsUnsafe()
    initial = gtsam.Values()
    for i in range(held.size()):
        factor = held.at(i)
        if isinstance(factor, gtsam.PriorFactorPoint2):
            initial.insert(factor.keys()[0], factor.prior())
    # The batch problem, built anew: one factor per range fed, the same priors.
    range_noise = noise_model(gtsam, args.loss, args.sigma_m)
    prior_noise = gtsam.noiseModel.Isotropic.Sigma(2, args.prior_sigma_m)
    graph = gtsam.NonlinearFactorGraph()
    for a, b, r in stream:
        graph.add(gtsam.RangeFactor2(a, b, r, range_noise))
    for key in initial.keys():
        graph.add(gtsam.PriorFactorPoint2(key, initial.atPoint2(key), prior_noise))
    check = {"batch_factors": graph.size(), "isam2_factors": held.size(),
             "batch_error_at_start": graph.error(initial), "isam2_error_at_start": held.error(initial)}
    run["start_accuracy"] = accuracy(estimate_positions(gtsam, initial), truth_m, stream)
    lm_start = run_lm(gtsam, graph, initial, args.lm_max_iterations, truth_m, stream)
    print(f"  LM from the same starting points (RMSE {run['start_accuracy']['rmse_m']:.1f} m there): "
          f"{lm_start['wall_s']:.2f} s ({lm_start['cpu_s']:.2f} CPU), {lm_start['iterations']} iterations, "
          f"RMSE {lm_start['accuracy']['rmse_m']:.3f} m", file=out, flush=True)
    lm_isam2 = run_lm(gtsam, graph, estimate, args.lm_max_iterations, truth_m, stream)
    print(f"  LM from iSAM2's estimate: {lm_isam2['wall_s']:.2f} s ({lm_isam2['cpu_s']:.2f} CPU), "
          f"{lm_isam2['iterations']} iterations, RMSE {lm_isam2['accuracy']['rmse_m']:.3f} m", file=out, flush=True)
    keeper.made.clear()
    return {"isam2": run, "lm_from_start": lm_start, "lm_from_isam2": lm_isam2, "graph_check": check}


def run_engine(command: list[str], out) -> dict:
    print("  running: " + " ".join(command), file=out, flush=True)
    start = time.perf_counter()
    result = json.loads(subprocess.run(command, check=True, stdout=subprocess.PIPE, text=True).stdout)
    print(f"  ... {time.perf_counter() - start:.0f} s", file=out, flush=True)
    return result


def per_range_us(timed: dict, key: str) -> float | None:
    return timed[key] / timed["ranges"] * 1e6 if timed["ranges"] else None


def median_sweep_us(engine: dict) -> float | None:
    """us per range of the steady state's median sweep (wall clock): the typical sweep, without the
    few calls that run a global solve, which the mean over the steady state holds."""
    rate = engine.get("steady_sweep_rate_median")
    return 1e6 / rate if rate else None


def span(values: list[float], digits: int) -> str:
    """min-max (median) of the seeds, or the one value."""
    values = [v for v in values if v is not None]
    if not values:
        return "n/a"
    if len(values) == 1 or min(values) == max(values):
        return f"{values[0]:.{digits}f}"
    return f"{min(values):.{digits}f}-{max(values):.{digits}f} (med {statistics.median(values):.{digits}f})"


def metres(value: float | None) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.3f}"


def engine_rmse(acc: dict) -> str:
    return metres(acc["rmse_m"])


def run_size(gtsam, nodes: int, index: int, args, options: dict, work: pathlib.Path, out) -> dict:
    print(f"\n=== {nodes} nodes, network seed {args.seed}", file=out, flush=True)
    folder = work / f"n{nodes}"
    folder.mkdir(parents=True, exist_ok=True)
    base = [args.engine_bin, "--one-network", str(nodes), "--seed", str(args.seed), "--json",
            "--warmup-sweeps", str(args.warmup_sweeps)]
    long_options = []
    if options["min_sweeps"] is not None:
        long_options += ["--min-sweeps", str(options["min_sweeps"][index])]
    if options["steady_ranges"] is not None:
        long_options += ["--steady-ranges", str(options["steady_ranges"][index])]
    engine = run_engine(base + long_options + ["--write-csv", str(folder)], out)
    links = engine["links"]
    sweeps = args.isam2_sweeps
    if sweeps > engine["sweeps"]:
        raise SystemExit(f"isam2_networks: --isam2-sweeps {sweeps} > the engine's {engine['sweeps']} sweeps")
    limit = sweeps * links
    capped = bool(args.isam2_max_ranges) and args.isam2_max_ranges < limit
    if capped:
        limit = args.isam2_max_ranges
    stream = read_stream(folder / "ranges.csv", limit)
    bad: list = []
    truth_m, _ = read_truth(str(folder / "truth.csv"), bad)
    if bad:
        raise SystemExit(f"isam2_networks: {folder / 'truth.csv'}: {bad[0].message}")
    fed = f"{len(stream)} ranges = {len(stream) / links:.2f} sweeps of {links} links"
    if capped:
        fed += f" (CAPPED by --isam2-max-ranges {args.isam2_max_ranges}: {sweeps} sweeps would be {sweeps * links})"
    print(f"  GTSAM fed the first {fed}", file=out, flush=True)

    short = None
    if args.engine_short_run:
        short_folder = work / f"n{nodes}-short"
        short_folder.mkdir(parents=True, exist_ok=True)
        short = run_engine([args.engine_bin, "--one-network", str(nodes), "--seed", str(args.seed), "--json",
                            "--warmup-sweeps", str(sweeps), "--min-sweeps", str(sweeps), "--steady-ranges", "0",
                            "--write-csv", str(short_folder)], out)
        same = read_stream(short_folder / "ranges.csv", sweeps * links) == read_stream(folder / "ranges.csv",
                                                                                      sweeps * links)
        short["same_stream_as_long_run"] = same
        if not same:
            print("  WARNING: the short engine run was not fed the long run's first sweeps", file=out, flush=True)

    configurations = []
    for text in args.relinearize or ["0.1:10"]:
        threshold, _, skip = text.partition(":")
        config = {"relinearize_threshold": float(threshold), "relinearize_skip": int(skip or 1), "runs": []}
        for seed in range(args.isam2_seed, args.isam2_seed + options["seeds"][index]):
            config["runs"].append(gtsam_side(gtsam, stream, truth_m, config, seed, args, out))
        configurations.append(config)
    oracle = None
    if args.lm_from_truth:
        # A reference, not a contender: the same ranges, the weak priors at the true positions
        # (not at the streaming starting points: those would drag a node with one link along its
        # circle and the map's frame towards a scrambled one), started at the true positions: the
        # maximum-likelihood map next to the truth, what these ranges allow at best.
        range_noise = noise_model(gtsam, args.loss, args.sigma_m)
        prior_noise = gtsam.noiseModel.Isotropic.Sigma(2, args.prior_sigma_m)
        graph = gtsam.NonlinearFactorGraph()
        start = gtsam.Values()
        for a, b, r in stream:
            graph.add(gtsam.RangeFactor2(a, b, r, range_noise))
        for key in sorted({a for a, _, _ in stream} | {b for _, b, _ in stream}):
            start.insert(key, truth_m[key])
            graph.add(gtsam.PriorFactorPoint2(key, truth_m[key], prior_noise))
        oracle = run_lm(gtsam, graph, start, args.lm_max_iterations, truth_m, stream)
        print(f"  LM from the true positions (reference): {oracle['wall_s']:.2f} s, {oracle['iterations']} "
              f"iterations, RMSE {oracle['accuracy']['rmse_m']:.3f} m", file=out, flush=True)

    result = {"nodes": nodes, "links": links, "engine_sweeps": engine["sweeps"], "gtsam_sweeps": len(stream) / links,
              "gtsam_ranges": len(stream), "capped": capped, "engine": engine, "engine_short_run": short,
              "gtsam": configurations, "lm_from_truth": oracle}
    print_table(result, args, out)
    return result


def print_table(result: dict, args, out) -> None:
    engine = result["engine"]
    short = result["engine_short_run"]
    warm, steady = engine["warmup"], engine["steady"]
    warm_us, warm_cpu_us = per_range_us(warm, "wall_s"), per_range_us(warm, "cpu_s")
    steady_us, steady_cpu_us = per_range_us(steady, "wall_s"), per_range_us(steady, "cpu_s")
    n = result["gtsam_ranges"]

    def placed(acc: dict) -> str:
        return f"{acc['placed']}/{acc['nodes']}"

    rows = [("CDRO engine, warm-up: sweeps 1-%d (builds the map)" % engine["warmup_sweeps"],
             f"{warm_us:.0f}", f"{warm_cpu_us:.0f}", f"{warm['wall_s']:.1f}",
             (f"{engine_rmse(short['accuracy_end'])} live, {engine_rmse(short['accuracy_end_settled'])} settled "
              f"(med {metres(short['accuracy_end']['median_error_m'])})" if short else "(no short run)"),
             placed(short["accuracy_end"]) if short else "")]
    if steady["ranges"]:
        typical_us = median_sweep_us(engine)
        rows.append((f"CDRO engine, steady: sweeps {engine['warmup_sweeps'] + 1}-{engine['sweeps']}",
                     f"{steady_us:.0f}" + (f" ({typical_us:.0f})" if typical_us else ""), f"{steady_cpu_us:.0f}",
                     f"{steady['wall_s']:.1f}",
                     f"{engine_rmse(engine['accuracy_end'])} live, {engine_rmse(engine['accuracy_end_settled'])} "
                     f"settled (med {metres(engine['accuracy_end']['median_error_m'])}), at sweep {engine['sweeps']}",
                     placed(engine["accuracy_end"])))
    for config in result["gtsam"]:
        name = f"{config['relinearize_threshold']}:{config['relinearize_skip']}"
        runs = config["runs"]
        isam = [r["isam2"] for r in runs]
        rows.append((f"GTSAM iSAM2 {name}, one update per range",
                     f"{statistics.median(r['update_us_per_range'] for r in isam):.0f} "
                     f"({statistics.median(r['total_us_per_range'] for r in isam):.0f})",
                     f"{statistics.median(r['update_cpu_us_per_range'] for r in isam):.0f}",
                     f"{statistics.median(r['stream_s'] for r in isam):.1f}",
                     f"{span([r['rmse_m'] for r in isam], 3)}; "
                     f"{span([r['rmse_after_extra_updates_m'] for r in isam], 3)} after "
                     f"{args.extra_updates} more updates (med err "
                     f"{span([r['accuracy_after_extra_updates']['median_error_m'] for r in isam], 3)})",
                     placed(isam[0]["accuracy_after_extra_updates"])))
        for key, what in (("lm_from_start", "from iSAM2's starting points"), ("lm_from_isam2", "from iSAM2's result")):
            lm = [r[key] for r in runs]
            rows.append((f"GTSAM batch LM {what} ({name})",
                         f"{statistics.median(r['wall_us_per_range'] for r in lm):.0f}",
                         f"{statistics.median(r['cpu_us_per_range'] for r in lm):.0f}",
                         f"{statistics.median(r['wall_s'] for r in lm):.2f}",
                         f"{span([r['accuracy']['rmse_m'] for r in lm], 3)} (med err "
                         f"{span([r['accuracy']['median_error_m'] for r in lm], 3)}), "
                         f"{span([r['iterations'] for r in lm], 0)} iterations",
                         placed(lm[0]["accuracy"])))
    oracle = result["lm_from_truth"]
    if oracle:
        rows.append(("reference: batch LM from the true positions", f"{oracle['wall_us_per_range']:.0f}",
                     f"{oracle['cpu_us_per_range']:.0f}", f"{oracle['wall_s']:.2f}",
                     f"{metres(oracle['accuracy']['rmse_m'])} (med err {metres(oracle['accuracy']['median_error_m'])}),"
                     f" {oracle['iterations']} iterations", placed(oracle["accuracy"])))
    print(f"\n{result['nodes']} nodes, {result['links']} links; GTSAM: the first {n} ranges "
          f"({result['gtsam_sweeps']:.2f} sweeps{', CAPPED' if result['capped'] else ''}), "
          f"{len(result['gtsam'][0]['runs'])} seed(s) of starting points", file=out)
    header = ("method", "us/range", "CPU us", "total s", "aligned RMSE (m)", "placed")
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]
    for row in [header, *rows]:
        print(f"{row[0]:<{widths[0]}}  {row[1]:>{widths[1]}}  {row[2]:>{widths[2]}}  {row[3]:>{widths[3]}}  "
              f"{row[4]:<{widths[4]}}  {row[5]}", file=out)
    ratios = ratios_of(result)
    for line in ratios["text"]:
        print(line, file=out)
    result["ratios"] = ratios["figures"]
    out.flush()


def ratios_of(result: dict) -> dict:
    engine = result["engine"]
    warm, steady = engine["warmup"], engine["steady"]
    warm_us, warm_cpu_us = per_range_us(warm, "wall_s"), per_range_us(warm, "cpu_s")
    steady_us, steady_cpu_us = per_range_us(steady, "wall_s"), per_range_us(steady, "cpu_s")
    typical_us = median_sweep_us(engine)
    text, figures = [], []
    for config in result["gtsam"]:
        name = f"{config['relinearize_threshold']}:{config['relinearize_skip']}"
        runs = config["runs"]
        isam_us = statistics.median(r["isam2"]["update_us_per_range"] for r in runs)
        isam_cpu_us = statistics.median(r["isam2"]["update_cpu_us_per_range"] for r in runs)
        isam_s = statistics.median(r["isam2"]["stream_s"] for r in runs)
        lm_us = statistics.median(r["lm_from_start"]["wall_us_per_range"] for r in runs)
        lm_s = statistics.median(r["lm_from_start"]["wall_s"] for r in runs)
        figure = {
            "relinearize": name,
            "isam2_over_engine_warmup_wall": isam_us / warm_us,
            "isam2_over_engine_warmup_cpu": isam_cpu_us / warm_cpu_us,
            "isam2_over_engine_steady_wall": isam_us / steady_us if steady_us else None,
            "isam2_over_engine_steady_cpu": isam_cpu_us / steady_cpu_us if steady_cpu_us else None,
            "isam2_over_engine_steady_median_sweep_wall": isam_us / typical_us if typical_us else None,
            "lm_per_range_over_engine_warmup_per_range_wall": lm_us / warm_us,
            "lm_over_isam2_stream_wall": lm_s / isam_s,
        }
        figures.append(figure)
        steady_text = (f", {figure['isam2_over_engine_steady_wall']:.1f}x its steady state "
                       f"({figure['isam2_over_engine_steady_cpu']:.1f}x in CPU time), "
                       f"{figure['isam2_over_engine_steady_median_sweep_wall']:.0f}x its median steady sweep"
                       if steady_us and typical_us else "")
        text.append(f"iSAM2 {name} per range: {figure['isam2_over_engine_warmup_wall']:.2f}x the engine's warm-up "
                    f"({figure['isam2_over_engine_warmup_cpu']:.2f}x in CPU time){steady_text}. Batch LM (from the "
                    f"starting points), per range fed: {figure['lm_per_range_over_engine_warmup_per_range_wall']:.3f}x "
                    f"the engine's warm-up per range; {figure['lm_over_isam2_stream_wall']:.3f}x iSAM2's whole stream.")
    text.append("us/range: wall clock (iSAM2: in update(), in parentheses with this script's own work; engine's "
                "steady state: the mean, in parentheses its median sweep; LM: its time / ranges fed); CPU us: "
                "process CPU time per range; total s: the warm-up's, the steady state's, iSAM2's stream, one LM "
                "solve (medians of the seeds). Engine RMSE: over the nodes it placed, live and after settle(); the "
                "warm-up row's RMSE is from the short run (the same ranges as GTSAM's when not capped).")
    return {"text": text, "figures": figures}


def machine_info(engine_bin: str) -> dict:
    binary = pathlib.Path(engine_bin)
    build_type = None
    cache = binary.resolve().parent.parent / "CMakeCache.txt"
    if cache.exists():
        for line in cache.read_text().splitlines():
            if line.startswith("CMAKE_BUILD_TYPE:"):
                build_type = line.split("=", 1)[1]
    try:
        commit = subprocess.run(["git", "-C", str(REPO_ROOT), "rev-parse", "HEAD"], check=True,
                                stdout=subprocess.PIPE, text=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = None
    try:
        gtsam_version = importlib.metadata.version("gtsam")
    except importlib.metadata.PackageNotFoundError:
        gtsam_version = None
    return {
        "cpu": cpu_model(),
        "nproc": os.cpu_count(),
        "affinity": sorted(os.sched_getaffinity(0)),
        "loadavg_at_start": pathlib.Path("/proc/loadavg").read_text().split()[:3],
        "python": platform.python_version(),
        "gtsam": gtsam_version,
        "engine_bin": str(binary),
        "engine_bin_sha256": hashlib.sha256(binary.read_bytes()).hexdigest() if binary.exists() else None,
        "engine_bin_mtime": time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(binary.stat().st_mtime))
        if binary.exists() else None,
        "engine_build_type": build_type,
        "git_head": commit,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--engine-bin", default=str(REPO_ROOT / "build" / "bin" / "cdro-bench-engine"),
                        help="the C++ benchmark, run first for each size (default: %(default)s)")
    parser.add_argument("--sizes", default="100,1000", help="network sizes, nodes (%(default)s)")
    parser.add_argument("--seed", type=int, default=1, help="the network's seed (cdro-bench-engine --seed)")
    parser.add_argument("--warmup-sweeps", type=int, default=4, help="engine: sweeps of its warm-up (%(default)s)")
    parser.add_argument("--min-sweeps", help="engine: --min-sweeps, one value or one per size "
                                             "(default: the engine's, 20)")
    parser.add_argument("--steady-ranges", help="engine: --steady-ranges, one value or one per size "
                                                "(default: the engine's, 60000)")
    parser.add_argument("--no-engine-short-run", dest="engine_short_run", action="store_false",
                        help="skip the engine run that stops after the GTSAM solvers' sweeps")
    parser.add_argument("--isam2-sweeps", type=int, default=4,
                        help="GTSAM: sweeps of the stream fed (%(default)s: the engine's warm-up)")
    parser.add_argument("--isam2-max-ranges", type=int, default=0,
                        help="GTSAM: at most this many ranges (0: no cap); the table says when it cut")
    parser.add_argument("--isam2-seed", type=int, default=1, help="iSAM2: seed of the first run's starting points")
    parser.add_argument("--seeds", default="3", help="iSAM2: runs (seeds isam2-seed..), one value or one per size "
                                                     "(%(default)s)")
    parser.add_argument("--loss", choices=["huber", "cauchy", "gaussian"], default="huber")
    parser.add_argument("--sigma-m", type=float, default=0.1,
                        help="m, range sigma of the factors (%(default)s: the networks' noise)")
    parser.add_argument("--prior-sigma-m", type=float, default=100.0,
                        help="m, the weak prior on each node's starting point (%(default)s)")
    parser.add_argument("--relinearize", metavar="THRESHOLD:SKIP", action="append",
                        help="an iSAM2 configuration; repeat for more (default: GTSAM's own 0.1:10)")
    parser.add_argument("--extra-updates", type=int, default=20,
                        help="iSAM2: update() calls without new factors after the stream (%(default)s)")
    parser.add_argument("--lm-max-iterations", type=int, default=100,
                        help="LM: maxIterations (%(default)s, GTSAM's default)")
    parser.add_argument("--no-lm-from-truth", dest="lm_from_truth", action="store_false",
                        help="skip the reference: batch LM started at the true positions")
    parser.add_argument("--work-dir", help="where the engine writes the streams (default: a temporary folder)")
    parser.add_argument("--json", metavar="PATH", help="write every figure here ('-' for stdout, the text to stderr)")
    parser.add_argument("--tables-from", metavar="PATH",
                        help="run nothing: print the tables and ratios of a report this script wrote (and with "
                             "--json, write it again with the ratios recomputed)")
    args = parser.parse_args(argv)
    out = sys.stderr if args.json == "-" else sys.stdout
    if args.tables_from:
        report = json.loads(pathlib.Path(args.tables_from).read_text())
        saved = argparse.Namespace(**report["settings"])
        for result in report["sizes"]:
            print_table(result, saved, out)  # recomputes result["ratios"]
        if args.json:
            saved.json = args.json  # where to write; the settings stay those of the run
            write_report(saved, report["machine"], report["sizes"], report["command"])
        return 0

    try:
        import gtsam
    except ImportError:
        print("isam2_networks: needs gtsam (the optional extra `bench`: .venv/bin/pip install gtsam)",
              file=sys.stderr)
        return 2
    if not pathlib.Path(args.engine_bin).exists():
        print(f"isam2_networks: no {args.engine_bin} (build it, or --engine-bin)", file=sys.stderr)
        return 2
    sizes = [int(s) for s in args.sizes.split(",")]
    options = {"min_sweeps": per_size(args.min_sweeps, sizes, "--min-sweeps"),
               "steady_ranges": per_size(args.steady_ranges, sizes, "--steady-ranges"),
               "seeds": per_size(args.seeds, sizes, "--seeds")}
    machine = machine_info(args.engine_bin)
    print(f"{machine['cpu']}, {machine['nproc']} cores, this process on CPU(s) {machine['affinity']}; engine "
          f"{machine['engine_build_type']} build; GTSAM {machine['gtsam']} from PyPI; {args.loss} loss on sigma "
          f"{args.sigma_m} m, prior sigma {args.prior_sigma_m} m", file=out, flush=True)

    results = []
    with tempfile.TemporaryDirectory(prefix="isam2-networks-") as scratch:
        work = pathlib.Path(args.work_dir or scratch)
        for index, nodes in enumerate(sizes):
            results.append(run_size(gtsam, nodes, index, args, options, work, out))
            if args.json and args.json != "-":  # after each size: a long run keeps what it has
                write_report(args, machine, results)
    if args.json:
        write_report(args, machine, results)
    return 0


def write_report(args, machine: dict, results: list[dict], command: list[str] | None = None) -> None:
    report = {
        "machine": machine,
        "command": command or sys.argv,
        "settings": {key: value for key, value in vars(args).items() if key not in ("json", "tables_from")},
        "sizes": results,
    }
    write_json(report, args.json)


if __name__ == "__main__":
    sys.exit(main())
