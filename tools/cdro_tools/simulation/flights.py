"""Seeded flights of UWB tags among fixed anchors: the truth (where every tag is at any time), the
schedule (which pair ranges when) and the ranges measured from the truth. The tracking baselines'
tests (tests/tools/test_tracking.py) and the engine's comparison with them
(scripts/flights_sim.py) run on these flights; `score_rows` scores estimates against their truth.

- The straight flight (`simulate`): six anchors at 2.0-2.8 m around a 10 m x 9 m room
  (ANCHORS_M), three tags flying straight below them at 0.6-0.75 m/s (TAGS) for DURATION_S; one
  range every RANGE_EVERY_S, round robin over the 18 tag-anchor pairs and the 3 tag-tag pairs
  (each tag hears each anchor about once a second).
- The sparse flight (`simulate_sparse`): what MiLUV's 3-robot run looks like
  (../shared/data/miluv/README.md), with a known truth: six anchors at 1.6-1.9 m around a
  ~6 m x 7 m room (SPARSE_ANCHORS_M); three drones (SPARSE_TAGS) flying straight legs between
  uniform random waypoints in FLIGHT_BOX_M (the middle 4 m x 4 m, 0.1-1.6 m high) at
  SPARSE_SPEED_M_S, a turn at each (`random_flight`); each tag ranging one anchor at a time in a
  random cycle of the six, gaps of min(MIN_GAP_S, gap / 2) + an exponential, mean gap SPARSE_GAP_S
  (~0.4 ranges a second; 0.43 s: MiLUV's 1-robot run, ~2.3 a second); each pair of tags ranging
  as a Poisson process of SPARSE_TAG_TAG_RATE a second (`anchor_cycle_events`, `tag_tag_events`).
- Two tags a body (`simulate_bodies`): the sparse flight's schedule for three bodies flying as its
  tags do, each carrying two tags on lever arms BODY_ARMS_M (MiLUV's 3-robot run: tags 10/11,
  20/21, 30/31, 0.45 m apart, from its tags.csv), the body's yaw turning at YAW_RATE_RAD_S; the
  tag-to-tag ranges between bodies, one of each body's tags (uniform) per range.

Ranges (`measured_ranges`): the true 3D distance at the range's time (a tag's truth interpolated
between its 100 Hz samples) through the UWB error model's formula (uwb.measured_range_m, no bias,
no scale, not clamped) with N(0, NOISE_M^2), and, on a share `nlos` of the ranges, an excess of
Exp(NLOS_MEAN_M) (NLOS reads long).

Randomness (deterministic, one numpy generator per flight): for the straight flight,
default_rng(seed) draws the noise only, one draw per range in time order. For the sparse flight
default_rng(seed) (the bodies: default_rng([seed, 7])) draws the flights (the bodies' centres) tag
by tag, then each tag's anchor cycle and gaps, then each pair's tag-to-tag times (and, for bodies,
which tags), then one noise draw per range in time order. The NLOS draws come from a second
generator, default_rng([seed, 1]), per range in time order (U(0, 1), then the excess if it is
one), so that the flight, the schedule and the noise do not change with `nlos`.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

from ..evaluation import tracking
from ..evaluation.tracking_baselines import TimedRanges
from .uwb import measured_range_m

Event = tuple[float, int, int]  # (t_s, from id, to id): one range of the schedule
Position = Callable[[int, float], np.ndarray]  # (node, t_s) -> its true position (m)

NOISE_M = 0.1        # m, the range noise std of every flight
NLOS_MEAN_M = 0.5    # m, the mean of an NLOS range's excess
TRUTH_STEP_S = 0.01  # s, the truth tracks' sampling

# the straight flight
ANCHORS_M = {0: (0.0, 0.0, 2.0), 1: (5.0, -0.5, 2.8), 2: (10.0, 0.0, 2.0), 3: (10.0, 8.0, 2.8), 4: (5.0, 8.5, 2.0),
             5: (0.0, 8.0, 2.8)}
# three tags flying straight at 0.6-0.75 m/s below the anchors: start (m), velocity (m/s)
TAGS = {10: ((1.0, 1.0, 0.5), (0.6, 0.45, 0.03)), 20: ((9.0, 1.5, 1.2), (-0.5, 0.5, -0.02)),
        30: ((5.0, 7.0, 0.8), (0.3, -0.6, 0.0))}
STRAIGHT_TAG_TAG_PAIRS = ((10, 20), (20, 30), (30, 10))
DURATION_S, RANGE_EVERY_S = 12.0, 0.05

# the sparse flight
SPARSE_ANCHORS_M = {0: (-3.0, -3.5, 1.6), 1: (3.2, -3.4, 1.9), 2: (3.3, 0.1, 1.7), 3: (3.1, 3.6, 1.6),
                    4: (-2.9, 3.7, 1.8), 5: (-3.1, 0.0, 1.9)}
SPARSE_TAGS = (10, 20, 30)
FLIGHT_BOX_M = ((-2.0, -2.0, 0.1), (2.0, 2.0, 1.6))
SPARSE_DURATION_S, SPARSE_SPEED_M_S, SPARSE_GAP_S, SPARSE_TAG_TAG_RATE = 120.0, 0.5, 2.5, 0.25
MIN_GAP_S = 0.3      # s, the shortest gap between a tag's anchor ranges (at most half the mean gap)

# two tags a body
BODY_ARMS_M = ((0.15, -0.165, -0.05), (-0.155, 0.16, -0.05))
BODY_TAGS = ((10, 11), (20, 21), (30, 31))
BODY_SEPARATION_M = float(np.linalg.norm(np.subtract(*BODY_ARMS_M)))
YAW_RATE_RAD_S = 0.3


# ----------------------------------------------------------------------------- the truth

def true_position(tag: int, t_s: float) -> np.ndarray:
    """Where a tag of the straight flight is at t_s (m)."""
    start, velocity = TAGS[tag]
    return np.array(start) + t_s * np.array(velocity)


def anchors() -> dict[int, np.ndarray]:
    """The straight flight's anchors (m)."""
    return {i: np.array(p, dtype=float) for i, p in ANCHORS_M.items()}


