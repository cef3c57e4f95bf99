"""Reading the CSV files cdro-eval compares (formats in docs/tools.md, cdro-eval).

Two kinds of bad input, treated differently on purpose:
- a file that cannot be used at all (missing, unreadable, not CSV, a required column
  missing) raises InputError: the tool exits 2 with the message;
- a bad row (a value that is not a finite number, a negative range, a node ranging itself,
  a repeated id, ...) is recorded as a BadRow with its file and line, counted and skipped, so
  one corrupt line in a long recording does not throw the recording away.
"""
from __future__ import annotations

import csv
import dataclasses
import math
from collections.abc import Iterator

import numpy as np


class InputError(ValueError):
    """A file that cannot be used at all."""


@dataclasses.dataclass(frozen=True)
class BadRow:
    path: str
    line: int                   # 1-based line of the file (the header is line 1)
    reason: str

    def __str__(self) -> str:
        return f"{self.path}:{self.line}: {self.reason}"

    def as_json(self) -> dict:
        return {"file": self.path, "line": self.line, "reason": self.reason}


class RowError(ValueError):
    """A row that is skipped (becomes a BadRow)."""


def parse_id(text: str | None) -> int:
    """A node id: decimal (24577), hex with 0x (0x6001), or an integral float (24577.0,
    as some CSV writers print integers)."""
    if text is None or not text.strip():
        raise RowError("empty id")
    text = text.strip()
    try:
        if text.lower().startswith("0x"):
            value = int(text, 16)
        else:
            number = float(text)
            if not math.isfinite(number) or number != int(number):
                raise ValueError
            value = int(number)
    except ValueError:
        raise RowError(f"id {text!r} is not an integer") from None
    if value < 0:
        raise RowError(f"id {text} is negative")
    return value


def parse_number(text: str | None, column: str) -> float:
    if text is None or not text.strip():
        raise RowError(f"{column} is empty")
    try:
        value = float(text)
    except ValueError:
        raise RowError(f"{column} {text.strip()!r} is not a number") from None
    if not math.isfinite(value):
        raise RowError(f"{column} {text.strip()!r} is not a finite number")
    return value


def parse_flag(text: str | None, column: str) -> bool:
    value = (text or "").strip()
    if value not in ("0", "1"):
        raise RowError(f"{column} {value!r} is neither 0 nor 1")
    return value == "1"


def csv_rows(path: str, required: list[str]) -> Iterator[tuple[int, dict]]:
    """(line, row) for every data row; InputError for a file that cannot be read or lacks a
    required column (checked before the first row is yielded)."""
    try:
        f = open(path, newline="")
    except OSError as error:
        raise InputError(f"{path}: cannot open: {error.strerror or error}") from None
    with f:
        try:
            reader = csv.DictReader(f)
            header = [name.strip() for name in (reader.fieldnames or [])]
        except (UnicodeDecodeError, csv.Error) as error:
            raise InputError(f"{path}: not a readable CSV file ({error})") from None
        if not header:
            raise InputError(f"{path}: empty file (expected a header with {','.join(required)})")
        reader.fieldnames = header          # tolerate "id, x, y" headers
        missing = [c for c in required if c not in header]
        if missing:
            raise InputError(f"{path}: missing column(s) {', '.join(missing)} (header: {','.join(header)})")
        try:
            for row in reader:
                yield reader.line_num, row
        except (UnicodeDecodeError, csv.Error) as error:
            raise InputError(f"{path}:{reader.line_num}: not a readable CSV row ({error})") from None


# ----------------------------------------------------------------------------- ranges

@dataclasses.dataclass
class Ranges:
    """Ranges in file order (the order the engine processed them)."""
    from_ids: np.ndarray                # int64
    to_ids: np.ndarray                  # int64
    range_m: np.ndarray                 # float
    lines: np.ndarray                   # the file line of each range
    rows: int = 0                       # data rows read, bad ones included

    def __len__(self) -> int:
        return len(self.range_m)

    @property
    def node_ids(self) -> list[int]:
        return sorted(set(self.from_ids.tolist()) | set(self.to_ids.tolist()))

    def links(self) -> dict[tuple[int, int], list[float]]:
        """(smaller id, larger id) -> the link's ranges (m): r_ij and r_ji are one link."""
        out: dict[tuple[int, int], list[float]] = {}
        for a, b, r in zip(self.from_ids.tolist(), self.to_ids.tolist(), self.range_m.tolist()):
            out.setdefault((min(a, b), max(a, b)), []).append(r)
        return out


