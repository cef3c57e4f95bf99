"""Tracking baselines: what a plain RTLS would run on the same ranges, for comparison with the
engine's 3D tracker of moving nodes (scripts/miluv.py; docs/results.md, "Moving nodes on real
data: MiLUV").

Inputs: ranges `t,from,to,range_m` (s, m; processed in time order, equal times in file order) and
the anchors `id,x,y,z` at surveyed positions (m). Every node that is not an anchor is a tag.
Everything is 3D and deterministic (no random numbers). Each baseline gives rows
(t_s, id, p_m, cov_m2) for evaluation.tracking.write_trajectory, and a status for every input
range (how it was used), so that a caller can count, e.g., the gate's rejects per anchor.

Below the anchors: anchors on walls and ceiling are often nearly coplanar (MiLUV's heights are
1.59-1.90 m), and then the mirror image of a tag through their plane fits its ranges (almost) as
well as the tag. An installer knows that the tags move below the anchors, so every baseline keeps
them there (`below_anchors=True`, counted in notes['mirrored_by_tag']): the first solve starts
`START_BELOW_ANCHORS_M` (1 m) below the anchors' centroid; a fix above the anchors' mean height is
solved again from its mirror image through that height and replaced when that lands below; an
EKF state above it is mirrored (z, vz and their covariance rows). On MiLUV without this rule, 412
of 947 fixes of the 1-robot run were on the mirror side.

(a) `trilaterate`: per tag, the latest range to each anchor that is at most `window_s` (2.0 s)
    old at the time of the tag's newest range to an anchor (an "epoch"). With >= 4 anchors, a 3D
    least-squares fix (scipy least_squares, analytic Jacobian, plain squared loss); with exactly
    3 and an earlier fix of the tag, a 2D fix of x, y with z held at that fix's z; with fewer, no
    fix (status `no_fix`). Each solve starts from the tag's previous fix. A row per fix, with the
    covariance sigma^2 (J^T J)^-1 (the held z keeps its previous variance; the motion during the
    window is not in it).
(b) `track_ekf(cooperative=False)`: per tag, an EKF on a constant-velocity model, state
    (x, y, z, vx, vy, vz), white-acceleration process noise of spectral density
    `PROCESS_Q_M2_S3` (1 m^2/s^3 per axis: Q = q [[dt^3/3, dt^2/2], [dt^2/2, dt]] per axis).
    Started from the tag's first 3D trilateration fix over `INIT_WINDOW_S` (10 s: at MiLUV's
    3-robot rate, ~0.4 ranges a second per tag, a 2 s window seldom holds four anchors), with
    velocity 0, covariance the fix's plus (0.5 m)^2 (the tag moved during the window) and
    (1 m/s)^2 on the velocity. Then each range to an anchor is one scalar update (Joseph form)
    with sigma `RANGE_SIGMA_M` (0.1 m), gated: a normalised innovation squared nu^2 / S above
    `GATE_CHI2` (9, i.e. 3 sigma) is rejected and counted (status `rejected`). With
    `huber=True` such a range is down-weighted instead (S inflated by sqrt(nu^2 / S / 9), so the
    correction is at most 3 sigma of the innovation; still status `rejected`): a hard gate can
    lock a filter out once it is off, a Huber weight cannot. A row after each of the tag's ranges
    (used or rejected) and one at its start.
(c-ref) `track_ekf(cooperative=True)`: the same filter over all tags jointly (one state of
    6 x tags, cross-covariances kept) that also takes the tag-to-tag ranges, gated the same way;
    a tag-to-tag range with an end not started yet is skipped (status `waiting`). Tags start
    exactly as in (b), so the only difference from (b) is the tag-to-tag ranges: without them
    the joint filter's blocks stay uncorrelated and it is (b) (tested). A reference for what
    cooperation can buy; rows for both ends after a tag-to-tag range.

Statuses: `init` (a range of a tag not started yet, used for its first fix), `used`, `rejected`,
`waiting`, `ignored` (a tag-to-tag range in (a)/(b), an anchor-to-anchor range), and for (a) `fix`,
`fix_fixed_z`, `no_fix`, `failed` (the solve did not give a usable covariance).
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.optimize import least_squares

from .inputs import (
    BadRow,
    InputError,
    RowError,
    csv_rows,
    parse_id,
    parse_number,
    read_truth,
)

RANGE_SIGMA_M = 0.10            # DW1000 line of sight; MiLUV's own MAD-sigma is 0.105 m
WINDOW_S = 2.0                  # (a): the oldest range a fix may use
MIN_ANCHORS_3D = 4
START_BELOW_ANCHORS_M = 1.0     # (a): the first solve starts this far below the anchors' centroid
INIT_WINDOW_S = 10.0            # (b), (c-ref): the window of the fix a tag's filter starts from
INIT_MOTION_SIGMA_M = 0.5       # added to the starting fix's position sigma, per axis
INIT_SPEED_SIGMA_M_S = 1.0
PROCESS_Q_M2_S3 = 1.0           # white-acceleration spectral density, per axis
GATE_CHI2 = 9.0                 # nu^2 / S above this is rejected (3 sigma)
NAMES = ("trilateration", "ekf", "coop-ekf")


@dataclasses.dataclass
class TimedRanges:
    """Ranges sorted by time (stable), with their file lines."""
    t_s: np.ndarray
    from_ids: np.ndarray
    to_ids: np.ndarray
    range_m: np.ndarray
    lines: np.ndarray

    def __len__(self) -> int:
        return len(self.t_s)


def read_timed_ranges(path: str, bad: list[BadRow]) -> TimedRanges:
    """`t,from,to,range_m`; bad rows (evaluation.inputs rules) are counted and skipped."""
    rows = []
    for line, row in csv_rows(path, ["t", "from", "to", "range_m"]):
        try:
            t_s = parse_number(row["t"], "t")
            a, b = parse_id(row["from"]), parse_id(row["to"])
            r = parse_number(row["range_m"], "range_m")
            if a == b:
                raise RowError(f"node {a} ranging itself")
            if r < 0:
                raise RowError(f"negative range {r:g} m")
        except RowError as error:
            bad.append(BadRow(path, line, str(error)))
            continue
        rows.append((t_s, a, b, r, line))
    rows.sort(key=lambda row: row[0])
    return TimedRanges(np.array([r[0] for r in rows], dtype=float), np.array([r[1] for r in rows], dtype=np.int64),
                       np.array([r[2] for r in rows], dtype=np.int64), np.array([r[3] for r in rows], dtype=float),
                       np.array([r[4] for r in rows], dtype=np.int64))


def read_anchors(path: str, bad: list[BadRow]) -> dict[int, np.ndarray]:
    """`id,x,y,z` (m): the anchors' 3D positions. InputError without a z for every anchor."""
    xy, z = read_truth(path, bad)
    missing = sorted(i for i in xy if i not in z)
    if missing:
        raise InputError(f"{path}: anchors need a z column (missing for {missing})")
    return {i: np.array([*xy[i], z[i]]) for i in xy}


