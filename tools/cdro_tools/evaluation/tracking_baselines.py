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
EKF state above it is mirrored (z, vz and their covariance rows), and the EKFs also keep the tags
above the floor and near the anchors (the room, (b)). On MiLUV without this rule, 412
of 947 fixes of the 1-robot run were on the mirror side.

(a) `trilaterate`: per tag, the latest range to each anchor that is at most `window_s` (2.0 s)
    old at the time of the tag's newest range to an anchor (an "epoch"). With >= 4 anchors, a 3D
    least-squares fix (scipy least_squares, analytic Jacobian, plain squared loss); with exactly
    3 and an earlier fix of the tag, a 2D fix of x, y with z held at that fix's z; with fewer, no
    fix (status `no_fix`). Each solve starts from the tag's previous fix. A row per fix, with the
    covariance sigma^2 (J^T J)^-1 (the held z keeps its previous variance; the motion during the
    window is not in it).
(b) `track_ekf(cooperative=False)`: per tag, a causal EKF (no smoothing: the rows are what the
    filter knew at their time), state (x, y, z, vx, vy, vz), every choice made on simulated
    flights (tests/tools/test_tracking.py, seeded), none on MiLUV's truth:
    - motion: each velocity component an Ornstein-Uhlenbeck process (Singer's model), stationary
      sigma `SPEED_SIGMA_M_S` (0.7 m/s per axis: the 3D speed is above 2 m/s with probability
      4 %, above 3 m/s with 0.05 %, a soft bound for drones indoors) and correlation time
      `SPEED_TAU_S` (2 s: they turn every few seconds), exact discretisation. Over a long gap
      the position becomes a random walk (2 sigma^2 tau m^2/s) instead of the constant-velocity
      model's dt^3 growth. `motion="cv"` is the constant-velocity model with white acceleration
      `PROCESS_Q_M2_S3` (q [[dt^3/3, dt^2/2], [dt^2/2, dt]] per axis).
    - start: at the tag's first range, from the room (below) as a prior: its centre, sigma half
      its size per axis, velocity 0 with sigma `SPEED_SIGMA_M_S`. The tag's rows start once it
      has heard `MIN_ANCHORS_3D` distinct anchors (what a 3D fix needs). `start="window"`
      instead starts from a trilateration fix over `INIT_WINDOW_S` (10 s; while the tag moves),
      covariance the fix's plus (0.5 m)^2, velocity sigma 1 m/s.
    - each range to an anchor is one scalar update (Joseph form) with sigma `RANGE_SIGMA_M`
      (0.1 m) plus the range's curvature under the state's spread (`curvature=True`; the
      Gaussian second-order filter's variance term, |P_perp|_F^2 / 2 d^2, P_perp the covariance
      of the relative position across the line of sight): a state metres off is not made
      confident by one range linearised at the wrong point. `iterations` > 1 is the iterated
      EKF (Gauss-Newton); it did no better on the simulated flights and is off.
    - gate: a range whose normalised innovation squared nu^2 / S is above `GATE_CHI2` (9, i.e.
      3 sigma) is down-weighted (`huber=True`, a Huber weight: S inflated by
      sqrt(nu^2 / S / 9), so the correction is at most 3 sigma of the innovation) and counted
      (status `rejected`); `huber=False` rejects it. UWB's errors have a long positive tail
      (NLOS); on the simulated flights with 5-20 % of the ranges NLOS the weight did as well as
      or better than the reject (0.49 m against 0.65 m at 2.3 ranges a second, 5 % NLOS), and the
      same on clean ranges. After `RESET_AFTER_REJECTS` (4) such ranges of a tag's anchor
      ranges in a row, the tag's covariance is the starting one again (state kept, correlations
      with other tags dropped; counted in notes['resets_by_tag']) and the range is used in full:
      a filter that is off cannot be locked out by its own gate.
    - room: the tags are in a box the installer knows, `Room.around(anchors)`: the anchors'
      horizontal bounding box grown by `ROOM_MARGIN_M` (1 m), from the floor `FLOOR_Z_M`
      (z = 0: heights above the floor) up to the anchors' mean height (the rule above, now
      with a floor). After each update the tag's Gaussian is truncated to it, one axis at a
      time: the truncated mean and variance of that coordinate, and the rest of the state
      moved with it through the covariance (notes['truncated_by_tag'] counts updates that
      changed something); a state above the anchors is first mirrored, as above.
    A row after each of the tag's ranges (used or rejected) once it reports.
