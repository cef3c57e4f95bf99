"""Reading the CSV files the tools take: the one CSV reader of the Python side (Reader), and the
files of cdro-eval on top of it (formats in docs/tools.md, cdro-eval).

The reader follows the C++ one (host/csv/include/cdro/csv/reader.hpp, its manual) rule for rule,
so that a file means the same thing to cdro-hostd and to the tools that judge what it made of it;
tests/data/csv_rules/cases.json holds both to the same answers (tests/csv/test_csv_rules.cpp,
tests/tools/test_csv_rules.py). In short:

- Lines end with \\n or \\r\\n; a UTF-8 byte-order mark at the start is skipped; blank lines and
  lines whose first other character is # are skipped anywhere and keep their numbers (a line
  number is the one an editor shows).
- Fields are separated by commas, spaces and tabs around them are not part of them, and a field
  may be quoted as RFC 4180 says (on one line; text after the closing quote makes the row bad).
- Columns are looked up by name in the header (the first line that is not blank or a comment);
  a header without a required column, or naming a declared column twice, refuses the file. A
  Format may take files without a header (the columns by position, one layout per number of
  fields): a first line whose every field is empty or a number to C's strtod (nan and inf too)
  is then data.
- Values: a number is the whole field as strtod reads it, finite and not underflowing (so
  "0x1p3" is 8, and "", "nan", "1e999", "1e-400", "1_0" are not numbers); a node id is 1..65535,
  decimal ("+" allowed) or 0x hex, never "24577.0".

Two kinds of bad input, treated differently on purpose:
- a file that cannot be used at all (missing, unreadable, not CSV, a header without a required
  column) raises InputError: the tool exits 2 with the message;
- a bad row (a value that is not what its column needs, too few fields, a broken quote, and the
  tools' own checks: a negative range, a node ranging itself, a repeated id, ...) is recorded as
  a BadRow with its file and line, counted and skipped (Policy.LENIENT), so one corrupt line in
  a long recording does not throw the recording away; with Policy.STRICT it is an InputError.
"""
from __future__ import annotations

import dataclasses
import enum
import math
import os
import re
import sys
from collections.abc import Callable
from fractions import Fraction
from typing import NoReturn

import numpy as np

MAX_LINE_BYTES = 4096           # bytes (csv::kMaxLineBytes): no row of these files comes near it
KEPT_PROBLEMS = 20              # bad rows whose reasons a Reader keeps by default (all are counted)


class InputError(ValueError):
    """A file that cannot be used at all, or (Policy.STRICT) its first bad row: "PATH[:LINE]: why"."""


class FormatBug(RuntimeError):
    """A Format that contradicts itself, or an accessor asked for a column the Format did not
    declare: a bug of the caller, not bad input (csv's std::logic_error)."""


@dataclasses.dataclass(frozen=True)
class BadRow:
    path: str
    line: int                   # 1-based, as an editor counts (comments and blank lines included)
    reason: str

    def __str__(self) -> str:
        return f"{self.path}:{self.line}: {self.reason}"

    def as_json(self) -> dict:
        return {"file": self.path, "line": self.line, "reason": self.reason}


class RowError(ValueError):
    """A row that is bad (Row's accessors and reject raise it; the Reader turns it into a BadRow)."""


class Policy(enum.Enum):
    STRICT = "strict"           # the first bad row is an InputError
    LENIENT = "lenient"         # bad rows are skipped, counted, their reasons kept


@dataclasses.dataclass(frozen=True)
class Format:
    required: tuple[str, ...]                       # a header must name them; a row must have them
    optional: tuple[str, ...] = ()                  # taken when there (Row.has)
    # Accepted without a header: the columns by position, one layout per number of fields (each
    # with every required column; other names are positions nobody reads). None: a header is
    # required.
    headerless: tuple[tuple[str, ...], ...] = ()


@dataclasses.dataclass
class Summary:
    data_rows: int = 0          # rows of data read, good and bad (not the header, comments, blanks)
    bad_rows: int = 0           # Policy.LENIENT: rows skipped
    problems: list[BadRow] = dataclasses.field(default_factory=list)  # the first kept ones, in file order