def read_ranges(path: str, bad: list[BadRow]) -> Ranges:
    """`[t,]from,to,range_m`; t (if any) is not used: the file order is the processing order."""
    from_ids, to_ids, values, lines = [], [], [], []
    rows = 0
    for line, row in csv_rows(path, ["from", "to", "range_m"]):
        rows += 1
        try:
            a, b = parse_id(row["from"]), parse_id(row["to"])
            r = parse_number(row["range_m"], "range_m")
            if a == b:
                raise RowError(f"node {a} ranging itself")
            if r < 0:
                raise RowError(f"negative range {r:g} m")
        except RowError as error:
            bad.append(BadRow(path, line, str(error)))
            continue
        from_ids.append(a)
        to_ids.append(b)
        values.append(r)
        lines.append(line)
    return Ranges(np.array(from_ids, dtype=np.int64), np.array(to_ids, dtype=np.int64), np.array(values, dtype=float),
                  np.array(lines, dtype=np.int64), rows)


@dataclasses.dataclass
class Projection:
    ranges: Ranges
    projected: int = 0              # ranges replaced by their horizontal projection
    clamped: int = 0                # of those, r^2 < dz^2: set to 0
    without_height: int = 0         # an end without a known height: left as measured
    nodes_without_height: list[int] = dataclasses.field(default_factory=list)


def project_ranges(ranges: Ranges, heights_m: dict[int, float]) -> Projection:
    """3D ranges to the plane: sqrt(r^2 - dz^2) with dz the known height difference. Noise can
    make r shorter than dz; such a range is clamped to 0 and counted (not dropped, so that the
    counts of ranges stay those of the file)."""
    known = np.array([a in heights_m and b in heights_m for a, b in zip(ranges.from_ids, ranges.to_ids)], dtype=bool)
    dz = np.array([heights_m[a] - heights_m[b] if k else 0.0
                   for a, b, k in zip(ranges.from_ids.tolist(), ranges.to_ids.tolist(), known)])
    squared = ranges.range_m ** 2 - dz ** 2
    clamped = known & (squared < 0)
    out = ranges.range_m.copy()
    out[known] = np.sqrt(np.clip(squared[known], 0.0, None))
    missing = sorted({i for a, b, k in zip(ranges.from_ids.tolist(), ranges.to_ids.tolist(), known) if not k
                      for i in (a, b) if i not in heights_m})
    projected = Ranges(ranges.from_ids, ranges.to_ids, out, ranges.lines, ranges.rows)
    return Projection(projected, int(known.sum()), int(clamped.sum()), int((~known).sum()), missing)


# ----------------------------------------------------------------------------- nodes

@dataclasses.dataclass
class NodeEstimate:
    xy_m: np.ndarray                # (2,), the engine's frame
    cov_m2: np.ndarray              # 2x2
    converged: bool


def _estimate_from_row(row: dict) -> NodeEstimate:
    x, y = parse_number(row["x"], "x"), parse_number(row["y"], "y")
    var_x, cov_xy, var_y = (parse_number(row[c], c) for c in ("var_x", "cov_xy", "var_y"))
    if var_x < 0 or var_y < 0:
        raise RowError(f"negative variance (var_x {var_x:g}, var_y {var_y:g} m^2)")
    # a covariance must be positive semi-definite; allow what rounding to a few digits does
    if cov_xy * cov_xy > var_x * var_y * (1 + 1e-6) + 1e-12:
        raise RowError(f"covariance not positive semi-definite (cov_xy^2 {cov_xy * cov_xy:g} > var_x var_y "
                       f"{var_x * var_y:g} m^4)")
    return NodeEstimate(np.array([x, y]), np.array([[var_x, cov_xy], [cov_xy, var_y]]),
                        parse_flag(row["converged"], "converged"))