def sparse_anchors() -> dict[int, np.ndarray]:
    """The sparse flight's anchors (m), also the bodies'."""
    return {i: np.array(p, dtype=float) for i, p in SPARSE_ANCHORS_M.items()}


def truth_tracks() -> dict[int, tracking.NodeTrack]:
    """The straight flight's truth, every TRUTH_STEP_S."""
    times = np.arange(0.0, DURATION_S + TRUTH_STEP_S / 2.0, TRUTH_STEP_S)
    return {tag: tracking.NodeTrack(times, np.array([true_position(tag, t) for t in times])) for tag in TAGS}


def random_flight(rng: np.random.Generator, duration_s: float, speed_m_s: float) -> tracking.NodeTrack:
    """Straight legs at speed_m_s between uniform random waypoints in FLIGHT_BOX_M, every TRUTH_STEP_S."""
    lo, hi = np.array(FLIGHT_BOX_M[0]), np.array(FLIGHT_BOX_M[1])
    points, times = [lo + (hi - lo) * rng.random(3)], [0.0]
    while times[-1] < duration_s:
        points.append(lo + (hi - lo) * rng.random(3))
        times.append(times[-1] + float(np.linalg.norm(points[-1] - points[-2])) / speed_m_s)
    grid = np.arange(0.0, duration_s + TRUTH_STEP_S / 2.0, TRUTH_STEP_S)
    return tracking.NodeTrack(grid, np.array([np.interp(grid, times, [q[k] for q in points]) for k in range(3)]).T)


def track_position(track: tracking.NodeTrack, t_s: float) -> np.ndarray:
    """A track's position at t_s (m), interpolated between its samples, held at its ends."""
    return np.array([np.interp(t_s, track.t_s, track.p_m[:, k]) for k in range(3)])


def _positions(anchors_m: Mapping[int, tuple], tag_position: Position) -> Position:
    def at(node: int, t_s: float) -> np.ndarray:
        return np.array(anchors_m[node]) if node in anchors_m else tag_position(node, t_s)
    return at


# ----------------------------------------------------------------------------- the schedule

