"""cdro-eval: an anchor-free map estimate against ground truth, next to baselines solved on
the same ranges, in one table.

Estimates (the engine's nodes CSV id,x,y,var_x,cov_xy,var_y,converged) are rigidly aligned
to the truth (rotation + translation, reflection allowed, no scale) and give the aligned
RMSE and per-node errors. From the ranges alone, without truth, it solves the baselines
MDS-MAP, batch least squares with a Huber loss started from MDS-MAP, and the same after
dropping links that read more than 0.6 m long; they are aligned the same way. The
Cramer-Rao bound of the network (anchor-free, Gaussian range noise of --sigma-m) is the
floor. Known heights (--heights-csv, or --heights-from-truth) project the 3D ranges to the
plane. Traces of the engine (--trace, rows after every K-th range) give each node's
convergence time in ranges and the RMSE over ranges. The table goes to stdout (to stderr
with --json -), every figure to --json. Bad rows are reported with their line, counted and
skipped; a missing file or column is an error (exit 2).

examples:
  cdro-eval --truth nodes.csv --ranges ranges.csv --heights-from-truth --estimates est.csv --json eval.json
  cdro-eval --truth nodes.csv --ranges ranges.csv --heights-from-truth --crb-per-link --map-png map.png --map-baselines
  cdro-eval --truth truth.csv --ranges ranges.csv --estimates est.csv --trace wt.csv --label "weight transfer" \\
            --trace no-wt.csv --label "no weight transfer" --rmse-png rmse.png --sigma-m 0.75
"""
from __future__ import annotations

import os

# The least-squares problems here are small and dense (PLANT: 105 x 56); OpenBLAS threads
# only contend for them, and on a loaded 2-core machine they made an SVD of that size 15-25x
# slower. Must be set before numpy is imported; an explicit setting wins.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import pathlib  # noqa: E402
import sys  # noqa: E402

import numpy as np  # noqa: E402

from .evaluation import drawing  # noqa: E402
from .evaluation.alignment import Alignment, align  # noqa: E402
from .evaluation.baselines import (DROP_THRESHOLD_M, HUBER_K, NAMES as LSQ_NAMES, BaselineError, Links,  # noqa: E402
                                   run_baselines)
from .evaluation.convergence import all_converged_at, convergence_ranges, rmse_over_ranges  # noqa: E402
from .evaluation.honesty import WRONG_M, converged_honesty  # noqa: E402
from .evaluation.crb import anchor_free_crb  # noqa: E402
from .evaluation.inputs import (BadRow, InputError, project_ranges, read_estimates, read_heights,  # noqa: E402
                                read_ranges, read_trace, read_truth)
from .cli import entry_point  # noqa: E402

PROG = "cdro-eval"
BASELINES = (*LSQ_NAMES, "crb")
TITLES = {"engine": "engine", "mds": "MDS-MAP", "lsq-huber": "LS Huber", "lsq-drop": "LS drop+resolve",
          "crb": "CRB"}
BASELINE_STYLE = {"mds": ("tab:red", "x"), "lsq-huber": ("tab:orange", "^"), "lsq-drop": ("tab:green", "s")}
BAD_ROWS_SHOWN = 20             # per file on stderr; all of them go to --json
DEFAULT_SIGMA_M = 0.13          # PLANT's robust range sigma (data/README.md)


def _log(message: str) -> None:
    print(f"{PROG}: {message}", file=sys.stderr)


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text}: must be above 0")
    return value


def _non_negative(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"{text}: must be 0 or above")
    return value


