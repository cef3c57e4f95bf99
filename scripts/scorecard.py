#!/usr/bin/env python3
"""The scorecard of stage 1 (docs/results.md, "Scorecard"): the engine on seeded networks of every
building family (host/netgen), next to the batch baselines on the same ranges and the reference
no user has (the engine's robust map solve started at the truth), with what matters to a user:
how far the map is, whether the nodes it calls converged are right, whether its ellipses hold the
truth, and whether the order the ranges came in changes the answer. docs/results.md shows the command lines.

For each family and seed: cdro-netgen writes the network (its seed printed); cdro-hostd maps it
as a user would (defaults, offline mode) in file order, in --shuffles shuffled orders, with the
nodes switched on one by one (staggered) and with one node switched on last (late); cdro-eval
gives the aligned RMSE, the baselines (MDS-MAP, Huber LS from MDS-MAP, LS after dropping links
that read long) and the honesty figures (honesty.py); cdro-reference gives the reference.
Every intermediate file goes to --out, every number to --out/summary.json, the tables to stdout
and, with --markdown, to a file. Deterministic: the same arguments give the same numbers.
"""
from __future__ import annotations

import argparse
import concurrent.futures
import json
import math
import os
import pathlib
import shlex
import statistics
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent
# The build whose cdro-hostd and cdro-netgen are scored ($CDRO_BUILD_DIR, as for the tests).
BIN = pathlib.Path(os.environ.get("CDRO_BUILD_DIR", ROOT / "build")) / "bin"
VENV = ROOT / ".venv" / "bin"
FAMILIES = ("random", "corridor", "wings", "walls", "biased")
# --set SECTION.KEY=VALUE passed to every cdro-hostd run (--set on the command line).
HOSTD_SETTINGS: list[str] = []
# --netgen OPTIONS passed to every cdro-netgen draw: a variant of the families (fewer sweeps, more
# NLOS links, more nodes) scored as they are.
NETGEN_OPTIONS: list[str] = []
BASELINES = ("mds", "lsq-huber", "lsq-drop")


def run(args: list) -> subprocess.CompletedProcess:
    result = subprocess.run([str(a) for a in args], capture_output=True, text=True)
    if result.returncode != 0:
        sys.stderr.write(result.stdout + result.stderr)
        raise SystemExit(f"scorecard: failed: {' '.join(map(str, args))}")
    return result


def evaluate(network: pathlib.Path, estimates: pathlib.Path, baselines: bool) -> dict:
    args = [VENV / "cdro-eval", "--truth", network / "truth.csv", "--ranges", network / "ranges.csv",
            "--estimates", estimates, "--json", "-"]
    if (network / "heights.csv").stat().st_size > len("id,z\n"):
        args += ["--heights-csv", network / "heights.csv"]
    args += ["--baselines", ",".join(BASELINES)] if baselines else ["--no-baselines"]
    return json.loads(run(args).stdout)


def engine_run(network: pathlib.Path, name: str) -> dict:
    """cdro-hostd on the network's ranges (defaults), then cdro-eval on its estimates."""
    out = network / f"engine-{name}.csv"
    args = [BIN / "cdro-hostd", "--ranges-csv", network / "ranges.csv", "--out-csv", out]
    for setting in HOSTD_SETTINGS:
        args += ["--set", setting]
    if (network / "heights.csv").stat().st_size > len("id,z\n"):
        args += ["--heights-csv", network / "heights.csv"]
    run(args)
    report = evaluate(network, out, baselines=False)["methods"]["engine"]
    return {"rmse_m": report["rmse_m"], "placed": report["estimates"], "nodes": report["nodes"],
            "converged": report["converged"], "rmse_converged_m": report["rmse_converged_m"],
            "converged_wrong": len(report["converged_wrong"]), "ellipse_coverage": report["ellipse_coverage"],
            "nees": report["nees"], "unplaced": len(report["unplaced"])}


def netgen(family: str, seed: int, out: pathlib.Path, *extra) -> pathlib.Path:
    if not (out / "ranges.csv").exists():
        run([BIN / "cdro-netgen", "--family", family, "--seed", seed, "--out", out, *NETGEN_OPTIONS, *extra])
    return out