def anchor_cycle_events(rng: np.random.Generator, tags: Sequence[int], anchor_ids: Sequence[int], duration_s: float,
                        gap_s: float) -> list[Event]:
    """Each tag in turn ranges one anchor at a time in a random cycle of anchor_ids, the first
    range at U(0, SPARSE_GAP_S), then after gaps of min(MIN_GAP_S, gap_s / 2) + an exponential,
    gap_s on average."""
    min_gap_s = min(MIN_GAP_S, gap_s / 2.0)
    events = []
    for tag in tags:
        cycle = rng.permutation(list(anchor_ids))
        t_s, k = rng.uniform(0.0, SPARSE_GAP_S), 0
        while t_s < duration_s:
            events.append((t_s, tag, int(cycle[k % len(cycle)])))
            k += 1
            t_s += min_gap_s + rng.exponential(gap_s - min_gap_s)
    return events


def tag_tag_events(rng: np.random.Generator, groups: Sequence[Sequence[int]], duration_s: float,
                   rate: float) -> list[Event]:
    """Ranges between each pair of groups (a lone tag, or a body's tags) as a Poisson process of
    `rate` a second (none at 0); between bodies, one tag of each, drawn uniformly per range."""
    events = []
    if not rate:
        return events
    for i, group in enumerate(groups):
        for other in groups[i + 1:]:
            t_s = rng.exponential(1.0 / rate)
            while t_s < duration_s:
                events.append((t_s, _one_of(rng, group), _one_of(rng, other)))
                t_s += rng.exponential(1.0 / rate)
    return events


def _one_of(rng: np.random.Generator, group: Sequence[int]) -> int:
    return group[0] if len(group) == 1 else int(rng.choice(group))


# ----------------------------------------------------------------------------- the ranges

def measured_ranges(true_m: Sequence[float], rng: np.random.Generator, nlos: float = 0.0,
                    outliers: np.random.Generator | None = None) -> np.ndarray:
    """The ranges (m) a flight measures for these true distances (m): one N(0, NOISE_M^2) draw from
    rng per range, in order; when nlos > 0, per range from `outliers`: U(0, 1), and when it is
    below nlos an Exp(NLOS_MEAN_M) excess."""
    true_m = np.asarray(true_m, dtype=float)
    noise = rng.standard_normal(len(true_m))
    excess_m = 0.0
    if nlos:
        excess_m = np.array([outliers.exponential(NLOS_MEAN_M) if outliers.random() < nlos else 0.0
                             for _ in range(len(true_m))])
    return measured_range_m(true_m, noise, NOISE_M, outlier_m=excess_m)


def _timed_ranges(events: list[Event], at: Position, rng: np.random.Generator, nlos: float = 0.0,
                  outliers: np.random.Generator | None = None) -> TimedRanges:
    """The schedule's ranges in time order, measured from the truth."""
    events = sorted(events)
    true_m = [float(np.linalg.norm(at(a, t_s) - at(b, t_s))) for t_s, a, b in events]
    return TimedRanges(np.array([e[0] for e in events], dtype=float), np.array([e[1] for e in events], dtype=np.int64),
                       np.array([e[2] for e in events], dtype=np.int64), measured_ranges(true_m, rng, nlos, outliers),
                       np.arange(len(events)))


# ----------------------------------------------------------------------------- the flights

def simulate(seed: int, tag_tag: bool = True) -> TimedRanges:
    """The straight flight's ranges (tag_tag: with the tag-tag pairs in the round robin)."""
    print(f"seed {seed}")
    rng = np.random.default_rng(seed)
    pairs = [(t, a) for t in TAGS for a in ANCHORS_M] + (list(STRAIGHT_TAG_TAG_PAIRS) if tag_tag else [])
    events = [(k * RANGE_EVERY_S, *pairs[k % len(pairs)]) for k in range(round(DURATION_S / RANGE_EVERY_S))]
    return _timed_ranges(events, _positions(ANCHORS_M, true_position), rng)