def _baseline_list(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in BASELINES]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"{text!r}: unknown baseline(s) {', '.join(unknown) or '(none given)'}; "
                                         f"known: {','.join(BASELINES)}")
    return names


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    inputs = p.add_argument_group("inputs")
    inputs.add_argument("--truth", required=True, metavar="CSV", help="ground truth id,x,y[,z] (m)")
    inputs.add_argument("--estimates", metavar="CSV", help="the engine's nodes id,x,y,var_x,cov_xy,var_y,converged")
    inputs.add_argument("--ranges", metavar="CSV", help="[t,]from,to,range_m: the ranges behind the estimates")
    heights = inputs.add_mutually_exclusive_group()
    heights.add_argument("--heights-csv", metavar="CSV", help="known heights id,z (m): project ranges to the plane")
    heights.add_argument("--heights-from-truth", action="store_true", help="take the heights from the truth's z column")
    inputs.add_argument("--trace", action="append", default=[], metavar="CSV",
                        help="engine trace ranges,id,x,y,var_x,cov_xy,var_y,converged (repeatable)")
    inputs.add_argument("--label", action="append", default=[], metavar="NAME",
                        help="a name per --trace, in the same order (default: the file's stem)")
    base = p.add_argument_group("baselines and bound")
    choice = base.add_mutually_exclusive_group()
    choice.add_argument("--baselines", type=_baseline_list, metavar="LIST",
                        help=f"comma list of {','.join(BASELINES)} (default: all, when --ranges is given)")
    choice.add_argument("--no-baselines", action="store_true", help="no baselines and no bound")
    base.add_argument("--sigma-m", type=_positive, default=DEFAULT_SIGMA_M, metavar="M",
                      help=f"Gaussian range noise std for the CRB and the Huber scale, m (default {DEFAULT_SIGMA_M})")
    base.add_argument("--crb-per-link", action="store_true",
                      help="CRB with one entry per link (default: one entry per range)")
    base.add_argument("--huber-scale-m", type=_positive, metavar="M",
                      help=f"Huber f_scale, m (default {HUBER_K} x --sigma-m)")
    base.add_argument("--drop-threshold-m", type=_non_negative, default=DROP_THRESHOLD_M, metavar="M",
                      help=f"lsq-drop: drop links that read more than this long, m (default {DROP_THRESHOLD_M})")
    base.add_argument("--resolve-loss", choices=("linear", "huber"), default="linear",
                      help="lsq-drop: loss of the re-solve (default linear: plain least squares)")
    out = p.add_argument_group("outputs")
    out.add_argument("--json", metavar="PATH",
                     help="every figure as JSON (- for stdout; the table then goes to stderr)")
    out.add_argument("--map-png", metavar="PATH",
                     help="map: truth, aligned estimates with 2-sigma ellipses, links, ids")
    out.add_argument("--map-baselines", action="store_true", help="also draw the baselines' solutions on the map")
    out.add_argument("--rmse-png", metavar="PATH", help="aligned RMSE over ranges processed, one curve per --trace")
    out.add_argument("--title", default="", help="plot title")
    return p


def _check_arguments(p: argparse.ArgumentParser, args) -> None:
    if args.label and len(args.label) != len(args.trace):
        p.error(f"{len(args.label)} --label for {len(args.trace)} --trace: give one label per trace, or none")
    if args.rmse_png and not args.trace:
        p.error("--rmse-png needs at least one --trace")
    if args.map_baselines and not args.map_png:
        p.error("--map-baselines goes with --map-png")
    if args.baselines and not args.ranges:
        p.error("--baselines needs --ranges (the baselines are solved from them)")
    if not (args.estimates or args.trace or args.ranges):
        p.error("nothing to evaluate: give --estimates, --trace and/or --ranges")
    for path in filter(None, [args.json if args.json != "-" else None, args.map_png, args.rmse_png]):
        target = pathlib.Path(path)
        if target.is_dir() or not target.parent.is_dir():
            p.error(f"{path}: cannot write there ({'a directory' if target.is_dir() else 'no such directory'})")


def _finite_or_none(value: float) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def _method_json(alignment: Alignment) -> dict:
    return {"rmse_m": _finite_or_none(alignment.rmse_m), "nodes": alignment.nodes, "reflected": alignment.reflected,
            "rotation": alignment.rotation.tolist(), "translation_m": alignment.translation_m.tolist(),
            "per_node": [{"id": i, "error_m": e} for i, e in sorted(alignment.errors_m.items())]}