# strtod's whole grammar in the C locale (the programs never change it): leading white space,
# a sign, then a decimal or 0x hexadecimal number, inf, infinity or nan(chars), any case.
_STRTOD = re.compile(
    r"[ \t\n\v\f\r]*(?P<sign>[+-]?)(?:"
    r"(?P<dec>(?P<dec_digits>[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?)"
    r"|0[xX](?P<hex>(?P<hex_digits>[0-9a-fA-F]+\.?[0-9a-fA-F]*|\.[0-9a-fA-F]+)(?:[pP](?P<hex_exp>[+-]?[0-9]+))?)"
    r"|(?i:inf(?:inity)?|nan(?:\([0-9A-Za-z_]*\))?))", re.ASCII)
_NODE_ID = re.compile(r"0[xX](?P<hex>[0-9a-fA-F]+)|\+?(?P<dec>[0-9]+)", re.ASCII)
# A non-zero value below this, rounded to 53 bits with an unbounded exponent, is tiny: when it is
# also inexact, strtod reports ERANGE (glibc detects tininess after rounding) and the field is
# refused, as it is in C++.
_TINY = Fraction(sys.float_info.min) * (1 - Fraction(1, 2 ** 54))
_BLANKS = " \t\r"               # around a field (csv's isBlank)
_BOM = b"\xef\xbb\xbf"


def _exact(match: re.Match) -> Fraction:
    """The exact value a strtod match names (finite forms only)."""
    if match["dec"] is not None:
        value = Fraction(match["dec"])
    else:
        digits = match["hex_digits"]
        point = digits.find(".")
        fraction_digits = 0 if point < 0 else len(digits) - point - 1
        value = Fraction(int(digits.replace(".", ""), 16)) * Fraction(2) ** (int(match["hex_exp"] or 0)
                                                                            - 4 * fraction_digits)
    return -value if match["sign"] == "-" else value


def parse_number(text: str) -> float | None:
    """The whole text as a finite double, as csv::parseNumber reads it (strtod, refused on ERANGE
    and when not finite); None otherwise."""
    match = _STRTOD.fullmatch(text)
    if match is None or (match["dec"] is None and match["hex"] is None):
        return None             # not a number, or inf / nan
    try:
        if match["dec"] is not None:
            value = float(match["sign"] + match["dec"])
        else:
            value = float.fromhex(match["sign"] + "0x" + match["hex"])
    except OverflowError:       # float.fromhex beyond the largest double
        return None
    if math.isinf(value):
        return None
    if abs(value) <= sys.float_info.min:
        mantissa = match["dec_digits"] if match["dec"] is not None else match["hex_digits"]
        if value == 0.0 and mantissa.strip("0.") == "":
            return value        # a zero, written as one
        if value == 0.0:
            return None         # underflow to zero
        exact = _exact(match)
        if abs(exact) < _TINY and Fraction(value) != exact:
            return None         # underflow to a subnormal, inexact
    return value


def parse_node_id(text: str) -> int | None:
    """A node id as csv::parseNodeId reads it: "42" (or "+42") or "0x2A" (or "0X2a"), in 1..65535;
    None otherwise. Ids follow the live link's rule (common/include/cdro/frames.h): 0 is not a node
    (it means "none" in the protocol), so a file and a capture of the same network name the same
    nodes."""
    match = _NODE_ID.fullmatch(text)
    if match is None:
        return None
    digits, base, most = (match["hex"], 16, 4) if match["hex"] is not None else (match["dec"], 10, 5)
    digits = digits.lstrip("0")
    if len(digits) > most:      # before int(): a field may hold thousands of digits
        return None
    value = int(digits or "0", base)
    return value if 1 <= value <= 65535 else None


def _looks_like_data(field: str) -> bool:
    """A field of a first line that is data: empty, or anything strtod reads whole (nan and inf
    too: a data row with a bad value is a bad row, not a header; 0x hex among the rest)."""
    return field == "" or _STRTOD.fullmatch(field) is not None