def draw(family: str, seed: int, out: pathlib.Path, shuffles: int, heights: str, other_orders: bool) -> dict:
    base = out / f"{family}-{heights}-{seed}"
    options = ["--heights", heights]
    orders = {"file": netgen(family, seed, base / "file", *options)}
    if other_orders:
        for k in range(1, shuffles + 1):
            orders[f"shuffled {k}"] = netgen(family, seed, base / f"shuffled-{k}", *options, "--shuffle", 1000 + k)
        orders["staggered"] = netgen(family, seed, base / "staggered", *options, "--order", "staggered")
        orders["late"] = netgen(family, seed, base / "late", *options, "--order", "late")
    runs = {name: engine_run(path, name.replace(" ", "-")) for name, path in orders.items()}
    file_order = orders["file"]
    with_baselines = evaluate(file_order, file_order / "engine-file.csv", baselines=True)["methods"]
    reference_csv = file_order / "reference.csv"
    args = [BIN / "cdro-reference", "--truth", file_order / "truth.csv", "--ranges", file_order / "ranges.csv",
            "--out", reference_csv]
    if heights == "known":
        args += ["--heights", file_order / "heights.csv"]
    run(args)
    reference = evaluate(file_order, reference_csv, baselines=False)["methods"]["engine"]
    about = (file_order / "world.txt").read_text().splitlines()
    rmses = [r["rmse_m"] for r in runs.values() if r["rmse_m"] is not None]
    return {
        "family": family, "seed": seed, "heights": heights,
        "world": next((line for line in about
                       if line and line.split()[0] not in ("family", "seed", "order", "shuffle")), ""),
        "nodes": runs["file"]["nodes"] + runs["file"]["unplaced"],
        "links": sum(1 for _ in open(file_order / "links.csv")) - 1,
        "engine": runs,
        "baselines": {name: with_baselines[name]["rmse_m"] for name in BASELINES},
        "reference_m": reference["rmse_m"],
        "order_spread": (max(rmses) / min(rmses) - 1.0) if len(rmses) > 1 and min(rmses) > 0 else None,
    }


