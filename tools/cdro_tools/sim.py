"""cdro-sim: a simulated Pozyx network behind the CDRO firmware.

Three ways to run a scenario (a built-in name or a YAML file, see docs/tools.md):
  offline, in simulated time as fast as possible: CSV files (ranges as the firmware reports
    them, plus truth) and/or a capture file of the whole conversation (a simulated host
    configures the device after every HELLO);
  live: --pty LINK_PATH makes a pseudo-terminal that acts as the device, per the "Device
    behaviour" contract of docs/protocol.md, at --speed times real time (default 1) or "max"
    (as fast as the reader takes the bytes). The device powers on when a reader opens the
    link. It stops at the scenario's end (--hold: keeps going, the world frozen) or on
    SIGINT/SIGTERM, and removes the link.
  --random-network N --degree D: a random geometric network's ranges and truth (no device).
Faults (garbage, bit_flip, cut_frame, absurd, vanish, reset) come from the scenario's faults:
list and from --fault; their counts are printed at the end and written by --fault-report.

examples:
  cdro-sim --scenario demo --seed 7 --ranges-csv ranges.csv --truth-csv truth.csv --tracks-csv tracks.csv
  cdro-sim --scenario demo --pty /tmp/cdro-dev --speed 2 --capture run.cdrocap
  cdro-sim --scenario demo --pty /tmp/cdro-dev --speed max --fault garbage@10,bytes=40 \\
           --fault vanish@20,duration_s=3 --fault-report faults.json
  cdro-sim --random-network 40 --degree 6 --noise-m 0.1 --seed 3 --ranges-csv r.csv --truth-csv t.csv
  cdro-sim --list-scenarios
"""
from __future__ import annotations

import argparse
import json
import pathlib
import signal
import sys

from .simulation.link import LinkError
from .simulation.network import random_network
from .simulation.runner import LiveRunner, Simulation, print_to_stderr, run_offline, streams
from .simulation.scenario import ScenarioError, builtin_names, load_scenario, parse_fault_option, shared_view
from .simulation.world import World
from .cli import entry_point

log = print_to_stderr("cdro-sim")


def _speed(text: str) -> float | None:
    if text == "max":
        return None
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is neither a number nor max") from None
    if not value > 0.0 or value > 1e6:
        raise argparse.ArgumentTypeError(f"{text}: the speed factor must be above 0")
    return value


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cdro-sim", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    source = p.add_mutually_exclusive_group()
    source.add_argument("--scenario", metavar="NAME|PATH", help="built-in scenario name or YAML file")
    source.add_argument("--random-network", type=int, metavar="NODES", help="random geometric network of NODES nodes")
    source.add_argument("--list-scenarios", action="store_true", help="list the built-in scenarios and exit")
    p.add_argument("--print-scenario", action="store_true",
                   help="print what cdro-sim and cdro-fil both read from the scenario as JSON and exit")
    p.add_argument("--seed", type=int, help="random seed (default: the scenario's seed; 1 for --random-network)")
    p.add_argument("--duration", type=float, metavar="S", help="simulated seconds (default: the scenario's duration_s)")
    out = p.add_argument_group("files (any mode)")
    out.add_argument("--ranges-csv", metavar="OUT", help="t,from,to,range_m: every range the device reported")
    out.add_argument("--truth-csv", metavar="OUT", help="id,x,y,z: positions at the start")
    out.add_argument("--heights-csv", metavar="OUT", help="id,z")
    out.add_argument("--tracks-csv", metavar="OUT", help="t,id,x,y every 0.1 s for everything that moves")
    out.add_argument("--odometry-csv", metavar="OUT", help="t,distance_m,dheading_rad: the robot's wheel odometry")
    out.add_argument("--robot-truth-csv", metavar="OUT",
                     help="t,x,y,heading_rad: the robot's true pose per odometry step")
    out.add_argument("--motion-csv", metavar="OUT", help="t,id,moving: every node at t=0, then every change")
    out.add_argument("--capture", metavar="FILE",
                     help="capture file of the conversation (offline, or what --pty sent and received)")
    live = p.add_argument_group("live device")
    live.add_argument("--pty", metavar="LINK_PATH", help="act as the device on a pseudo-terminal linked at LINK_PATH")
    live.add_argument("--speed", type=_speed, default=1.0, metavar="X|max",
                      help="simulated time per wall time (default 1)")
    live.add_argument("--hold", action="store_true", help="keep running after the scenario's end (world frozen)")
    faults = p.add_argument_group("faults")
    faults.add_argument("--fault", action="append", default=[], metavar="KIND@T[,key=value...]",
                        help="add a fault at T simulated seconds, e.g. vanish@20,duration_s=3 (repeatable)")
    faults.add_argument("--no-faults", action="store_true", help="ignore the scenario's faults: list")
    faults.add_argument("--fault-report", metavar="FILE", help="write the fault counts and link counters as JSON")
    net = p.add_argument_group("random network")
    net.add_argument("--degree", type=float, help="mean node degree")
    net.add_argument("--noise-m", type=float, default=0.1, help="Gaussian range noise std, m (default 0.1)")
    net.add_argument("--sweeps", type=int, default=10, help="ranges per link (default 10)")
    net.add_argument("--height-range-m", type=float, nargs=2, metavar=("LO", "HI"),
                     help="random heights in [LO, HI] m (default: all nodes at z = 0)")
    net.add_argument("--nlos-fraction", type=float, default=0.0, help="fraction of links with a +0.3..1.5 m bias")
    return p