def _split(line: str) -> tuple[list[str], str | None]:
    """A line's fields, unquoted and trimmed, and why the row is bad (a broken quote) or None."""
    if '"' not in line:
        return [field.strip(_BLANKS) for field in line.split(",")], None
    fields: list[str] = []
    i, end = 0, len(line)
    while True:
        while i < end and line[i] in _BLANKS:
            i += 1
        if i < end and line[i] == '"':
            i += 1
            text: list[str] = []
            closed = False
            while i < end:
                if line[i] == '"':
                    if i + 1 < end and line[i + 1] == '"':
                        text.append('"')
                        i += 2
                        continue
                    i += 1
                    closed = True
                    break
                text.append(line[i])
                i += 1
            if not closed:
                return fields, "a quoted field without its closing quote (a field does not span lines)"
            while i < end and line[i] in _BLANKS:
                i += 1
            if i < end and line[i] != ",":
                return fields, "text after the closing quote of a quoted field"
            fields.append("".join(text))
        else:
            comma = line.find(",", i)
            stop = end if comma < 0 else comma
            fields.append(line[i:stop].rstrip(_BLANKS))
            i = stop
        if i >= end:
            return fields, None
        i += 1                  # the comma


def _skipped(line: str) -> bool:
    """A blank line or a comment."""
    text = line.lstrip(_BLANKS)
    return not text or text[0] == "#"


class _Lines:
    """A file's lines in one pass, without their ends; a line longer than MAX_LINE_BYTES or a
    0x00 byte means the file is not a CSV at all (read with a bounded buffer: /dev/zero is
    refused, not read into memory)."""

    def __init__(self, path: str):
        self.path = path
        self.number = 0
        if os.path.isdir(path):
            raise InputError(f"{path}: is a directory, not a CSV file")
        try:
            self._file = open(path, "rb")
        except OSError as error:
            raise InputError(f"{path}: cannot open the file ({error.strerror or error})") from None
        try:
            if self._file.peek(len(_BOM))[:len(_BOM)] == _BOM:
                self._file.read(len(_BOM))      # spreadsheets write one
        except OSError as error:
            self.close()
            raise InputError(f"{path}: read failed after line 0 ({error.strerror or error})") from None

    def next(self) -> str | None:
        """The next line (None at the end of the file)."""
        try:
            raw = self._file.readline(MAX_LINE_BYTES + 2)
        except OSError as error:
            raise InputError(f"{self.path}: read failed after line {self.number} ({error.strerror or error})") \
                from None
        if not raw:
            return None
        content = raw[:-1] if raw.endswith(b"\n") else raw
        if b"\0" in content:
            raise InputError(f"{self.path}:{self.number + 1}: a 0x00 byte: not a CSV file")
        if len(content) > MAX_LINE_BYTES:
            raise InputError(f"{self.path}:{self.number + 1}: a line longer than {MAX_LINE_BYTES} bytes: "
                             "not a CSV file of this kind")
        self.number += 1
        if content.endswith(b"\r"):
            content = content[:-1]
        # Bytes that are not UTF-8 can only be part of a field that is not a number, an id or a
        # declared name, in C++ as here; they show as U+FFFD in a message.
        return content.decode("utf-8", "replace")

    def close(self) -> None:
        self._file.close()


class Row:
    """One data row, valid inside on_row only. The accessors take a declared column's name and
    raise RowError when the field is not what they want, with a reason that names the column and
    shows the text ("range_m 'five' is not a finite number")."""

    __slots__ = ("line", "_fields", "_layout", "_reader")

    def __init__(self, reader: Reader, line: int, fields: list[str], layout: list[int | None]):
        self._reader = reader
        self.line = line
        self._fields = fields
        self._layout = layout

    def _index(self, column: str) -> int | None:
        return self._layout[self._reader._declared_index(column)]

    def has(self, column: str) -> bool:
        """Whether the row has a field for the column (an optional one: the header names it and
        the row is long enough)."""
        index = self._index(column)
        return index is not None and index < len(self._fields)

    def text(self, column: str) -> str:
        """The field as written (unquoted, without the spaces around it)."""
        index = self._index(column)
        if index is None:
            raise RowError(f"no column '{column}'")
        if index >= len(self._fields):
            raise RowError(f"too few fields ({len(self._fields)})")
        return self._fields[index]

    def number(self, column: str) -> float:
        """A finite number (parse_number)."""
        text = self.text(column)
        value = parse_number(text)
        if value is None:
            raise RowError(f"{column} '{text}' is not a finite number")
        return value

    def node_id(self, column: str) -> int:
        """A node id, 1..65535, decimal or 0x hex (parse_node_id)."""
        text = self.text(column)
        value = parse_node_id(text)
        if value is None:
            raise RowError(f"{column} '{text}' is not a node id (1..65535, decimal or 0x hex; 0 is not a node on "
                           "the live link either)")
        return value

    def flag(self, column: str) -> bool:
        """A number that is 0 or 1 (cdro-hostd's motion file reads `moving` so)."""
        value = self.number(column)
        if value not in (0.0, 1.0):
            self.reject(f"{column} must be 0 or 1")
        return value == 1.0

    def reject(self, why: str) -> NoReturn:
        """The row is bad for the caller's own reason."""
        raise RowError(why)