(c-ref) `track_ekf(cooperative=True)`: the same filter over all tags jointly (one state of
    6 x tags, cross-covariances kept) that also takes the tag-to-tag ranges, gated and
    curvature-weighted the same way (the relative position of two tags is what both ends'
    spread and their correlation make it); a tag-to-tag range with an end not started yet is
    skipped (status `waiting`). Tags start exactly as in (b), so the only difference from (b)
    is the tag-to-tag ranges: without them the joint filter's blocks stay uncorrelated and it
    is (b) (tested). A reference for what cooperation can buy; rows for both ends after a
    tag-to-tag range.

Statuses: `init` (`start="window"`: a range of a tag not started yet, used for its first fix),
`used`, `rejected` (beyond the gate: down-weighted or rejected), `waiting`, `ignored` (a tag-to-tag
range in (a)/(b), an anchor-to-anchor range), and for (a) `fix`, `fix_fixed_z`, `no_fix`, `failed`
(the solve did not give a usable covariance).
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import truncnorm

from .inputs import (
    BadRow,
    Format,
    InputError,
    Row,
    read_rows,
    read_truth,
)

RANGE_SIGMA_M = 0.10            # DW1000 line of sight; MiLUV's own MAD-sigma is 0.105 m
WINDOW_S = 2.0                  # (a): the oldest range a fix may use
MIN_ANCHORS_3D = 4
START_BELOW_ANCHORS_M = 1.0     # (a): the first solve starts this far below the anchors' centroid
INIT_WINDOW_S = 10.0            # (b), (c-ref) with start="window": the window of the starting fix
INIT_MOTION_SIGMA_M = 0.5       # start="window": added to the starting fix's position sigma, per axis
INIT_SPEED_SIGMA_M_S = 1.0      # start="window" with motion="cv": the starting velocity's sigma
PROCESS_Q_M2_S3 = 1.0           # motion="cv": white-acceleration spectral density, per axis
GATE_CHI2 = 9.0                 # nu^2 / S above this is down-weighted (Huber) or rejected (3 sigma)
HUBER = True                    # down-weight beyond the gate (False: reject)
MOTION = "ou"                   # velocity an Ornstein-Uhlenbeck process ("cv": constant velocity)
SPEED_SIGMA_M_S = 0.7           # its stationary sigma per axis: 3D speed > 2 m/s with p 4 %, > 3 m/s with p 0.05 %
SPEED_TAU_S = 2.0               # its correlation time
START = "prior"                 # from the room as a prior ("window": from a trilateration fix)
RESET_AFTER_REJECTS = 4         # rejects in a row of a tag's anchor ranges that reset its covariance
ROOM_MARGIN_M = 1.0             # the room: the anchors' horizontal bounding box grown by this
FLOOR_Z_M = 0.0                 # the room's floor (heights above the floor)
TRUNCATION_SIGMAS = 6.0         # a room bound farther than this from the mean is not applied
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


# cdro-hostd's ranges with their t required (its --motion-csv needs one too): without a header, 4 fields.
TIMED_RANGES_FORMAT = Format(("t", "from", "to", "range_m"), (), (("t", "from", "to", "range_m"),))


def read_timed_ranges(path: str, bad: list[BadRow]) -> TimedRanges:
    """`t,from,to,range_m`; bad rows (evaluation.inputs rules) are counted and skipped."""
    rows = []

    def on_row(row: Row) -> None:
        t_s, a, b, r = row.number("t"), row.node_id("from"), row.node_id("to"), row.number("range_m")
        if a == b:
            row.reject(f"node {a} ranging itself")
        if r < 0:
            row.reject(f"negative range {r:g} m")
        rows.append((t_s, a, b, r, row.line))

    read_rows(path, TIMED_RANGES_FORMAT, on_row, bad)
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
    """F and Q of one tag's constant-velocity block over dt_s (white acceleration, spectral
    density q per axis)."""
    f = np.eye(6)
    f[:3, 3:] = dt_s * np.eye(3)
    qq = np.zeros((6, 6))
    qq[:3, :3] = q * dt_s ** 3 / 3.0 * np.eye(3)
    qq[:3, 3:] = qq[3:, :3] = q * dt_s ** 2 / 2.0 * np.eye(3)
    qq[3:, 3:] = q * dt_s * np.eye(3)
    return f, qq


