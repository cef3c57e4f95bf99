#!/usr/bin/env python3
"""The engine against a baseline engine, side by side on the same machine state (docs/bench.md).

Machines differ by 2x and more, and a machine shared with other work differs from itself from
one minute to the next, so speed goals are ratios against a baseline build measured in the same
run: this runs `cdro-bench-engine --plant-only` of this build and of the baseline alternately,
`--pairs` times, and prints, per figure, both medians and the ratios pair by pair.

    scripts/bench_compare.py --baseline-bin ../old/build/bin/cdro-bench-engine [--pairs 3] [--passes 100]

The baseline is any earlier build of cdro-bench-engine (the engine before its rebuild is commit f69b6a3, built in a
worktree: `git worktree add /tmp/old f69b6a3 && cmake -S /tmp/old -B /tmp/old/build -G Ninja
-DCMAKE_BUILD_TYPE=RelWithDebInfo && cmake --build /tmp/old/build --target cdro-bench-engine`).
Figures (all per CPU-second or CPU time, higher is better unless it says ms):
  steady, per pass      median over the steady passes of each run (leaves out the one pass that
                        holds a one-off global solve); the JSON's runs[0].steady_pass_rate_median
  steady, all passes    ranges per CPU-second over every steady pass
  first pass            ms of CPU a range while the map is built (lower is better)
Figures only: run on purpose, never by the tests. Exit 2 on unusable input.
"""
from __future__ import annotations

import argparse
import json
import pathlib
import statistics
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent

FIGURES = {
    # name: (how to read it from the JSON's "plant" object, higher is better)
    "steady, per pass (ranges/s, wall)": (lambda p: p["runs"][0]["steady_pass_rate_median"], True),
    "steady, all passes (ranges/CPU-s)": (lambda p: p["steady_ranges_per_cpu_s_median"], True),
    "first pass (ms CPU/range)": (lambda p: p["first_pass_cpu_us_per_range_median"] / 1000.0, False),
}


def run_bench(binary: pathlib.Path, data_dir: pathlib.Path, passes: int) -> dict:
    command = [str(binary), "--data-dir", str(data_dir), "--plant-only", "--passes", str(passes), "--repeat", "1",
               "--json"]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        raise SystemExit(f"bench_compare: {' '.join(command)} failed:\n{result.stderr}")
    try:
        return json.loads(result.stdout)["plant"]
    except (ValueError, KeyError) as error:
        raise SystemExit(f"bench_compare: {binary} printed no PLANT JSON ({error})") from None


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="bench_compare.py", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--baseline-bin", required=True, type=pathlib.Path, help="the baseline's cdro-bench-engine")
    p.add_argument("--bin", type=pathlib.Path, default=ROOT / "build" / "bin" / "cdro-bench-engine",
                   help="this build's cdro-bench-engine (default build/bin/)")
    p.add_argument("--data-dir", type=pathlib.Path, default=ROOT.parent / "shared" / "data",
                   help="the folder that holds plant/ (default ../shared/data)")
    p.add_argument("--pairs", type=int, default=3, help="runs of each, alternating (default 3)")
    p.add_argument("--passes", type=int, default=100, help="PLANT passes a run (default 100)")
    p.add_argument("--json", type=pathlib.Path, help="also write every figure of every run here")
    args = p.parse_args(argv)
    for binary in (args.bin, args.baseline_bin):
        if not binary.is_file():
            print(f"bench_compare: {binary}: no such program", file=sys.stderr)
            return 2
    if not (args.data_dir / "plant").is_dir() or args.pairs < 1 or args.passes < 2:
        print("bench_compare: needs --data-dir with plant/, --pairs >= 1, --passes >= 2", file=sys.stderr)
        return 2
    runs: dict[str, list[dict]] = {"this": [], "baseline": []}
    for pair in range(args.pairs):
        for name, binary in (("this", args.bin), ("baseline", args.baseline_bin)):
            plant = run_bench(binary, args.data_dir, args.passes)
            runs[name].append({figure: read(plant) for figure, (read, _) in FIGURES.items()})
        print(f"pair {pair + 1}/{args.pairs} done", file=sys.stderr)
    print(f"PLANT, {args.passes} passes, {args.pairs} pairs alternating: {args.bin} against {args.baseline_bin}")
    print("| figure | this build, median | baseline, median | ratio, pair by pair |")
    print("|---|---|---|---|")
    for figure, (_, higher_is_better) in FIGURES.items():
        mine = [run[figure] for run in runs["this"]]
        base = [run[figure] for run in runs["baseline"]]
        # A ratio above 1 is always "this build is better".
        ratios = [(m / b if higher_is_better else b / m) for m, b in zip(mine, base) if m > 0 and b > 0]
        print(f"| {figure} | {statistics.median(mine):.6g} | {statistics.median(base):.6g} | "
              f"{', '.join(f'{r:.2f}' for r in ratios)} |")
    if args.json:
        args.json.write_text(json.dumps(runs, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