class Reader:
    """Opens a file and reads up to its header (or first data row), raising InputError; then
    for_each gives each data row, with the policy for bad rows. Close it (with, or for_each's
    end)."""

    def __init__(self, path: str, fmt: Format, policy: Policy, kept_problems: int | None = KEPT_PROBLEMS):
        self.path = path
        self.format = fmt
        self.policy = policy
        self.kept_problems = kept_problems      # None: all
        self.summary = Summary()
        self.columns: tuple[str, ...] = ()      # the header's names, as written (none without one)
        self._header = False
        self._declared = (*fmt.required, *fmt.optional)
        if len(set(self._declared)) != len(self._declared):
            twice = next(c for i, c in enumerate(self._declared) if c in self._declared[:i])
            raise FormatBug(f"csv Format declares column '{twice}' twice")
        self._by_count: dict[int, list[int | None]] = {}
        for names in fmt.headerless:
            if len(names) in self._by_count:
                raise FormatBug(f"csv Format has two headerless layouts of {len(names)} fields")
            layout = [names.index(c) if c in names else None for c in self._declared]
            for column in fmt.required:
                if layout[self._declared_index(column)] is None:
                    raise FormatBug(f"csv Format has a headerless layout without column '{column}'")
            self._by_count[len(names)] = layout
        self._header_layout: list[int | None] = [None] * len(self._declared)
        self._required_fields = 0
        self._pending: tuple[int, list[str], str | None] | None = None   # a first data line
        self._read = False
        self._lines = _Lines(path)
        try:
            self._read_header()
        except BaseException:
            self.close()
            raise

    def __enter__(self) -> Reader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._lines.close()

    @property
    def has_header(self) -> bool:
        return self._header

    def _declared_index(self, column: str) -> int:
        try:
            return self._declared.index(column)
        except ValueError:
            raise FormatBug(f"csv: column '{column}' was not declared in the Format ({self.path})") from None

    def _read_header(self) -> None:
        expected = ",".join(self.format.required)
        while (line := self._lines.next()) is not None:
            if _skipped(line):
                continue
            where = f"{self.path}:{self._lines.number}: "
            fields, why = _split(line)
            data = why is None and all(_looks_like_data(f) for f in fields)
            if data and self.format.headerless:
                self._pending = (self._lines.number, fields, why)
                return
            if data:
                raise InputError(f"{where}no header: the first line is data (expected a header naming the columns "
                                 f"{expected})")
            if why is not None:
                raise InputError(f"{where}the first line: {why}")
            for i, name in enumerate(fields):
                if name in self._declared:
                    d = self._declared.index(name)
                    if self._header_layout[d] is not None:
                        raise InputError(f"{where}the header names column '{name}' twice")
                    self._header_layout[d] = i
            for d, column in enumerate(self.format.required):
                index = self._header_layout[d]
                if index is None:
                    raise InputError(f"{where}the header has no column '{column}' (expected {expected})")
                self._required_fields = max(self._required_fields, index + 1)
            self._header = True
            self.columns = tuple(fields)
            return
        if not self.format.headerless:
            raise InputError(f"{self.path}: empty file (expected a header naming the columns {expected})")

    def _bad_row(self, line: int, why: str) -> None:
        if self.policy is Policy.STRICT:
            raise InputError(f"{self.path}:{line}: {why}")
        self.summary.bad_rows += 1
        if self.kept_problems is None or len(self.summary.problems) < self.kept_problems:
            self.summary.problems.append(BadRow(self.path, line, why))

    def for_each(self, on_row: Callable[[Row], object]) -> None:
        """Calls on_row for each data row, in file order; a RowError it raises (an accessor's, or
        Row.reject) makes the row bad. Raises InputError (a file that turns out unusable further
        on; Policy.STRICT: the first bad row). Once only; closes the file."""
        if self._read:
            raise FormatBug(f"csv Reader.for_each called twice ({self.path})")
        self._read = True
        counts = " or ".join(str(n) for n in sorted(self._by_count))
        try:
            while True:
                if self._pending is not None:
                    line, fields, why = self._pending
                    self._pending = None
                else:
                    text = self._lines.next()
                    if text is None:
                        return
                    if _skipped(text):
                        continue
                    line = self._lines.number
                    fields, why = _split(text)
                if why is not None:
                    self._bad_row(line, why)
                elif self.has_header and len(fields) < self._required_fields:
                    self._bad_row(line, f"too few fields ({len(fields)})")
                elif not self.has_header and len(fields) not in self._by_count:
                    self._bad_row(line, f"{len(fields)} fields, expected {counts}")
                else:
                    layout = self._header_layout if self.has_header else self._by_count[len(fields)]
                    try:
                        on_row(Row(self, line, fields, layout))
                    except RowError as error:
                        self._bad_row(line, str(error))
                self.summary.data_rows += 1
        finally:
            self.close()