def _transition_ou(dt_s: float, speed_sigma_m_s: float, tau_s: float) -> tuple[np.ndarray, np.ndarray]:
    """F and Q of one tag's block over dt_s when each velocity component is an Ornstein-Uhlenbeck
    process (mean 0, stationary sigma speed_sigma_m_s, correlation time tau_s) and the position its
    integral (Singer's model on the velocity; exact discretisation). Small dt: the constant-velocity
    model with q = 2 sigma^2 / tau; long dt: a position random walk of 2 sigma^2 tau m^2/s."""
    x = dt_s / tau_s
    e = np.exp(-x)
    s2 = speed_sigma_m_s ** 2
    f = np.eye(6)
    f[:3, 3:] = tau_s * (1.0 - e) * np.eye(3)
    f[3:, 3:] = e * np.eye(3)
    qq = np.zeros((6, 6))
    # x - 2 (1 - e) + (1 - e^2) / 2, by its series where its terms cancel
    walk = x - 2.0 * (1.0 - e) + 0.5 * (1.0 - e * e) if x > 1e-2 else x ** 3 / 3.0 - x ** 4 / 4.0 + 7.0 * x ** 5 / 60.0
    qq[:3, :3] = 2.0 * s2 * tau_s ** 2 * walk * np.eye(3)
    qq[:3, 3:] = qq[3:, :3] = s2 * tau_s * (1.0 - e) ** 2 * np.eye(3)
    qq[3:, 3:] = s2 * (1.0 - e * e) * np.eye(3)
    return f, qq


@dataclasses.dataclass
class Room:
    """The box the tags are known to be in (m): lo_m (3,), hi_m (3,)."""
    lo_m: np.ndarray
    hi_m: np.ndarray

    @staticmethod
    def around(anchors: dict[int, np.ndarray], margin_m: float = ROOM_MARGIN_M, floor_z_m: float = FLOOR_Z_M) -> Room:
        """x, y: the anchors' bounding box grown by margin_m; z: from the floor to the anchors'
        mean height (the "below the anchors" rule)."""
        positions = np.array(list(anchors.values()))
        lo = np.array([*(positions[:, :2].min(axis=0) - margin_m), floor_z_m])
        hi = np.array([*(positions[:, :2].max(axis=0) + margin_m), positions[:, 2].mean()])
        return Room(lo, hi)

    def prior(self) -> tuple[np.ndarray, np.ndarray]:
        """The starting position (the box's centre) and its per-axis sigma (half the box)."""
        return 0.5 * (self.lo_m + self.hi_m), 0.5 * (self.hi_m - self.lo_m)