def _fmt(value: float | None, digits: int = 3) -> str:
    return "-" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def evaluate(args, bad: list[BadRow]) -> tuple[dict, dict]:
    """Everything but the output: (the JSON report, what the plots need); bad rows are
    appended to `bad` as they are found."""
    truth_xy, truth_z = read_truth(args.truth, bad)
    if not truth_xy:
        raise InputError(f"{args.truth}: no usable truth row")
    report: dict = {"inputs": {"truth": args.truth, "estimates": args.estimates, "ranges": args.ranges,
                               "heights": (f"csv {args.heights_csv}" if args.heights_csv else
                                           "truth" if args.heights_from_truth else None),
                               "traces": args.trace},
                    "methods": {}}
    heights = None
    if args.heights_csv:
        heights = read_heights(args.heights_csv, bad)
    elif args.heights_from_truth:
        if not truth_z:
            raise InputError(f"{args.truth}: --heights-from-truth, but the truth has no z column")
        heights = truth_z

    ranges = links = None
    if args.ranges:
        raw = read_ranges(args.ranges, bad)
        if not len(raw):
            raise InputError(f"{args.ranges}: no usable range row")
        summary = {"rows": raw.rows, "used": len(raw), "bad_rows": raw.rows - len(raw)}
        if heights is not None:
            projection = project_ranges(raw, heights)
            ranges = projection.ranges
            summary.update(projected=projection.projected, clamped=projection.clamped,
                           without_height=projection.without_height,
                           nodes_without_height=projection.nodes_without_height)
        else:
            ranges = raw
            summary.update(projected=0, clamped=0, without_height=len(raw), nodes_without_height=[])
        links = Links.from_ranges(ranges.links())
        summary.update(links=len(links.pairs), nodes=len(ranges.node_ids),
                       nodes_without_truth=[i for i in ranges.node_ids if i not in truth_xy])
        report["ranges"] = summary

    plots: dict = {"truth": truth_xy, "links": links.pairs if links else [], "baselines": {}, "traces": []}
    ranged = set(ranges.node_ids) if ranges is not None else set()

    if args.estimates:
        unplaced: list[int] = []
        estimates = read_estimates(args.estimates, bad, unplaced)
        if not estimates:
            raise InputError(f"{args.estimates}: no usable estimate row")
        if not any(i in truth_xy for i in estimates):
            shown = ", ".join(map(str, sorted(estimates)[:5])) + (", ..." if len(estimates) > 5 else "")
            raise InputError(f"{args.estimates}: none of its ids is in {args.truth} (its ids: {shown})")
        alignment = align({i: e.xy_m for i, e in estimates.items()}, truth_xy)
        converged = {i: e for i, e in estimates.items() if e.converged}
        converged_alignment = align({i: e.xy_m for i, e in converged.items()}, truth_xy)
        engine = _method_json(alignment)
        honesty = converged_honesty(converged, converged_alignment, truth_xy) if len(converged) >= 3 else None
        engine.update(estimates=len(estimates), converged=len(converged),
                      rmse_converged_m=_finite_or_none(converged_alignment.rmse_m) if len(converged) >= 3 else None,
                      converged_wrong=honesty.wrong if honesty else [],
                      ellipse_coverage=_finite_or_none(honesty.coverage) if honesty else None,
                      nees=_finite_or_none(honesty.nees) if honesty else None,
                      nodes_without_truth=sorted(i for i in estimates if i not in truth_xy),
                      unplaced=sorted(unplaced),
                      ranged_nodes_without_estimate=sorted(ranged - set(estimates) - set(unplaced)))
        notes = [f"{len(converged)}/{len(estimates)} converged"]
        if engine["rmse_converged_m"] is not None and len(converged) < len(estimates):
            notes.append(f"converged nodes alone {_fmt(engine['rmse_converged_m'])} m")
        if honesty:
            notes.append(f"{len(honesty.wrong)} converged > {WRONG_M:g} m off; truth inside the 2-sigma ellipse of "
                         f"{100 * honesty.coverage:.0f} % of them (NEES {honesty.nees:.2f})")
        if unplaced:
            shown = ", ".join(map(str, sorted(unplaced)[:5])) + (", ..." if len(unplaced) > 5 else "")
            notes.append(f"{len(unplaced)} not placed ({shown})")
        if engine["nodes_without_truth"]:
            notes.append(f"{len(engine['nodes_without_truth'])} without truth")
        if engine["ranged_nodes_without_estimate"]:
            notes.append(f"{len(engine['ranged_nodes_without_estimate'])} ranged nodes not estimated")
        if alignment.reflected:
            notes.append("reflected")
        engine["notes"] = notes
        report["methods"]["engine"] = engine
        plots["engine"] = (estimates, alignment)

    wanted = [] if args.no_baselines or ranges is None else (args.baselines or list(BASELINES))
    solvers = [n for n in LSQ_NAMES if n in wanted]
    if solvers:
        f_scale_m = args.huber_scale_m if args.huber_scale_m else HUBER_K * args.sigma_m
        try:
            results = run_baselines(links, solvers, f_scale_m, args.drop_threshold_m, args.resolve_loss)
        except BaselineError as error:
            results = []
            for name in solvers:
                report["methods"][name] = {"rmse_m": None, "nodes": 0, "notes": [f"not solved: {error}"]}
        for result in results:
            alignment = align(result.positions_m, truth_xy)
            entry = _method_json(alignment)
            entry.update(notes=result.notes, **result.details,
                         positions_m=[{"id": i, "x": float(p[0]), "y": float(p[1])}
                                      for i, p in sorted(result.positions_m.items())])
            report["methods"][result.name] = entry
            plots["baselines"][result.name] = {i: alignment.apply(p) for i, p in result.positions_m.items()}

    if "crb" in wanted:
        per = "link" if args.crb_per_link else "range"
        pairs = links.pairs if args.crb_per_link else list(zip(ranges.from_ids.tolist(), ranges.to_ids.tolist()))
        crb = anchor_free_crb(truth_xy, pairs, args.sigma_m)
        notes = [f"sigma {args.sigma_m:g} m, one entry per {per} ({crb.entries})"]
        if crb.skipped:
            notes.append(f"{crb.skipped} {per}(s) without truth at both ends left out")
        if not crb.rigid and crb.nodes:
            notes.append(f"not rigid (rank {crb.rank} < {2 * crb.nodes - 3}): the bound is too optimistic")
        report["crb"] = {"rmse_m": _finite_or_none(crb.rmse_m), "nodes": crb.nodes, "sigma_m": args.sigma_m, "per": per,
                         "entries": crb.entries, "skipped": crb.skipped, "rank": crb.rank, "rigid": crb.rigid,
                         "notes": notes}

    labels = args.label or [pathlib.Path(t).stem for t in args.trace]
    report["convergence"] = []
    for path, label in zip(args.trace, labels):
        snapshots = read_trace(path, bad)
        if not snapshots:
            raise InputError(f"{path}: no usable trace row")
        times = convergence_ranges(snapshots)
        curve = rmse_over_ranges(snapshots, truth_xy)
        report["convergence"].append({
            "label": label, "trace": path, "snapshots": len(snapshots), "last_ranges": snapshots[-1][0],
            "nodes": [{"id": i, "converged_at_ranges": t} for i, t in sorted(times.items())],
            "all_converged_at_ranges": all_converged_at(times),
            "never_converged": sorted(i for i, t in times.items() if t is None),
            "final_rmse_m": _finite_or_none(curve[-1].rmse_m) if curve else None,
            "rmse_over_ranges": [{"ranges": p.ranges, "rmse_m": p.rmse_m, "nodes": p.nodes} for p in curve]})
        plots["traces"].append((label, curve))

    report["bad_rows"] = {"count": len(bad), "rows": [b.as_json() for b in bad]}
    return report, plots