def read_rows(path: str, fmt: Format, on_row: Callable[[Row], object], bad: list[BadRow] | None,
              policy: Policy = Policy.LENIENT) -> Summary:
    """A whole file through on_row; every bad row (Policy.LENIENT) is appended to `bad`, also those
    before an InputError further on (they often explain it)."""
    reader = Reader(path, fmt, policy, kept_problems=None)
    try:
        reader.for_each(on_row)
    finally:
        if bad is not None:
            bad.extend(reader.summary.problems)
    return reader.summary


# ----------------------------------------------------------------------------- ranges

# cdro-hostd's ranges (host/hostd/src/csv_input.cpp): t optional, and without a header 3 or 4 fields.
RANGES_FORMAT = Format(("from", "to", "range_m"), ("t",), (("from", "to", "range_m"), ("t", "from", "to", "range_m")))


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


def read_ranges(path: str, bad: list[BadRow], policy: Policy = Policy.LENIENT) -> Ranges:
    """`[t,]from,to,range_m`; t (if any) must be a number as cdro-hostd reads it, and is not used
    otherwise: the file order is the processing order."""
    from_ids, to_ids, values, lines = [], [], [], []

    def on_row(row: Row) -> None:
        if row.has("t"):
            row.number("t")
        a, b, r = row.node_id("from"), row.node_id("to"), row.number("range_m")
        if a == b:
            row.reject(f"node {a} ranging itself")
        if r < 0:
            row.reject(f"negative range {r:g} m")
        from_ids.append(a)
        to_ids.append(b)
        values.append(r)
        lines.append(row.line)

    summary = read_rows(path, RANGES_FORMAT, on_row, bad, policy)
    return Ranges(np.array(from_ids, dtype=np.int64), np.array(to_ids, dtype=np.int64), np.array(values, dtype=float),
                  np.array(lines, dtype=np.int64), summary.data_rows)


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


def _estimate_from_row(row: Row) -> NodeEstimate:
    x, y = row.number("x"), row.number("y")
    var_x, cov_xy, var_y = (row.number(c) for c in ("var_x", "cov_xy", "var_y"))
    converged = row.flag("converged")
    if var_x < 0 or var_y < 0:
        row.reject(f"negative variance (var_x {var_x:g}, var_y {var_y:g} m^2)")
    # a covariance must be positive semi-definite; allow what rounding to a few digits does
    if cov_xy * cov_xy > var_x * var_y * (1 + 1e-6) + 1e-12:
        row.reject(f"covariance not positive semi-definite (cov_xy^2 {cov_xy * cov_xy:g} > var_x var_y "
                   f"{var_x * var_y:g} m^4)")
    return NodeEstimate(np.array([x, y]), np.array([[var_x, cov_xy], [cov_xy, var_y]]), converged)