@dataclasses.dataclass
class TrackingResult:
    name: str
    rows: list[tuple[float, int, np.ndarray, np.ndarray | None]]    # (t_s, id, p_m, cov_m2)
    status: list[str]                                               # one per input range
    notes: dict = dataclasses.field(default_factory=dict)

    def counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for s in self.status:
            out[s] = out.get(s, 0) + 1
        return out


def solve_fix(anchors_m: np.ndarray, ranges_m: np.ndarray, start_m: np.ndarray, sigma_m: float = RANGE_SIGMA_M,
              fixed_z_m: float | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """Least-squares position from ranges to anchors ((k, 3), (k,)), from start_m (3,); with
    fixed_z_m, only x, y are solved. Returns (p_m (3,), covariance of the solved coordinates
    (3x3 or 2x2)), or None when the covariance is singular."""
    free = 3 if fixed_z_m is None else 2

    def point(q: np.ndarray) -> np.ndarray:
        return q if free == 3 else np.array([q[0], q[1], fixed_z_m])

    def residuals(q: np.ndarray) -> np.ndarray:
        return np.linalg.norm(point(q) - anchors_m, axis=1) - ranges_m

    def jacobian(q: np.ndarray) -> np.ndarray:
        d = point(q) - anchors_m
        n = np.maximum(np.linalg.norm(d, axis=1), 1e-9)
        return (d / n[:, None])[:, :free]

    solution = least_squares(residuals, np.asarray(start_m, dtype=float)[:free], jac=jacobian, method="trf")
    j = jacobian(solution.x)
    try:
        cov = sigma_m ** 2 * np.linalg.inv(j.T @ j)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(cov)) or np.linalg.cond(j.T @ j) > 1e12:
        return None
    return point(solution.x), cov