def _table(report: dict) -> str:
    rows = [("method", "RMSE (m)", "nodes", "notes")]
    for name in ("engine", *LSQ_NAMES):
        if name in report["methods"]:
            m = report["methods"][name]
            rows.append((TITLES[name], _fmt(m["rmse_m"]), str(m["nodes"]), "; ".join(m.get("notes", []))))
    if "crb" in report:
        c = report["crb"]
        rows.append((TITLES["crb"], _fmt(c["rmse_m"]), str(c["nodes"]), "; ".join(c["notes"])))
    widths = [max(len(r[k]) for r in rows) for k in range(3)]
    lines = [f"{r[0]:<{widths[0]}}  {r[1]:>{widths[1]}}  {r[2]:>{widths[2]}}  {r[3]}".rstrip() for r in rows]
    if len(rows) == 1:
        lines = []                      # traces only: no method to score

    # per-node errors, one column per method
    methods = [n for n in ("engine", *LSQ_NAMES) if n in report["methods"] and "per_node" in report["methods"][n]]
    traces = report["convergence"]
    if methods or traces:
        ids = sorted({p["id"] for n in methods for p in report["methods"][n]["per_node"]}
                     | {p["id"] for t in traces for p in t["nodes"]})
        errors = {n: {p["id"]: p["error_m"] for p in report["methods"][n]["per_node"]} for n in methods}
        converged = [{p["id"]: p["converged_at_ranges"] for p in t["nodes"]} for t in traces]
        header = ["node", *(f"{TITLES[n]} (m)" for n in methods), *(f"converged at ({t['label']})" for t in traces)]
        body = [[drawing.node_label(i), *(_fmt(errors[n].get(i)) for n in methods),
                 *(("never" if c[i] is None else str(c[i])) if i in c else "-" for c in converged)] for i in ids]
        widths = [max(len(row[k]) for row in [header, *body]) for k in range(len(header))]
        heading = "per-node errors (aligned)" + (" and convergence time (ranges processed)" if traces else "")
        lines += ["" if lines else None, heading]
        for row in [header, *body]:
            lines.append("  ".join(f"{cell:>{w}}" for cell, w in zip(row, widths)))
    for t in traces:
        at = t["all_converged_at_ranges"]
        never = ", ".join(drawing.node_label(i) for i in t["never_converged"])
        lines.append(f"trace {t['label']}: {t['snapshots']} snapshots up to {t['last_ranges']} ranges; "
                     + (f"all converged at {at} ranges" if at is not None else f"never converged: {never or '-'}")
                     + f"; final RMSE {_fmt(t['final_rmse_m'])} m")
    return "\n".join(line for line in lines if line is not None)