ESTIMATE_COLUMNS = ("id", "x", "y", "var_x", "cov_xy", "var_y", "converged")
ESTIMATES_FORMAT = Format(ESTIMATE_COLUMNS)             # written by cdro-hostd, always with its header
# `id,x,y[,z]`; without a header id,x,y or id,x,y,z, the layouts cdro-hostd takes for --fixed-csv
# and --heights-csv, so that one positions file is read alike by both.
TRUTH_FORMAT = Format(("id", "x", "y"), ("z",), (("id", "x", "y"), ("id", "x", "y", "z")))
# cdro-hostd's heights: without a header id,z or id,x,y,z (a truth file).
HEIGHTS_FORMAT = Format(("id", "z"), (), (("id", "z"), ("id", "x", "y", "z")))


def read_estimates(path: str, bad: list[BadRow], unplaced: list[int] | None = None,
                   policy: Policy = Policy.LENIENT) -> dict[int, NodeEstimate]:
    """The engine's nodes CSV `id,x,y,var_x,cov_xy,var_y,converged` (m, m^2, 0/1).

    cdro-hostd writes a row with empty x, y and covariance for a node it has ranges of but has
    not placed (yet): that is an answer, not a damaged row, so its id goes to `unplaced` (when
    given) instead of `bad`."""
    out: dict[int, NodeEstimate] = {}
    seen: set[int] = set()

    def on_row(row: Row) -> None:
        node_id = row.node_id("id")
        if node_id in seen:
            row.reject(f"id {node_id} repeated (the first row is kept)")
        if unplaced is not None and all(row.text(c) == "" for c in ESTIMATE_COLUMNS[1:6]):
            seen.add(node_id)
            unplaced.append(node_id)
            return
        out[node_id] = _estimate_from_row(row)
        seen.add(node_id)

    read_rows(path, ESTIMATES_FORMAT, on_row, bad, policy)
    return out


def read_truth(path: str, bad: list[BadRow],
               policy: Policy = Policy.LENIENT) -> tuple[dict[int, np.ndarray], dict[int, float]]:
    """`id,x,y[,z]` (m): positions, and the heights of the rows that have a z."""
    xy: dict[int, np.ndarray] = {}
    z: dict[int, float] = {}

    def on_row(row: Row) -> None:
        node_id = row.node_id("id")
        if node_id in xy:
            row.reject(f"id {node_id} repeated (the first row is kept)")
        position = np.array([row.number("x"), row.number("y")])
        if row.has("z"):
            z[node_id] = row.number("z")
        xy[node_id] = position

    read_rows(path, TRUTH_FORMAT, on_row, bad, policy)
    return xy, z


def read_heights(path: str, bad: list[BadRow], policy: Policy = Policy.LENIENT) -> dict[int, float]:
    """`id,z` (m)."""
    out: dict[int, float] = {}

    def on_row(row: Row) -> None:
        node_id = row.node_id("id")
        if node_id in out:
            row.reject(f"id {node_id} repeated (the first row is kept)")
        out[node_id] = row.number("z")

    read_rows(path, HEIGHTS_FORMAT, on_row, bad, policy)
    return out


# ----------------------------------------------------------------------------- trace

TRACE_COLUMNS = ("ranges", *ESTIMATE_COLUMNS)
TRACE_FORMAT = Format(TRACE_COLUMNS)                    # written by cdro-hostd, always with its header


def read_count(row: Row, column: str) -> int:
    """A count: a number that is a non-negative integer."""
    value = row.number(column)
    if value < 0 or value != int(value):
        row.reject(f"{column} '{row.text(column)}' is not a count (a non-negative integer)")
    return int(value)


def read_trace(path: str, bad: list[BadRow]) -> list[tuple[int, dict[int, NodeEstimate]]]:
    """The engine's trace `ranges,id,x,y,var_x,cov_xy,var_y,converged`: after every K-th
    processed range, one row per placed node. Returns the snapshots sorted by `ranges`
    (count of ranges processed so far), each id -> estimate."""
    snapshots: dict[int, dict[int, NodeEstimate]] = {}

    def on_row(row: Row) -> None:
        count = read_count(row, "ranges")
        node_id = row.node_id("id")
        estimate = _estimate_from_row(row)
        snapshot = snapshots.setdefault(count, {})
        if node_id in snapshot:
            row.reject(f"id {node_id} repeated at ranges {count} (the first row is kept)")
        snapshot[node_id] = estimate

    read_rows(path, TRACE_FORMAT, on_row, bad)
    return sorted(snapshots.items())
