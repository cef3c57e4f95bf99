#!/usr/bin/env python3
"""The engine's 3D tracker of moving nodes (cdro-hostd --moving; docs/engine.md, "Nodes that never
stop") against the Python baselines (b) and (c-ref) on the seeded simulated flights of
cdro_tools.simulation.flights (never on MiLUV): the sparse schedule (a tag hears an anchor every
~2.5 s, tag-to-tag ranges 0.25/s per pair: MiLUV's 3-robot run), the dense one (every ~0.43 s, no
tag-to-tag: its 1-robot run), the dense one with 5 % NLOS ranges (+Exp(0.5 m)), and two tags a
body on the sparse schedule (with and without cdro-hostd --moving-body). Scored as
scripts/miluv.py scores, at every row and at (b)'s rows.

    CDRO_BUILD_DIR=build .venv/bin/python scripts/flights_sim.py [--seeds 1-5] [--set K=V]...

--set passes engine settings on to cdro-hostd (e.g. engine.motion.flight_speed_tau_s=4), to
choose them here. Deterministic.
"""
from __future__ import annotations

import argparse
import pathlib
import sys
import tempfile

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tools"))
sys.path.insert(0, str(ROOT / "scripts"))

from cdro_tools.evaluation import tracking_baselines as tb  # noqa: E402
from cdro_tools.simulation import flights  # noqa: E402
import miluv  # noqa: E402

SCENARIOS = {"sparse (3 robots' schedule)": {},
             "dense (1 robot's schedule)": {"tag_tag_rate": 0.0, "gap_s": 0.43},
             "dense, 5 % NLOS": {"tag_tag_rate": 0.0, "gap_s": 0.43, "nlos": 0.05}}
ZERO_AS = 100   # the sparse flight's anchor 0 is no node id for cdro-hostd


def moving_body_arguments() -> list[str]:
    """cdro-hostd's --moving-body arguments for the bodies of flights.simulate_bodies."""
    return [a for x, y in flights.BODY_TAGS for a in ("--moving-body", f"{x}:{y}:{flights.BODY_SEPARATION_M:.3f}")]


def renumber(ranges: tb.TimedRanges) -> tb.TimedRanges:
    return tb.TimedRanges(ranges.t_s, np.where(ranges.from_ids == 0, ZERO_AS, ranges.from_ids),
                          np.where(ranges.to_ids == 0, ZERO_AS, ranges.to_ids), ranges.range_m, ranges.lines)