def _summary_lines(report: dict) -> list[str]:
    lines = []
    if "ranges" in report:
        r = report["ranges"]
        text = (f"ranges: {r['used']} used of {r['rows']} rows, {r['links']} links, {r['nodes']} nodes")
        if report["inputs"]["heights"]:
            text += f"; heights from {report['inputs']['heights']}: {r['projected']} projected, {r['clamped']} clamped"
            if r["without_height"]:
                text += f", {r['without_height']} left 3D (no height for {r['nodes_without_height']})"
        lines.append(text)
    return lines


def _plot_map(path: str, report: dict, plots: dict, with_baselines: bool, title: str) -> None:
    fig, ax = drawing.new_figure(drawing.MAP_SIZE_IN)
    truth = plots["truth"]
    involved = {i for pair in plots["links"] for i in pair}
    if "engine" in plots:
        involved |= set(plots["engine"][0])
    shown_truth = {i: truth[i] for i in sorted(involved or truth) if i in truth}
    positions = dict(shown_truth)
    aligned = {}
    if "engine" in plots:
        estimates, alignment = plots["engine"]
        aligned = {i: alignment.apply(e.xy_m) for i, e in estimates.items()}
        positions.update({i: p for i, p in aligned.items() if i not in positions})
    drawing.draw_links(ax, plots["links"], positions)       # the true network where the truth is known
    dropped = [(d["from"], d["to"]) for d in report["methods"].get("lsq-drop", {}).get("dropped_links", [])]
    if with_baselines and dropped:
        drawing.draw_links(ax, dropped, positions, color="tab:red", linestyle="--", linewidth=0.9, zorder=2)
        ax.plot([], [], color="tab:red", linestyle="--", linewidth=0.9, label=f"dropped by lsq-drop ({len(dropped)})")
    drawing.draw_truth(ax, np.array(list(shown_truth.values())))
    if with_baselines:
        for name, solution in plots["baselines"].items():
            color, marker = BASELINE_STYLE[name]
            label = f"{TITLES[name]} ({_fmt(report['methods'][name]['rmse_m'], 2)} m)"
            drawing.draw_estimates(ax, solution, None, label,
                                   color=color, marker=marker, ids=False)
    if "engine" in plots:
        estimates, alignment = plots["engine"]
        covariances = {i: alignment.rotate_covariance(e.cov_m2) for i, e in estimates.items()}
        drawing.draw_estimates(ax, aligned, covariances,
                               f"estimate, 2-sigma ({_fmt(report['methods']['engine']['rmse_m'], 2)} m)", ids=False)
        drawing.draw_ids(ax, aligned)
    else:
        drawing.draw_ids(ax, shown_truth)
    drawing.finish(fig, ax, path, title)