def simulate_sparse(seed: int, tag_tag_rate: float = SPARSE_TAG_TAG_RATE, gap_s: float = SPARSE_GAP_S,
                    nlos: float = 0.0) -> tuple[TimedRanges, dict[int, tracking.NodeTrack]]:
    """(ranges, truth tracks) of the sparse flight. gap_s: the mean gap between a tag's anchor
    ranges; tag_tag_rate: each pair of tags' ranges a second; nlos: the share of ranges that read
    long."""
    print(f"sparse flight, seed {seed}, gap {gap_s} s, tag-tag {tag_tag_rate}/s, NLOS {nlos}")
    rng = np.random.default_rng(seed)
    truth = {tag: random_flight(rng, SPARSE_DURATION_S, SPARSE_SPEED_M_S) for tag in SPARSE_TAGS}
    events = anchor_cycle_events(rng, SPARSE_TAGS, list(SPARSE_ANCHORS_M), SPARSE_DURATION_S, gap_s)
    events += tag_tag_events(rng, [(tag,) for tag in SPARSE_TAGS], SPARSE_DURATION_S, tag_tag_rate)
    outliers = np.random.default_rng([seed, 1]) if nlos else None
    at = _positions(SPARSE_ANCHORS_M, lambda tag, t_s: track_position(truth[tag], t_s))
    return _timed_ranges(events, at, rng, nlos, outliers), truth


def simulate_bodies(seed: int) -> tuple[TimedRanges, dict[int, tracking.NodeTrack]]:
    """(ranges, truth tracks) of two tags a body on the sparse flight's schedule."""
    print(f"bodies, seed {seed}")
    rng = np.random.default_rng([seed, 7])
    truth = {}
    for body in BODY_TAGS:
        centre = random_flight(rng, SPARSE_DURATION_S, SPARSE_SPEED_M_S)
        yaw_rad = YAW_RATE_RAD_S * centre.t_s
        cos, sin = np.cos(yaw_rad), np.sin(yaw_rad)
        for tag, arm in zip(body, BODY_ARMS_M):
            offset_m = np.stack([cos * arm[0] - sin * arm[1], sin * arm[0] + cos * arm[1],
                                 np.full_like(yaw_rad, arm[2])], axis=1)
            truth[tag] = tracking.NodeTrack(centre.t_s, centre.p_m + offset_m)
    events = anchor_cycle_events(rng, list(truth), list(SPARSE_ANCHORS_M), SPARSE_DURATION_S, SPARSE_GAP_S)
    events += tag_tag_events(rng, BODY_TAGS, SPARSE_DURATION_S, SPARSE_TAG_TAG_RATE)
    at = _positions(SPARSE_ANCHORS_M, lambda tag, t_s: track_position(truth[tag], t_s))
    return _timed_ranges(events, at, rng), truth


# ----------------------------------------------------------------------------- the score

def score_rows(rows: list, truth: dict[int, tracking.NodeTrack], keep: set | None = None, align: bool = False) -> dict:
    """The overall figures (tracking.evaluate_tracking) of estimate rows (t_s, id, p_m, cov_m2 or
    None) against a flight's truth, of the truth's tags, only the (t_s, id) in keep when given;
    with nees_mean, the mean normalised estimation error squared (3D) of the rows that have a
    covariance and a truth (None when there are none, and with align: the rows are not in the
    truth's frame)."""
    estimates = {}
    for tag in truth:
        mine = [r for r in rows if r[1] == tag and (keep is None or (r[0], tag) in keep)]
        covs = [np.full((3, 3), np.nan) if r[3] is None else r[3] for r in mine]
        estimates[tag] = tracking.NodeTrack(np.array([r[0] for r in mine]),
                                            np.array([r[2] for r in mine]).reshape(-1, 3),
                                            np.array(covs).reshape(-1, 3, 3))
    out = tracking.evaluate_tracking(estimates, truth, align=align)["overall"]
    nees = []
    for t_s, tag, p_m, cov in [] if align else rows:
        if tag in truth and cov is not None and (keep is None or (t_s, tag) in keep):
            g = tracking.interpolate_truth(truth[tag], t_s)
            if not isinstance(g, str):      # a row without truth has no error
                nees.append(float((p_m - g) @ np.linalg.solve(cov, p_m - g)))
    out["nees_mean"] = float(np.mean(nees)) if nees else None
    return out