def _write_csv(path: str, header: str, rows, fmt: str) -> int:
    with open(path, "w", newline="\n") as f:
        f.write(header + "\n")
        for row in rows:
            f.write(fmt % tuple(row) + "\n")
    return len(rows)


def _truth_files(args, world: World, scenario, odometry_rng) -> list[str]:
    written = []
    if args.truth_csv:
        rows = [(n.id, *world.position(n.id, 0.0)) for n in scenario.nodes]
        written.append(f"{args.truth_csv} ({_write_csv(args.truth_csv, 'id,x,y,z', rows, '%d,%.3f,%.3f,%.3f')} nodes)")
    if args.heights_csv:
        rows = [(n.id, n.z_m) for n in scenario.nodes]
        written.append(f"{args.heights_csv} ({_write_csv(args.heights_csv, 'id,z', rows, '%d,%.3f')} nodes)")
    if args.tracks_csv:
        n = _write_csv(args.tracks_csv, "t,id,x,y", world.track_rows(), "%.3f,%d,%.4f,%.4f")
        written.append(f"{args.tracks_csv} ({n} rows)")
    if args.motion_csv:
        n = _write_csv(args.motion_csv, "t,id,moving", world.motion_rows(), "%.3f,%d,%d")
        written.append(f"{args.motion_csv} ({n} rows)")
    if args.odometry_csv or args.robot_truth_csv:
        odometry, truth = world.odometry(odometry_rng)
        if args.odometry_csv:
            n = _write_csv(args.odometry_csv, "t,distance_m,dheading_rad", odometry, "%.3f,%.6f,%.8f")
            written.append(f"{args.odometry_csv} ({n} rows)")
        if args.robot_truth_csv:
            n = _write_csv(args.robot_truth_csv, "t,x,y,heading_rad", truth, "%.3f,%.4f,%.4f,%.6f")
            written.append(f"{args.robot_truth_csv} ({n} rows)")
    return written


def _ranges_csv(path: str, ranges) -> str:
    rows = [(t_us / 1e6, a, b, mm / 1000.0) for t_us, a, b, mm in ranges]
    return f"{path} ({_write_csv(path, 't,from,to,range_m', rows, '%.3f,%d,%d,%.3f')} ranges)"


