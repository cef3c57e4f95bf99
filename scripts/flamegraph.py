#!/usr/bin/env python3
"""A flame graph (SVG) of where a program's CPU time goes, from Linux `perf` samples (docs/bench.md).

    scripts/flamegraph.py --out docs/bench/x.svg -- build/bin/cdro-bench-engine --one-network 300 ...
    scripts/flamegraph.py --out x.svg --perf-script samples.txt    # render `perf script` output

With a command, it runs `perf record` (DWARF call graphs, --frequency samples a second per CPU)
on it, then `perf script`, and renders every thread's samples: the bottom row splits them into
the main thread (the process's first) and the other threads (the global solve's workers), so the
range path's share is read off at once. Each box is a function, as wide as the samples in which
it was on the stack; above it, what it called. Frames of the C++ library, Eigen and the thread
plumbing are folded into their caller (a matrix product is dozens of inlined template frames
deep), except where a sample landed; template and argument lists are cut from the names. Hover a
box for its full name, samples and share.
The output depends only on the samples: children are ordered by name, colours by a hash of it.

Needs `perf` (Debian: apt-get install linux-perf) and, to record, permission to profile
(root, or kernel.perf_event_paranoid <= 1). Figures only: run on purpose, never by the tests.
Exit 2 on unusable input.
"""
from __future__ import annotations

import argparse
import hashlib
import html
import pathlib
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field

# Inlined frames from these are folded into their caller.
LIBRARY_PREFIXES = ("Eigen::", "std::", "__gnu_cxx::", "__invoke", "_M_", "operator{call}", "__pthread", "start_thread",
                    "clone3")
MAIN_THREAD = "main thread"
OTHER_THREADS = "other threads"

WIDTH_PX = 1200
ROW_PX = 16
MIN_BOX_PX = 1.0  # boxes narrower than this are not drawn (their samples count in the parent)
FONT_PX = 11
CHAR_PX = 6.6  # a character's width at FONT_PX, for fitting labels


class FlameError(ValueError):
    """Input the flame graph cannot be made from; the message says why."""


@dataclass
class Frame:
    name: str
    samples: int = 0
    children: dict[str, Frame] = field(default_factory=dict)

    def child(self, name: str) -> Frame:
        if name not in self.children:
            self.children[name] = Frame(name)
        return self.children[name]


def short_name(symbol: str) -> str:
    """The function's name without its offset, template arguments and argument list."""
    symbol = re.sub(r"\+0x[0-9a-f]+$", "", symbol.strip()).replace("(anonymous namespace)", "{anonymous}")
    symbol = symbol.replace("operator()", "operator{call}")
    out, depth = [], 0
    for char in symbol:  # drop <...> and (...) at any depth, keeping "operator<" and the like rare
        if char in "<(":
            depth += 1
        elif char in ">)" and depth > 0:
            depth -= 1
        elif depth == 0:
            out.append(char)
    name = "".join(out).strip()
    return name or symbol


def parse_perf_script(text: str) -> list[tuple[int, int, list[tuple[str, bool]]]]:
    """Samples of `perf script` output: (pid, tid, frames leaf first as (symbol, inlined))."""
    samples = []
    header = re.compile(r"^\S.*?\s(\d+)(?:/(\d+))?\s+\[?\d*\]?\s*[\d.]+:")
    current = None
    for number, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            if current is not None:
                samples.append(current)
                current = None
            continue
        if not line[0].isspace():
            match = header.match(line)
            if match is None:
                raise FlameError(f"line {number}: not a `perf script` sample header: {line[:80]!r}")
            if current is not None:
                samples.append(current)
            pid_or_tid = int(match.group(1))
            tid = int(match.group(2)) if match.group(2) else pid_or_tid
            pid = pid_or_tid
            current = (pid, tid, [])
            continue
        if current is None:
            raise FlameError(f"line {number}: a stack frame before any sample header")
        parts = line.split(None, 1)
        if len(parts) < 2:
            continue
        rest = parts[1]
        inlined = rest.endswith("(inlined)")
        symbol = re.sub(r"\s+\([^()]*\)$", "", rest)  # the trailing (dso) or (inlined)
        current[2].append((symbol, inlined))
    if current is not None:
        samples.append(current)
    return samples


def build_tree(samples, main_tid: int | None = None, keep_library_inlines: bool = False) -> Frame:
    """Stacks merged root first, under one box per kind of thread. The main thread is main_tid, or
    the lowest thread id seen (a process's first thread has the process's id, the lowest)."""
    if not samples:
        raise FlameError("no samples")
    if main_tid is None:
        main_tid = min(tid for _, tid, _ in samples)
    root = Frame("all")
    for _, tid, frames in samples:
        kept = []
        for symbol, inlined in frames:
            if symbol in ("[unknown]", "") or re.fullmatch(r"0x[0-9a-f]+", symbol):
                continue
            name = short_name(symbol)
            # Library plumbing is folded into its caller (inlined always; called, unless it is
            # where the sample landed: std::sort's own time stays visible).
            library = name.startswith(LIBRARY_PREFIXES) or symbol.startswith(LIBRARY_PREFIXES)
            if library and not keep_library_inlines and (inlined or kept):
                continue
            kept.append(name)
        node = root
        node.samples += 1
        node = node.child(MAIN_THREAD if tid == main_tid else OTHER_THREADS)
        node.samples += 1
        for name in reversed(kept):
            node = node.child(name)
            node.samples += 1
    return root