def calibration_rows(hostd, scratch: pathlib.Path, seeds, extra: list[str]) -> None:
    """(d): the same flights with only the anchors' heights given (cdro-hostd --moving without
    --fixed-csv: moving_calibration.hpp calibrates the anchors first). Prints, per scenario, the
    mean over the seeds (and the worst) of the anchors' 3D RMSE after their own rigid fit, and the
    tags' 3D RMSE after one rigid fit of the trajectory (cdro-eval-motion --align)."""
    anchors = {(ZERO_AS if i == 0 else i): np.array(p) for i, p in flights.sparse_anchors().items()}
    print("\n| scenario, anchors not given (d) | anchors' aligned RMSE 3D, mean (worst) | tags' aligned RMSE 3D, "
          "mean (worst) |")
    print("|---|---|---|")
    simulated = {title: (lambda seed, o=options: flights.simulate_sparse(seed, **o))
                 for title, options in SCENARIOS.items()}
    simulated["two tags a body (sparse)"] = flights.simulate_bodies
    for title, flight in simulated.items():
        anchor_rmse, tag_rmse = [], []
        for seed in seeds:
            ranges, truth = flight(seed)
            miluv.write_ranges(scratch / "ranges.csv", renumber(ranges))
            log: list[str] = []
            rows, _ = miluv.run_engine(hostd, scratch / "ranges.csv", anchors, sorted(truth), scratch, f"d{seed}",
                                       extra, calibrate=True, log=log)
            anchor_rmse.append(miluv.anchors_aligned(miluv.calibrated_anchors(log), anchors)["rmse_3d_m"])
            tag_rmse.append(flights.score_rows(rows, truth, align=True)["rmse_3d_m"])
        print(f"| {title} | {np.mean(anchor_rmse):.3f} ({np.max(anchor_rmse):.3f}) | {np.mean(tag_rmse):.3f} "
              f"({np.max(tag_rmse):.3f}) |")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", default="1-5")
    parser.add_argument("--set", action="append", default=[], help="engine setting K=V for cdro-hostd")
    parser.add_argument("--only-calibration", action="store_true", help="only (d), the anchors not given")
    args = parser.parse_args()
    lo, _, hi = args.seeds.partition("-")
    seeds = range(int(lo), int(hi or lo) + 1)
    hostd = miluv.hostd_binary()
    anchors = {(ZERO_AS if i == 0 else i): p for i, p in flights.sparse_anchors().items()}
    extra = [a for kv in args.set for a in ("--set", kv)]
    print(f"seeds {seeds.start}-{seeds.stop - 1}; engine settings: {args.set or 'defaults'}")
    print("| scenario | (b) EKF per tag | (c-ref) cooperative EKF | (c) engine | (c) at (b)'s rows "
          "| (c-ref) at (b)'s rows |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory(prefix="flights-") as scratch_dir:
        scratch = pathlib.Path(scratch_dir)
        if args.only_calibration:
            calibration_rows(hostd, scratch, seeds, extra)
            return 0
        for title, options in SCENARIOS.items():
            sums = {k: [] for k in ("ekf", "coop", "engine", "engine_b", "coop_b", "engine_in", "coop_in")}
            for seed in seeds:
                ranges, truth = flights.simulate_sparse(seed, **options)
                ranges = renumber(ranges)
                ekf = tb.track_ekf(ranges, anchors)
                coop = tb.track_ekf(ranges, anchors, cooperative=True)
                miluv.write_ranges(scratch / "ranges.csv", ranges)
                engine, _ = miluv.run_engine(hostd, scratch / "ranges.csv", anchors, list(flights.SPARSE_TAGS), scratch,
                                             f"seed{seed}", extra)
                keep = {(t, n) for t, n, _, _ in ekf.rows}
                for key, rows, only in (("ekf", ekf.rows, None), ("coop", coop.rows, None), ("engine", engine, None),
                                        ("engine_b", engine, keep), ("coop_b", coop.rows, keep)):
                    s = flights.score_rows(rows, truth, only)
                    sums[key].append(s["rmse_3d_m"])
                    if only is None and key in ("coop", "engine"):
                        sums[key + "_in"].append(s["inside_95_3d"])
            m = {k: float(np.mean(v)) for k, v in sums.items() if v}
            print(f"| {title} | {m['ekf']:.3f} | {m['coop']:.3f} ({m['coop_in']:.0%} inside) | {m['engine']:.3f} "
                  f"({m['engine_in']:.0%} inside) | {m['engine_b']:.3f} | {m['coop_b']:.3f} |")
        # Two tags a body: the engine with and without --moving-body.
        sums = {k: [] for k in ("ekf", "coop", "engine", "body", "body_in", "engine_in", "body_b", "engine_b")}
        bodies = moving_body_arguments()
        for seed in seeds:
            ranges, truth = flights.simulate_bodies(seed)
            ranges = renumber(ranges)
            ekf = tb.track_ekf(ranges, anchors)
            coop = tb.track_ekf(ranges, anchors, cooperative=True)
            miluv.write_ranges(scratch / "ranges.csv", ranges)
            tags = sorted(truth)
            engine, _ = miluv.run_engine(hostd, scratch / "ranges.csv", anchors, tags, scratch, f"b{seed}", extra)
            body, _ = miluv.run_engine(hostd, scratch / "ranges.csv", anchors, tags, scratch, f"b{seed}",
                                       extra + bodies)
            keep = {(t, n) for t, n, _, _ in ekf.rows}
            for key, rows, only in (("ekf", ekf.rows, None), ("coop", coop.rows, None), ("engine", engine, None),
                                    ("body", body, None), ("engine_b", engine, keep), ("body_b", body, keep)):
                sc = flights.score_rows(rows, truth, only)
                sums[key].append(sc["rmse_3d_m"])
                if key in ("engine", "body"):
                    sums[key + "_in"].append(sc["inside_95_3d"])
        m = {k: float(np.mean(v)) for k, v in sums.items() if v}
        print(f"\nTwo tags a body (sparse schedule): (b) {m['ekf']:.3f}, (c-ref) {m['coop']:.3f}, "
              f"(c) {m['engine']:.3f} "
              f"({m['engine_in']:.0%} inside), (c) with --moving-body {m['body']:.3f} ({m['body_in']:.0%} inside); "
              f"at (b)'s rows (c) {m['engine_b']:.3f}, with --moving-body {m['body_b']:.3f}")
        print("Cells: mean over the seeds of the 3D RMSE (m); inside: errors inside the 95 % region (3D).")
        calibration_rows(hostd, scratch, seeds, extra)
    return 0


if __name__ == "__main__":
    sys.exit(main())