def _report(sim: Simulation, mode: str, duration_s: float, ended_by: str = "") -> dict:
    device = sim.device
    transport = sim.transport
    report = {"scenario": sim.scenario.name, "seed": sim.seed, "mode": mode,
              "simulated_s": round(device.now_us / 1e6, 6) if device else 0.0, **sim.faults.report(),
              "link": {"host_decoder": transport.tally.counters(), **vars(transport.stats)},
              "device": {"boots": device.boots if device else 0, "counters": dict(device.counters) if device else {},
                         "host_bytes_lost_booting": device.host_bytes_lost_booting if device else 0}}
    if ended_by:
        report["ended_by"] = ended_by
    return report


def _print_summary(report: dict) -> None:
    counts = report["counts"]
    parts = []
    for kind, c in counts.items():
        extra = ", ".join(f"{k} {v}" for k, v in c.items() if k != "injected" and v)
        parts.append(f"{kind} {c['injected']}" + (f" ({extra})" if extra else ""))
    log("faults injected: " + "; ".join(parts))
    decoder = report["link"]["host_decoder"]
    rejected = {k: v for k, v in decoder.items() if k.endswith("_errors") and v}
    log(f"link: {decoder['frames_ok']} good frames, rejections {rejected or 'none'}, "
        f"{report['link']['frames_lost_while_gone']} frames lost while gone; device: {report['device']['boots']} "
        f"boot(s), counters {report['device']['counters']}")


def _check_outputs(paths) -> None:
    """Output files go into existing directories, and are not directories themselves."""
    for path in filter(None, paths):
        p = pathlib.Path(path)
        if p.is_dir() or not p.parent.is_dir():
            raise ScenarioError(f"{path}: cannot write there ({'a directory' if p.is_dir() else 'no such directory'})")


def _run_random(args) -> int:
    if args.pty or args.capture:
        raise ScenarioError("--random-network writes CSV files only (no device: no --pty, no --capture)")
    if args.degree is None:
        raise ScenarioError("--random-network needs --degree")
    if not (args.ranges_csv or args.truth_csv or args.heights_csv):
        raise ScenarioError("nothing to do: give --ranges-csv and/or --truth-csv, --heights-csv")
    _check_outputs([args.ranges_csv, args.truth_csv, args.heights_csv])
    seed = 1 if args.seed is None else args.seed
    net = random_network(args.random_network, args.degree, seed, args.noise_m, args.sweeps,
                         tuple(args.height_range_m) if args.height_range_m else None, args.nlos_fraction)
    written = []
    if args.ranges_csv:
        n = _write_csv(args.ranges_csv, "t,from,to,range_m", net.ranges, "%.3f,%d,%d,%.3f")
        written.append(f"{args.ranges_csv} ({n} ranges)")
    if args.truth_csv:
        count = _write_csv(args.truth_csv, "id,x,y,z", net.nodes, "%d,%.3f,%.3f,%.3f")
        written.append(f"{args.truth_csv} ({count} nodes)")
    if args.heights_csv:
        rows = [(i, z) for i, _, _, z in net.nodes]
        written.append(f"{args.heights_csv} ({_write_csv(args.heights_csv, 'id,z', rows, '%d,%.3f')} nodes)")
    log(f"random network, seed {seed}: {len(net.nodes)} nodes, {len(net.links)} links, mean degree "
        f"{net.mean_degree:.2f}, radio range {net.radius_m:.2f} m, {net.biased_links} NLOS links; wrote "
        + ", ".join(written))
    return 0