def _kind(a: int, b: int, anchors: dict[int, np.ndarray]) -> str:
    return "anchor" if (a in anchors) != (b in anchors) else ("tag-tag" if a not in anchors else "anchor-anchor")


class _WindowFixer:
    """(a)'s per-tag bookkeeping: the latest range to each anchor, and the fixes."""

    def __init__(self, anchors: dict[int, np.ndarray], window_s: float, sigma_m: float, allow_fixed_z: bool,
                 below_anchors: bool):
        self.anchors, self.window_s, self.sigma_m, self.allow_fixed_z = anchors, window_s, sigma_m, allow_fixed_z
        self.below_anchors = below_anchors
        self.latest: dict[int, tuple[float, float]] = {}
        self.previous: tuple[np.ndarray, np.ndarray] | None = None
        centroid = np.mean(list(anchors.values()), axis=0)
        self.plane_z_m = float(centroid[2])
        self.first_start_m = centroid - [0.0, 0.0, START_BELOW_ANCHORS_M]
        self.mirrored = 0

    def add(self, t_s: float, anchor: int, range_m: float) -> tuple[str, np.ndarray | None, np.ndarray | None]:
        """Take a range; (status, p_m, 3x3 covariance) of the fix it makes, if any."""
        self.latest[anchor] = (t_s, range_m)
        ids = sorted(a for a, (t, _) in self.latest.items() if t_s - t <= self.window_s)
        positions = np.array([self.anchors[a] for a in ids]).reshape(-1, 3)
        ranges = np.array([self.latest[a][1] for a in ids])
        start = self.first_start_m if self.previous is None else self.previous[0]
        if len(ids) >= MIN_ANCHORS_3D:
            solved = solve_fix(positions, ranges, start, self.sigma_m)
            if solved is not None and self.below_anchors and solved[0][2] > self.plane_z_m:
                mirrored = solved[0] * [1.0, 1.0, -1.0] + [0.0, 0.0, 2.0 * self.plane_z_m]
                again = solve_fix(positions, ranges, mirrored, self.sigma_m)
                if again is not None and again[0][2] <= self.plane_z_m:
                    solved = again
                    self.mirrored += 1
            if solved is None:
                return "failed", None, None
            self.previous = solved
            return "fix", *solved
        if len(ids) == MIN_ANCHORS_3D - 1 and self.allow_fixed_z and self.previous is not None:
            solved = solve_fix(positions, ranges, start, self.sigma_m, fixed_z_m=float(self.previous[0][2]))
            if solved is None:
                return "failed", None, None
            cov = np.zeros((3, 3))
            cov[:2, :2] = solved[1]
            cov[2, 2] = self.previous[1][2, 2]
            self.previous = (solved[0], cov)
            return "fix_fixed_z", solved[0], cov
        return "no_fix", None, None