def track_ekf(ranges: TimedRanges, anchors: dict[int, np.ndarray], cooperative: bool = False,
              sigma_m: float = RANGE_SIGMA_M, gate_chi2: float = GATE_CHI2, huber: bool = HUBER,
              motion: str = MOTION, speed_sigma_m_s: float = SPEED_SIGMA_M_S, tau_s: float = SPEED_TAU_S,
              q_m2_s3: float = PROCESS_Q_M2_S3, start: str = START, init_window_s: float = INIT_WINDOW_S,
              curvature: bool = True, iterations: int = 1, reset_after: int = RESET_AFTER_REJECTS,
              room: Room | None | bool = True, below_anchors: bool = True,
              report_after: int = MIN_ANCHORS_3D) -> TrackingResult:
    """(b) per tag (cooperative=False) or (c-ref) over all tags with the tag-to-tag ranges
    (cooperative=True), module docstring. One joint state either way: without tag-to-tag
    updates nothing couples the tags' blocks, so the per-tag filters are exactly separate.
    room: True for Room.around(anchors), a Room, or False/None for none."""
    if motion not in ("ou", "cv"):
        raise ValueError(f"motion {motion!r}: 'ou' or 'cv'")
    if start not in ("prior", "window"):
        raise ValueError(f"start {start!r}: 'prior' or 'window'")
    if room is True:
        room = Room.around(anchors)
    room = room or None
    tags = sorted({i for i in ranges.from_ids.tolist() + ranges.to_ids.tolist() if i not in anchors})
    index = {tag: k for k, tag in enumerate(tags)}
    x = np.zeros(6 * len(tags))
    p = np.zeros((6 * len(tags), 6 * len(tags)))
    started: set[int] = set()
    fixers = {tag: _WindowFixer(anchors, init_window_s, sigma_m, False, below_anchors) for tag in tags}
    t_filter = None
    rows, status = [], []
    rejected = {tag: 0 for tag in tags}
    in_a_row = {tag: 0 for tag in tags}
    resets = {tag: 0 for tag in tags}
    mirrored = {tag: 0 for tag in tags}
    truncated = {tag: 0 for tag in tags}
    heard: dict[int, set[int]] = {tag: set() for tag in tags}
    plane_z_m = float(np.mean([position[2] for position in anchors.values()]))
    speed_var = speed_sigma_m_s ** 2 if motion == "ou" else INIT_SPEED_SIGMA_M_S ** 2
    if room is not None:
        prior_p, prior_sigma = room.prior()
    else:       # the anchors' centroid 1 m below them, sigma half their extent (1 m in z)
        positions = np.array(list(anchors.values()))
        prior_p = positions.mean(axis=0) - [0.0, 0.0, START_BELOW_ANCHORS_M]
        prior_sigma = np.array([*(np.ptp(positions[:, :2], axis=0) / 2.0), START_BELOW_ANCHORS_M])

    def block(tag: int) -> slice:
        return slice(6 * index[tag], 6 * index[tag] + 6)

    def predict(t_s: float) -> None:
        nonlocal t_filter
        if t_filter is not None and t_s > t_filter:
            dt = t_s - t_filter
            f, qq = _transition(dt, q_m2_s3) if motion == "cv" else _transition_ou(dt, speed_sigma_m_s, tau_s)
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

    def curvature_var(h: np.ndarray, a: int, b: int, distance: float) -> float:
        """The range's variance from its curvature under the state's spread (the Gaussian
        second-order filter's term): 1/2 tr((H_xx P)^2) = |P_perp|_F^2 / 2 d^2, where P_perp is
        the covariance of position a - position b across the line of sight."""
        ends = [(n, sign) for n, sign in ((a, 1.0), (b, -1.0)) if n in index]
        rel = np.zeros((3, 3))
        for n, sn in ends:
            for m, sm in ends:
                rel += sn * sm * p[block(n).start:block(n).start + 3, block(m).start:block(m).start + 3]
        unit = h[block(ends[0][0]).start:block(ends[0][0]).start + 3]     # +-(a - b) / d
        perp = np.eye(3) - np.outer(unit, unit)
        pp = perp @ rel @ perp
        return float(np.sum(pp * pp)) / (2.0 * distance ** 2)

    def update(a: int, b: int, range_m: float, force: bool = False) -> bool:
        """One range, gated on the innovation at the prediction (force: not gated); with
        iterations > 1 the iterated EKF (Gauss-Newton on the prior and the range) linearises at
        the updated state. True when the gate passed it."""
        h, predicted = measure(x, a, b)
        r_eff = sigma_m ** 2 + (curvature_var(h, a, b, predicted) if curvature else 0.0)
        s = float(h @ p @ h) + r_eff
        nis = (range_m - predicted) ** 2 / s
        if nis > gate_chi2 and not force:
            if not huber:
                return False
            r_eff = s * np.sqrt(nis / gate_chi2) - (s - r_eff)
        x0 = x.copy()
        xi = x0
        for step in range(max(1, iterations)):
            k = p @ h / (float(h @ p @ h) + r_eff)
            x_next = x0 + k * (range_m - predicted - h @ (x0 - xi))
            done = step >= iterations - 1 or float(np.max(np.abs(x_next - xi))) < 1e-6
            xi = x_next
            if done:
                break
            h, predicted = measure(xi, a, b)
        x[:] = xi
        i_kh = np.eye(len(x)) - np.outer(k, h)
        p[:] = i_kh @ p @ i_kh.T + r_eff * np.outer(k, k)
        return nis <= gate_chi2

    def start_tag(tag: int, position: np.ndarray, cov: np.ndarray) -> None:
        s = block(tag)
        x[s] = np.concatenate([position, np.zeros(3)])
        p[s, :] = 0.0
        p[:, s] = 0.0
        p[s, s] = np.diag([0, 0, 0] + [speed_var] * 3)
        p[s.start:s.start + 3, s.start:s.start + 3] = cov

    def keep_inside(tag: int) -> None:
        """Below the anchors (mirrored through their mean height), then the room: per axis, the
        state's Gaussian truncated to the box, its mean and variance matched, and the other
        components moved with it through their covariance (an exact update for one bound)."""
        b = block(tag)
        if below_anchors and x[b.start + 2] > plane_z_m:
            flip = np.ones(len(x))
            flip[b.start + 2] = flip[b.start + 5] = -1.0
            x[b.start + 2] = 2.0 * plane_z_m - x[b.start + 2]
            x[b.start + 5] = -x[b.start + 5]
            p[:] = flip[:, None] * p * flip[None, :]
            mirrored[tag] += 1
        if room is None:
            return
        touched = False
        for axis in range(3):
            i = b.start + axis
            var = float(p[i, i])
            if var <= 0.0:
                continue
            sigma = np.sqrt(var)
            lo, hi = (room.lo_m[axis] - x[i]) / sigma, (room.hi_m[axis] - x[i]) / sigma
            if lo < -TRUNCATION_SIGMAS and hi > TRUNCATION_SIGMAS:
                continue
            mean_t, var_t = (float(v) for v in truncnorm.stats(lo, hi, loc=x[i], scale=sigma, moments="mv"))
            column = p[:, i].copy()
            x[:] = x + column * (mean_t - x[i]) / var
            p[:] = p - np.outer(column, column) * (var - var_t) / var ** 2
            touched = True
        truncated[tag] += touched

    def reporting(tag: int) -> bool:
        """A tag's rows start once it has heard report_after distinct anchors (what a 3D fix
        needs); its filter runs from its first range."""
        return start == "window" or len(heard[tag]) >= report_after

    def row(t_s: float, tag: int) -> tuple[float, int, np.ndarray, np.ndarray]:
        b = block(tag)
        return t_s, tag, x[b][:3].copy(), p[b, b][:3, :3].copy()

    def anchor_range(tag: int, anchor: int, range_m: float) -> bool:
        """An update with a range to an anchor; after reset_after rejects in a row, the tag's
        covariance is the starting one again (its state kept, its correlations with the other
        tags dropped) and the range is used."""
        used = update(tag, anchor, range_m)
        if used:
            in_a_row[tag] = 0
        else:
            rejected[tag] += 1
            in_a_row[tag] += 1
            if reset_after and in_a_row[tag] >= reset_after:
                start_tag(tag, x[block(tag)][:3].copy(), np.diag(prior_sigma ** 2))
                resets[tag] += 1
                in_a_row[tag] = 0
                update(tag, anchor, range_m, force=True)
        keep_inside(tag)
        return used

    for t, a, b, r in zip(ranges.t_s.tolist(), ranges.from_ids.tolist(), ranges.to_ids.tolist(),
                          ranges.range_m.tolist()):
        kind = _kind(a, b, anchors)
        if kind == "anchor":
            tag, anchor = (b, a) if a in anchors else (a, b)
            if tag not in started:
                if start == "prior":
                    predict(t)
                    start_tag(tag, prior_p.copy(), np.diag(prior_sigma ** 2))
                    started.add(tag)
                else:
                    what, fix, cov = fixers[tag].add(t, anchor, r)
                    status.append("init")
                    if what == "fix":
                        predict(t)
                        start_tag(tag, fix, cov + INIT_MOTION_SIGMA_M ** 2 * np.eye(3))
                        started.add(tag)
                        keep_inside(tag)
                        rows.append(row(t, tag))
                    continue
            predict(t)
            used = anchor_range(tag, anchor, r)
            status.append("used" if used else "rejected")
            heard[tag].add(anchor)
            if reporting(tag):
                rows.append(row(t, tag))
        elif kind == "tag-tag" and cooperative:
            if a not in started or b not in started:
                status.append("waiting")
                continue
            predict(t)
            used = update(a, b, r)
            keep_inside(a)
            keep_inside(b)
            status.append("used" if used else "rejected")
            rejected[a] += not used
            rejected[b] += not used
            rows.extend(row(t, n) for n in (a, b) if reporting(n))
        else:
            status.append("ignored")
    notes = {"sigma_m": sigma_m, "gate_chi2": gate_chi2, "huber": huber, "motion": motion,
             "speed_sigma_m_s": speed_sigma_m_s, "tau_s": tau_s, "q_m2_s3": q_m2_s3, "start": start,
             "init_window_s": init_window_s, "curvature": curvature, "iterations": iterations,
             "reset_after": reset_after,
             "room": None if room is None else {"lo_m": room.lo_m.tolist(), "hi_m": room.hi_m.tolist()},
             "rejected_by_tag": rejected, "resets_by_tag": resets, "mirrored_by_tag": mirrored,
             "truncated_by_tag": truncated, "never_started": [tag for tag in tags if tag not in started]}
    return TrackingResult("coop-ekf" if cooperative else "ekf", rows, status, notes)


def run_all(ranges: TimedRanges, anchors: dict[int, np.ndarray]) -> dict[str, TrackingResult]:
    """(a), (b) and (c-ref) with their defaults, by name (NAMES)."""
    return {"trilateration": trilaterate(ranges, anchors), "ekf": track_ekf(ranges, anchors),
            "coop-ekf": track_ekf(ranges, anchors, cooperative=True)}