def fmt(value, digits: int = 2) -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def tables(rows: list[dict]) -> str:
    lines = ["| family | seed | nodes | links | engine (m) | placed / converged | converged > 1 m off | "
             "ellipse coverage | MDS-MAP | Huber LS | LS drop | reference | orders: min-max (m), spread |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        e = r["engine"]["file"]
        rmses = [x["rmse_m"] for x in r["engine"].values() if x["rmse_m"] is not None]
        wrong = sum(x["converged_wrong"] for x in r["engine"].values())
        runs_with_converged = [x for x in r["engine"].values() if x["ellipse_coverage"] is not None]
        coverage = (sum(x["ellipse_coverage"] * x["converged"] for x in runs_with_converged) /
                    sum(x["converged"] for x in runs_with_converged)) if runs_with_converged else None
        lines.append(
            f"| {r['family']}{'' if r['heights'] == 'known' else ' (heights unknown)'} | {r['seed']} | {r['nodes']} | "
            f"{r['links']} | {fmt(e['rmse_m'])} | {e['placed']} / {e['converged']} | {wrong} | "
            f"{fmt(100 * coverage, 0) + ' %' if coverage is not None else '-'} | "
            + " | ".join(fmt(r["baselines"][b]) for b in BASELINES)
            + f" | {fmt(r['reference_m'])} | "
            + (f"{fmt(min(rmses))}-{fmt(max(rmses))}, {fmt(100 * r['order_spread'], 0)} % |"
               if r["order_spread"] is not None else "file order only |"))
    return "\n".join(lines)


def summary(rows: list[dict]) -> str:
    lines = ["| family | draws | engine median (m) | best baseline median (m) | engine <= best baseline + 0.05 m | "
             "reference median (m) | runs | converged | converged > 1 m off | ellipse coverage | "
             "order spread median / max |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    keys = sorted({(r["family"], r["heights"]) for r in rows}, key=lambda k: (FAMILIES.index(k[0]), k[1]))
    for family, heights in keys:
        group = [r for r in rows if r["family"] == family and r["heights"] == heights]
        engine = [r["engine"]["file"]["rmse_m"] for r in group if r["engine"]["file"]["rmse_m"] is not None]
        best = [min(v for v in r["baselines"].values() if v is not None) for r in group]
        at_least = sum(1 for r, b in zip(group, best)
                       if r["engine"]["file"]["rmse_m"] is not None and r["engine"]["file"]["rmse_m"] <= b + 0.05)
        runs = [x for r in group for x in r["engine"].values()]
        converged = sum(x["converged"] for x in runs)
        wrong = sum(x["converged_wrong"] for x in runs)
        judged = [x for x in runs if x["ellipse_coverage"] is not None]
        covered = sum(x["ellipse_coverage"] * x["converged"] for x in judged)
        judged_converged = sum(x["converged"] for x in judged)
        spreads = [r["order_spread"] for r in group if r["order_spread"] is not None]
        lines.append(
            f"| {family}{'' if heights == 'known' else ' (heights unknown)'} | {len(group)} | "
            f"{fmt(statistics.median(engine)) if engine else '-'} | {fmt(statistics.median(best))} | "
            f"{at_least} of {len(group)} | {fmt(statistics.median([r['reference_m'] for r in group]))} | {len(runs)} | "
            f"{converged} | {wrong} | {fmt(100 * covered / judged_converged, 0) + ' %' if judged_converged else '-'} | "
            + (f"{fmt(100 * statistics.median(spreads), 0)} % / {fmt(100 * max(spreads), 0)} % |" if spreads
               else "file order only |"))
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--families", default=",".join(FAMILIES), help="comma-separated, of: " + ", ".join(FAMILIES))
    parser.add_argument("--seeds", default="1-5", help="a range (1-5) or a list (1,4,7)")
    parser.add_argument("--shuffles", type=int, default=2, help="shuffled orders per draw")
    parser.add_argument("--heights-unknown", default="random",
                        help="families also drawn with heights unknown (comma-separated; '' for none)")
    parser.add_argument("--file-order-only", default="walls",
                        help="families run in file order only (comma-separated; '' for none): the largest")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="draws run at once")
    parser.add_argument("--out", default=str(ROOT / "out" / "scorecard"))
    parser.add_argument("--markdown", help="also write the tables to this file")
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="an engine setting for every cdro-hostd run (repeatable), e.g. engine.solve.threads=1")
    parser.add_argument("--netgen", default="", metavar="OPTIONS",
                        help="cdro-netgen options for every draw, e.g. --netgen='--sweeps 4 --nlos-fraction 0.25' "
                             "(a variant of the families; not --family, --seed, --heights, --order, --shuffle, --out, "
                             "which the scorecard sets)")
    args = parser.parse_args()
    HOSTD_SETTINGS.extend(args.set)
    NETGEN_OPTIONS.extend(shlex.split(args.netgen))
    reserved = {"--family", "--seed", "--heights", "--order", "--shuffle", "--out"}
    if reserved & {option.split("=")[0] for option in NETGEN_OPTIONS}:
        parser.error(f"--netgen may not set {', '.join(sorted(reserved))}: the scorecard sets them")
    if "-" in args.seeds:
        first, last = (int(x) for x in args.seeds.split("-"))
        seeds = list(range(first, last + 1))
    else:
        seeds = [int(x) for x in args.seeds.split(",")]
    families = [f for f in args.families.split(",") if f]
    unknown = [f for f in families if f not in FAMILIES]
    if unknown:
        parser.error(f"unknown family {unknown} (known: {', '.join(FAMILIES)})")
    work = [(f, s, "known") for f in families for s in seeds]
    work += [(f, s, "unknown") for f in args.heights_unknown.split(",") if f in families for s in seeds]
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"scorecard: {len(work)} draws ({', '.join(families)}; seeds {seeds}), {args.shuffles} shuffles each, "
          f"{args.jobs} at once -> {out}", file=sys.stderr, flush=True)
    rows = []
    with concurrent.futures.ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        only_file = set(args.file_order_only.split(","))
        futures = {pool.submit(draw, f, s, out, args.shuffles, h, f not in only_file): (f, s, h) for f, s, h in work}
        for future in concurrent.futures.as_completed(futures):
            row = future.result()
            e = row["engine"]["file"]
            print(f"scorecard: {row['family']} seed {row['seed']} heights {row['heights']}: "
                  f"engine {fmt(e['rmse_m'])} m, "
                  f"{e['converged']} converged ({e['converged_wrong']} > 1 m off), best baseline "
                  f"{fmt(min(v for v in row['baselines'].values() if v is not None))} m, reference "
                  f"{fmt(row['reference_m'])} m", file=sys.stderr, flush=True)
            rows.append(row)
    rows.sort(key=lambda r: (FAMILIES.index(r["family"]), r["heights"], r["seed"]))
    (out / "summary.json").write_text(json.dumps(rows, indent=1))
    text = "### Per family\n\n" + summary(rows) + "\n\n### Per draw\n\n" + tables(rows) + "\n"
    print(text)
    if args.markdown:
        pathlib.Path(args.markdown).write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