def trilaterate(ranges: TimedRanges, anchors: dict[int, np.ndarray], window_s: float = WINDOW_S,
                sigma_m: float = RANGE_SIGMA_M, below_anchors: bool = True) -> TrackingResult:
    """(a), module docstring."""
    fixers: dict[int, _WindowFixer] = {}
    rows, status = [], []
    for t, a, b, r in zip(ranges.t_s.tolist(), ranges.from_ids.tolist(), ranges.to_ids.tolist(),
                          ranges.range_m.tolist()):
        if _kind(a, b, anchors) != "anchor":
            status.append("ignored")
            continue
        tag, anchor = (b, a) if a in anchors else (a, b)
        fixer = fixers.setdefault(tag, _WindowFixer(anchors, window_s, sigma_m, True, below_anchors))
        what, p, cov = fixer.add(t, anchor, r)
        status.append(what)
        if p is not None:
            rows.append((t, tag, p, cov))
    return TrackingResult("trilateration", rows, status, {
        "window_s": window_s, "sigma_m": sigma_m, "mirrored_by_tag": {tag: f.mirrored for tag, f in fixers.items()}})


def _transition(dt_s: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    """F and Q of one tag's constant-velocity block over dt_s."""
    f = np.eye(6)
    f[:3, 3:] = dt_s * np.eye(3)
    qq = np.zeros((6, 6))
    qq[:3, :3] = q * dt_s ** 3 / 3.0 * np.eye(3)
    qq[:3, 3:] = qq[3:, :3] = q * dt_s ** 2 / 2.0 * np.eye(3)
    qq[3:, 3:] = q * dt_s * np.eye(3)
    return f, qq


def track_ekf(ranges: TimedRanges, anchors: dict[int, np.ndarray], cooperative: bool = False,
              sigma_m: float = RANGE_SIGMA_M, q_m2_s3: float = PROCESS_Q_M2_S3, gate_chi2: float = GATE_CHI2,
              init_window_s: float = INIT_WINDOW_S, below_anchors: bool = True,
              huber: bool = False) -> TrackingResult:
    """(b) per tag (cooperative=False) or (c-ref) over all tags with the tag-to-tag ranges
    (cooperative=True), module docstring. One joint state either way: without tag-to-tag
    updates nothing couples the tags' blocks, so the per-tag filters are exactly separate."""
    tags = sorted({i for i in ranges.from_ids.tolist() + ranges.to_ids.tolist() if i not in anchors})
    index = {tag: k for k, tag in enumerate(tags)}
    x = np.zeros(6 * len(tags))
    p = np.zeros((6 * len(tags), 6 * len(tags)))
    started: set[int] = set()
    fixers = {tag: _WindowFixer(anchors, init_window_s, sigma_m, False, below_anchors) for tag in tags}
    t_filter = None
    rows, status = [], []
    rejected = {tag: 0 for tag in tags}
    mirrored = {tag: 0 for tag in tags}
    plane_z_m = float(np.mean([position[2] for position in anchors.values()]))

    def block(tag: int) -> slice:
        return slice(6 * index[tag], 6 * index[tag] + 6)

    def predict(t_s: float) -> None:
        nonlocal t_filter
        if t_filter is not None and t_s > t_filter:
            f, qq = _transition(t_s - t_filter, q_m2_s3)
            big_f = np.eye(len(x))
            big_q = np.zeros_like(p)
            for tag in started:
                big_f[block(tag), block(tag)] = f
                big_q[block(tag), block(tag)] = qq
            x[:] = big_f @ x
            p[:] = big_f @ p @ big_f.T + big_q
        t_filter = t_s if t_filter is None else max(t_filter, t_s)

    def measure(state: np.ndarray, a: int, b: int) -> tuple[np.ndarray, float]:
        """The Jacobian row and the predicted range a-b (an end is an anchor or a started tag)."""
        ends = [(state[block(n)][:3], block(n)) if n in index else (anchors[n], None) for n in (a, b)]
        d = ends[0][0] - ends[1][0]
        distance = max(float(np.linalg.norm(d)), 1e-9)
        h = np.zeros(len(state))
        for (_, where), sign in zip(ends, (1.0, -1.0)):
            if where is not None:
                h[where.start:where.start + 3] = sign * d / distance
        return h, distance

    def update(a: int, b: int, range_m: float) -> bool:
        h, predicted = measure(x, a, b)
        s = float(h @ p @ h) + sigma_m ** 2
        nis = (range_m - predicted) ** 2 / s
        r_eff = sigma_m ** 2
        if nis > gate_chi2:
            if not huber:
                return False
            s_eff = s * np.sqrt(nis / gate_chi2)
            r_eff = s_eff - (s - sigma_m ** 2)
            s = s_eff
        k = p @ h / s
        x[:] = x + k * (range_m - predicted)
        i_kh = np.eye(len(x)) - np.outer(k, h)
        p[:] = i_kh @ p @ i_kh.T + r_eff * np.outer(k, k)
        return nis <= gate_chi2

    def keep_below(tag: int) -> None:
        b = block(tag)
        if not below_anchors or x[b.start + 2] <= plane_z_m:
            return
        flip = np.ones(len(x))
        flip[b.start + 2] = flip[b.start + 5] = -1.0
        x[b.start + 2] = 2.0 * plane_z_m - x[b.start + 2]
        x[b.start + 5] = -x[b.start + 5]
        p[:] = flip[:, None] * p * flip[None, :]
        mirrored[tag] += 1

    def row(t_s: float, tag: int) -> tuple[float, int, np.ndarray, np.ndarray]:
        b = block(tag)
        return t_s, tag, x[b][:3].copy(), p[b, b][:3, :3].copy()

    for t, a, b, r in zip(ranges.t_s.tolist(), ranges.from_ids.tolist(), ranges.to_ids.tolist(),
                          ranges.range_m.tolist()):
        kind = _kind(a, b, anchors)
        if kind == "anchor":
            tag, anchor = (b, a) if a in anchors else (a, b)
            if tag not in started:
                what, fix, cov = fixers[tag].add(t, anchor, r)
                status.append("init")
                if what == "fix":
                    predict(t)
                    s = block(tag)
                    x[s] = np.concatenate([fix, np.zeros(3)])
                    p[s, :] = 0.0
                    p[:, s] = 0.0
                    p[s, s] = np.diag([0, 0, 0] + [INIT_SPEED_SIGMA_M_S ** 2] * 3)
                    p[s.start:s.start + 3, s.start:s.start + 3] = cov + INIT_MOTION_SIGMA_M ** 2 * np.eye(3)
                    started.add(tag)
                    keep_below(tag)
                    rows.append(row(t, tag))
                continue
            predict(t)
            used = update(tag, anchor, r)
            keep_below(tag)
            status.append("used" if used else "rejected")
            rejected[tag] += not used
            rows.append(row(t, tag))
        elif kind == "tag-tag" and cooperative:
            if a not in started or b not in started:
                status.append("waiting")
                continue
            predict(t)
            used = update(a, b, r)
            keep_below(a)
            keep_below(b)
            status.append("used" if used else "rejected")
            rejected[a] += not used
            rejected[b] += not used
            rows.extend([row(t, a), row(t, b)])
        else:
            status.append("ignored")
    notes = {"sigma_m": sigma_m, "q_m2_s3": q_m2_s3, "gate_chi2": gate_chi2, "init_window_s": init_window_s,
             "rejected_by_tag": rejected, "mirrored_by_tag": mirrored,
             "never_started": [tag for tag in tags if tag not in started]}
    return TrackingResult("coop-ekf" if cooperative else "ekf", rows, status, notes)


def run_all(ranges: TimedRanges, anchors: dict[int, np.ndarray]) -> dict[str, TrackingResult]:
    """(a), (b) and (c-ref) with their defaults, by name (NAMES)."""
    return {"trilateration": trilaterate(ranges, anchors), "ekf": track_ekf(ranges, anchors),
            "coop-ekf": track_ekf(ranges, anchors, cooperative=True)}