def colour(name: str) -> str:
    digest = hashlib.sha256(name.encode()).digest()
    return f"rgb({205 + digest[0] % 50},{80 + digest[1] % 140},{digest[2] % 60})"


def render_svg(root: Frame, title: str) -> str:
    def depth_of(frame: Frame) -> int:
        return 1 + max((depth_of(c) for c in frame.children.values()), default=0)

    rows = depth_of(root)
    height = (rows + 2) * ROW_PX + 8
    scale = WIDTH_PX / root.samples
    boxes: list[str] = []

    def draw(frame: Frame, x: float, row: int) -> None:
        width = frame.samples * scale
        if width < MIN_BOX_PX:
            return
        y = height - (row + 1) * ROW_PX - 4
        share = 100.0 * frame.samples / root.samples
        tip = html.escape(f"{frame.name}: {frame.samples} samples, {share:.1f} %")
        label = re.sub(r"^cdro::(engine::)?", "", frame.name)  # our namespace: the tooltip has it
        if len(label) * CHAR_PX >= width - 4:
            label = label[: int((width - 4) / CHAR_PX) - 2] + ".." if width > 4 * CHAR_PX else ""
        boxes.append(f'<g><title>{tip}</title><rect x="{x:.2f}" y="{y}" width="{width:.2f}" height="{ROW_PX - 1}" '
                     f'fill="{colour(frame.name)}" rx="2"/>'
                     + (f'<text x="{x + 3:.2f}" y="{y + ROW_PX - 4}">{html.escape(label)}</text>' if label else "")
                     + "</g>")
        child_x = x
        for name in sorted(frame.children):
            child = frame.children[name]
            draw(child, child_x, row + 1)
            child_x += child.samples * scale

    draw(root, 0.0, 0)
    return (f'<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH_PX}" height="{height}" '
            f'font-family="monospace" font-size="{FONT_PX}">\n'
            f'<rect width="100%" height="100%" fill="#fdfdf8"/>\n'
            f'<text x="{WIDTH_PX / 2}" y="{ROW_PX}" text-anchor="middle" font-size="{FONT_PX + 2}">'
            f'{html.escape(title)} ({root.samples} samples)</text>\n' + "\n".join(boxes) + "\n</svg>\n")


def record(command: list[str], frequency_hz: int) -> str:
    if shutil.which("perf") is None:
        raise FlameError("perf is not installed (Debian: apt-get install linux-perf)")
    with tempfile.TemporaryDirectory() as folder:
        data = pathlib.Path(folder) / "perf.data"
        recorded = subprocess.run(["perf", "record", "-F", str(frequency_hz), "--call-graph", "dwarf,16384", "-o",
                                   str(data), "--", *command], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                  text=True)
        if recorded.returncode != 0:
            raise FlameError(f"perf record failed (exit {recorded.returncode}): {recorded.stderr.strip()[-400:]}")
        script = subprocess.run(["perf", "script", "-i", str(data)], capture_output=True, text=True)
        if script.returncode != 0:
            raise FlameError(f"perf script failed: {script.stderr.strip()[-400:]}")
        return script.stdout


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True, type=pathlib.Path, help="the SVG to write")
    parser.add_argument("--perf-script", type=pathlib.Path,
                        help="render this `perf script` output instead of recording")
    parser.add_argument("--title", default="", help="the graph's title (default: the command)")
    parser.add_argument("--frequency", type=int, default=499, help="samples a second per CPU (default 499)")
    parser.add_argument("--keep-library-inlines", action="store_true", help="keep std::, Eigen:: and thread frames")
    parser.add_argument("command", nargs="*", help="the program to profile and its arguments (after --)")
    args = parser.parse_args(argv)
    try:
        if (args.perf_script is None) == (not args.command):
            raise FlameError("give either --perf-script FILE or a command after --")
        if args.perf_script is not None:
            try:
                text = args.perf_script.read_text(errors="replace")
            except OSError as error:
                raise FlameError(f"{args.perf_script}: {error.strerror}") from error
        else:
            text = record(args.command, args.frequency)
        tree = build_tree(parse_perf_script(text), keep_library_inlines=args.keep_library_inlines)
        title = args.title or " ".join(args.command) or str(args.perf_script)
        args.out.write_text(render_svg(tree, title))
    except FlameError as error:
        print(f"flamegraph: {error}", file=sys.stderr)
        return 2
    main_share = 100.0 * tree.children.get(MAIN_THREAD, Frame("")).samples / tree.samples
    print(f"flamegraph: {tree.samples} samples, {main_share:.1f} % on the main thread -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