def _plot_rmse(path: str, report: dict, plots: dict, title: str) -> None:
    fig, ax = drawing.new_figure(drawing.CURVE_SIZE_IN)
    for label, curve in plots["traces"]:
        ax.plot([p.ranges for p in curve], [p.rmse_m for p in curve], label=label)
    if "crb" in report and report["crb"]["rmse_m"] is not None:
        ax.axhline(report["crb"]["rmse_m"], color="0.4", linestyle="--", linewidth=0.8,
                   label=f"CRB ({_fmt(report['crb']['rmse_m'], 2)} m)")
    ax.set_ylim(bottom=0)
    drawing.finish(fig, ax, path, title, xlabel="ranges processed", ylabel="aligned RMSE (m)", equal=False)


def _json_safe(value):
    """NaN and infinities are not JSON: they become null."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return _json_safe(float(value))
    return value


def _report_bad_rows(bad: list[BadRow]) -> None:
    by_file: dict[str, int] = {}
    for row in bad:
        by_file[row.path] = by_file.get(row.path, 0) + 1
        if by_file[row.path] <= BAD_ROWS_SHOWN:
            _log(f"{row}: row skipped")
    for path, count in by_file.items():
        _log(f"{path}: {count} bad row(s) skipped" + (" (all in --json)" if count > BAD_ROWS_SHOWN else ""))


@entry_point
def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    _check_arguments(parser, args)
    bad: list[BadRow] = []
    try:
        report, plots = evaluate(args, bad)
    except InputError as error:
        _report_bad_rows(bad)           # they often explain the error ("no usable row")
        _log(str(error))
        return 2
    _report_bad_rows(bad)

    table_out = sys.stderr if args.json == "-" else sys.stdout
    try:
        for line in _summary_lines(report):
            print(line, file=table_out)
        print(_table(report), file=table_out, flush=True)
    except BrokenPipeError:
        # The reader stopped early (| head): the files asked for are still written.
        os.dup2(os.open(os.devnull, os.O_WRONLY), table_out.fileno())
    title = args.title or f"cdro-eval: {args.estimates or args.ranges or args.trace[0]}"
    try:
        if args.map_png:
            _plot_map(args.map_png, report, plots, args.map_baselines, title)
        if args.rmse_png:
            _plot_rmse(args.rmse_png, report, plots, title)
        if args.json:
            text = json.dumps(_json_safe(report), indent=1, allow_nan=False) + "\n"
            if args.json == "-":
                sys.stdout.write(text)
            else:
                with open(args.json, "w") as f:
                    f.write(text)
    except OSError as error:
        _log(f"cannot write an output: {error}")
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