ESTIMATE_COLUMNS = ["id", "x", "y", "var_x", "cov_xy", "var_y", "converged"]


def read_estimates(path: str, bad: list[BadRow], unplaced: list[int] | None = None) -> dict[int, NodeEstimate]:
    """The engine's nodes CSV `id,x,y,var_x,cov_xy,var_y,converged` (m, m^2, 0/1).

    cdro-hostd writes a row with empty x, y and covariance for a node it has ranges of but has
    not placed (yet): that is an answer, not a damaged row, so its id goes to `unplaced` (when
    given) instead of `bad`."""
    out: dict[int, NodeEstimate] = {}
    seen: set[int] = set()
    for line, row in csv_rows(path, ESTIMATE_COLUMNS):
        try:
            node_id = parse_id(row["id"])
            if node_id in seen:
                raise RowError(f"id {node_id} repeated (the first row is kept)")
            if unplaced is not None and all(not (row[c] or "").strip() for c in ESTIMATE_COLUMNS[1:6]):
                seen.add(node_id)
                unplaced.append(node_id)
                continue
            out[node_id] = _estimate_from_row(row)
            seen.add(node_id)
        except RowError as error:
            bad.append(BadRow(path, line, str(error)))
    return out


def read_truth(path: str, bad: list[BadRow]) -> tuple[dict[int, np.ndarray], dict[int, float]]:
    """`id,x,y[,z]` (m): positions, and heights when the file has a z column."""
    xy: dict[int, np.ndarray] = {}
    z: dict[int, float] = {}
    has_z = None
    for line, row in csv_rows(path, ["id", "x", "y"]):
        if has_z is None:
            has_z = "z" in row
        try:
            node_id = parse_id(row["id"])
            if node_id in xy:
                raise RowError(f"id {node_id} repeated (the first row is kept)")
            position = np.array([parse_number(row["x"], "x"), parse_number(row["y"], "y")])
            height = parse_number(row["z"], "z") if has_z else None
        except RowError as error:
            bad.append(BadRow(path, line, str(error)))
            continue
        xy[node_id] = position
        if height is not None:
            z[node_id] = height
    return xy, z


def read_heights(path: str, bad: list[BadRow]) -> dict[int, float]:
    """`id,z` (m)."""
    out: dict[int, float] = {}
    for line, row in csv_rows(path, ["id", "z"]):
        try:
            node_id = parse_id(row["id"])
            if node_id in out:
                raise RowError(f"id {node_id} repeated (the first row is kept)")
            out[node_id] = parse_number(row["z"], "z")
        except RowError as error:
            bad.append(BadRow(path, line, str(error)))
    return out


# ----------------------------------------------------------------------------- trace

TRACE_COLUMNS = ["ranges", *ESTIMATE_COLUMNS]


def read_trace(path: str, bad: list[BadRow]) -> list[tuple[int, dict[int, NodeEstimate]]]:
    """The engine's trace `ranges,id,x,y,var_x,cov_xy,var_y,converged`: after every K-th
    processed range, one row per placed node. Returns the snapshots sorted by `ranges`
    (count of ranges processed so far), each id -> estimate."""
    snapshots: dict[int, dict[int, NodeEstimate]] = {}
    for line, row in csv_rows(path, TRACE_COLUMNS):
        try:
            count = parse_number(row["ranges"], "ranges")
            if count < 0 or count != int(count):
                raise RowError(f"ranges {row['ranges'].strip()!r} is not a count (a non-negative integer)")
            node_id = parse_id(row["id"])
            estimate = _estimate_from_row(row)
            snapshot = snapshots.setdefault(int(count), {})
            if node_id in snapshot:
                raise RowError(f"id {node_id} repeated at ranges {int(count)} (the first row is kept)")
            snapshot[node_id] = estimate
        except RowError as error:
            bad.append(BadRow(path, line, str(error)))
    return sorted(snapshots.items())