@entry_point
def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        if args.list_scenarios:
            for name in builtin_names():
                scenario = load_scenario(name)
                print(f"{name}: {scenario.description.splitlines()[0] if scenario.description else ''}")
            return 0
        if args.random_network is not None:
            return _run_random(args)
        if not args.scenario:
            parser.error("give --scenario, --random-network or --list-scenarios")
        scenario = load_scenario(args.scenario)
        extra = [parse_fault_option(text) for text in args.fault]
        scenario.faults = sorted(([] if args.no_faults else scenario.faults) + extra, key=lambda f: f.at_s)
        seed = scenario.seed if args.seed is None else args.seed
        duration_s = scenario.duration_s if args.duration is None else args.duration
        if not duration_s > 0:
            raise ScenarioError(f"--duration {duration_s}: must be above 0")
        scenario.duration_s = duration_s
        world = World(scenario)
        if args.print_scenario:
            scenario.seed = seed
            print(json.dumps(shared_view(scenario), indent=1))
            return 0
        offline_outputs = [args.ranges_csv, args.capture, args.truth_csv, args.heights_csv, args.tracks_csv,
                           args.odometry_csv, args.robot_truth_csv, args.motion_csv]
        if not args.pty and not any(offline_outputs):
            parser.error("nothing to do: give --pty LINK_PATH, --capture FILE or CSV outputs (see --help)")
        _check_outputs([*offline_outputs, args.fault_report])
        log(f"scenario {scenario.name}, seed {seed}, {duration_s:g} s, {len(scenario.nodes)} nodes, "
            f"{len(scenario.faults)} fault(s)")
    except ScenarioError as error:
        print(f"cdro-sim: {error}", file=sys.stderr)
        return 2

    try:
        return _run_scenario(args, scenario, world, seed, duration_s)
    except OSError as error:
        print(f"cdro-sim: {error}", file=sys.stderr)
        return 1


def _run_scenario(args, scenario, world, seed: int, duration_s: float) -> int:
    if scenario.faults and not (args.pty or args.capture):
        log(f"{len(scenario.faults)} fault(s) ignored: faults act on the link (--pty or --capture), not on CSV files")
    written = _truth_files(args, world, scenario, streams(seed)["odometry"])
    try:
        if args.pty:
            stopping = []

            def on_signal(signum, frame):
                stopping.append(signum)
            signal.signal(signal.SIGTERM, on_signal)
            signal.signal(signal.SIGINT, on_signal)
            runner = LiveRunner(scenario, seed, args.pty, args.speed, duration_s, args.hold, args.capture,
                                True, log, lambda: bool(stopping))
            runner.run()
            sim, mode, ended_by = runner.sim, "pty", runner.ended_by or "signal"
            log(f"stopped ({ended_by}) after {sim.device.now_us / 1e6 if sim.device else 0:.3f} simulated s")
        else:
            sim = run_offline(scenario, seed, duration_s, args.capture, faults_enabled=bool(args.capture))
            mode, ended_by = ("capture" if args.capture else "csv"), ""
            if args.capture:
                written.append(f"{args.capture} ({sim.transport.rx.records + sim.transport.tx.records} records)")
    except LinkError as error:
        print(f"cdro-sim: {error}", file=sys.stderr)
        return 2
    if args.ranges_csv:
        written.append(_ranges_csv(args.ranges_csv, sim.ranges))
    report = _report(sim, mode, duration_s, ended_by)
    if sim.device is not None:
        c = sim.device.counters
        uptime_s = max((sim.device.now_us - sim.device.boot_us) / 1e6, 1e-9)
        ok = c["ranges_ok_direct"] + c["ranges_ok_remote"]
        since = " since the last boot" if sim.device.boots > 1 else ""
        log(f"{sim.device.now_us / 1e6:.1f} s simulated; {ok} ranges ({ok / uptime_s:.1f}/s), "
            f"{c['ranges_failed_direct'] + c['ranges_failed_remote']} failed attempts, {c['frames_sent']} frames sent"
            f"{since}")
    if scenario.faults or args.fault_report:
        _print_summary(report)
    if args.fault_report:
        with open(args.fault_report, "w") as f:
            json.dump(report, f, indent=1, sort_keys=True)
            f.write("\n")
        written.append(args.fault_report)
    if written:
        log("wrote " + ", ".join(written))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
