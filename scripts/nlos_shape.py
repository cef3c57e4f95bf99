#!/usr/bin/env python3
"""What real NLOS errors look like, next to the engine's likelihood (docs/results.md, "The NLOS
likelihood against kolakowski-nlos").

kolakowski-nlos (../shared/data, its README): 36 static DW1000 pairs in a furnished flat, each
labelled LOS, NLOS or NDP-NLOS (no direct path), with the true 2D distance. The engine's model
(host/engine/include/cdro/engine/range_likelihood.hpp) says: a line-of-sight reading is Gaussian
around the truth; an NLOS one is long by a persistent excess X ~ Exp(mean 1/lambda) plus the noise; readings short by
more than the noise are all but impossible; and each radio may add its own offset (an uncalibrated
antenna delay, range_offsets.hpp). This script measures each claim on the data, pair by pair (the
engine sees a link's median, so the pair is the unit):

- the common offset: the median error of the LOS pairs (the antenna delays of both radios);
- the excess: each NLOS / NDP pair's median error less that offset; its mean is the maximum-
  likelihood 1/lambda of an exponential, and a Kolmogorov-Smirnov distance says how well an
  exponential fits;
- one-sidedness: how many readings, and how many pairs, are short of the truth beyond the noise.

    .venv/bin/python scripts/nlos_shape.py [--data ../shared/data/kolakowski-nlos] [--json out.json]
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import pathlib
import statistics
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent
DATA = pathlib.Path(os.environ.get("CDRO_DATA_DIR", ROOT.parent / "shared" / "data")) / "kolakowski-nlos"
NOISE_SIGMAS = 3.0      # a reading is short "beyond the noise" below -3 sigma of its pair's spread


def ks_exponential(values: list[float], mean: float) -> float:
    """The Kolmogorov-Smirnov distance between the sample and Exp(mean)."""
    ordered = sorted(values)
    n = len(ordered)
    worst = 0.0
    for i, v in enumerate(ordered):
        cdf = 1.0 - math.exp(-max(v, 0.0) / mean)
        worst = max(worst, abs(cdf - i / n), abs(cdf - (i + 1) / n))
    return worst


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", default=str(DATA))
    parser.add_argument("--json", help="also write every figure here")
    args = parser.parse_args()
    path = pathlib.Path(args.data) / "range_samples.csv"
    if not path.is_file():
        print(f"nlos_shape: {path} not found (set CDRO_DATA_DIR or --data)", file=sys.stderr)
        return 2
    pairs: dict[int, dict] = {}
    with open(path) as f:
        for row in csv.DictReader(f):
            pair = pairs.setdefault(int(row["file_id"]), {"label": row["label"], "errors": []})
            pair["errors"].append(float(row["range_m"]) - float(row["true_2d_m"]))
    for pair in pairs.values():
        errors = pair["errors"]
        pair["median_m"] = statistics.median(errors)
        mad = statistics.median(abs(e - pair["median_m"]) for e in errors)
        pair["sigma_m"] = max(1.4826 * mad, 1e-3)
    labels = ("LOS", "NLOS", "NDP NLOS")
    offset_m = statistics.median(p["median_m"] for p in pairs.values() if p["label"] == "LOS")
    report = {"pairs": len(pairs), "ranges": sum(len(p["errors"]) for p in pairs.values()),
              "common_offset_m": offset_m, "labels": {}}
    for label in labels:
        group = [p for p in pairs.values() if p["label"] == label]
        excess = [p["median_m"] - offset_m for p in group]
        short_readings = sum(1 for p in group for e in p["errors"] if e - p["median_m"] < -NOISE_SIGMAS * p["sigma_m"]
                             and e < 0.0)
        entry = {"pairs": len(group), "ranges": sum(len(p["errors"]) for p in group),
                 "median_error_m": statistics.median(p["median_m"] for p in group),
                 "excess_median_m": statistics.median(excess), "excess_max_m": max(excess),
                 "pairs_short_of_truth": sum(1 for p in group if p["median_m"] < 0.0),
                 "readings_short_beyond_noise": short_readings,
                 "within_pair_sigma_m": statistics.median(p["sigma_m"] for p in group)}
        if label != "LOS":
            positive = [max(x, 0.0) for x in excess]
            mean = max(statistics.fmean(positive), 1e-3)
            entry.update(exponential_mean_m=mean, ks_distance=ks_exponential(positive, mean))
        report["labels"][label] = entry
    every_nlos = [p["median_m"] - offset_m for p in pairs.values() if p["label"] != "LOS"]
    positive = [max(x, 0.0) for x in every_nlos]
    report["nlos_and_ndp"] = {"pairs": len(every_nlos), "exponential_mean_m": statistics.fmean(positive),
                              "ks_distance": ks_exponential(positive, statistics.fmean(positive))}
    print(f"kolakowski-nlos: {report['pairs']} pairs, {report['ranges']} ranges; common offset (median LOS error) "
          f"{offset_m:+.3f} m")
    print("| label | pairs | median error (m) | excess over the offset: median / max (m) | exponential mean (m), KS |"
          " pairs short of the truth | readings short beyond 3 sigma | spread within a pair (m) |")
    print("|---|---|---|---|---|---|---|---|")
    for label, e in report["labels"].items():
        fit = f"{e['exponential_mean_m']:.2f}, {e['ks_distance']:.2f}" if "exponential_mean_m" in e else "-"
        print(f"| {label} | {e['pairs']} | {e['median_error_m']:+.3f} | {e['excess_median_m']:+.3f} / "
              f"{e['excess_max_m']:+.3f} | {fit} | {e['pairs_short_of_truth']} | {e['readings_short_beyond_noise']} of "
              f"{e['ranges']} | {e['within_pair_sigma_m']:.3f} |")
    both = report["nlos_and_ndp"]
    print(f"NLOS and NDP together: {both['pairs']} pairs, exponential mean {both['exponential_mean_m']:.2f} m, "
          f"KS {both['ks_distance']:.2f}")
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
