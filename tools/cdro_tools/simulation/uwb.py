"""The UWB error model: what a Pozyx two-way range reports for two nodes at a given time, and
when it fails. (How long it takes is the Pozyx model's, sim/pozyx_sim, which asks this
model for every ranging the firmware runs.)

    measured_m = scale x true_3d_m + link_bias_m + N(0, link_std_m^2) [+ Exp(outlier_mean_m)]

(measured_range_m, also the ranges of the seeded flights, flights.py, and of the paper's
Algorithm 1, evaluation/paper_algorithm1.py)

- link_std_m: uwb.noise_std_m, or per link sqrt(U(noise_variance_m2)) drawn once per link;
- link_bias_m: persistent NLOS bias (>= 0) of listed links and of random_links chosen ones;
- the exponential term is added with probability outlier_probability (NLOS reads long);
- a range fails (Pozyx error 0x11) with dropout_probability, and (0x12, timeout) when the
  nodes are farther apart than max_range_m or a node does not exist;
- negative results are clamped to 0 (the Pozyx reports an unsigned distance).
RSS follows a log-distance model: -67 dBm - 20 log10(d / 1 m), rss_loss_db lower on biased
links, N(0, 1.5 dB) noise, clamped to [-110, -40] dBm.
"""
from __future__ import annotations

import dataclasses
import itertools
import math
import random

from .scenario import Scenario
from .world import World

POZYX_RANGING_FAILED = 0x11
POZYX_RANGING_TIMEOUT = 0x12
RSS_AT_1M_DBM = -67.0
RSS_NOISE_DB = 1.5


@dataclasses.dataclass
class RangeOutcome:
    ok: bool
    distance_mm: int = 0
    rss_dbm: int = 0
    error_code: int = 0        # Pozyx ERRORCODE when not ok


def measured_range_m(true_m, noise_draw, std_m, bias_m=0.0, scale=1.0, outlier_m=0.0):
    """scale x true_m + bias_m + std_m x noise_draw + outlier_m: the range a two-way ranging reports,
    from a standard normal draw and an NLOS excess (0 when the range is not an outlier). Floats or
    numpy arrays alike (elementwise). Not clamped: what a negative result becomes is the caller's
    (the Pozyx reports 0, the paper's Algorithm 1 takes its absolute value)."""
    return scale * true_m + bias_m + std_m * noise_draw + outlier_m


def link_key(a: int, b: int) -> tuple[int, int]:
    return (a, b) if a < b else (b, a)


class UwbModel:
    def __init__(self, scenario: Scenario, world: World, link_rng: random.Random, range_rng: random.Random):
        self.model = scenario.uwb
        self.world = world
        self._range_rng = range_rng
        ids = sorted(n.id for n in scenario.nodes)
        pairs = list(itertools.combinations(ids, 2))
        self.link_std_m: dict[tuple[int, int], float] = {}
        for pair in pairs:  # drawn for every pair, in id order, whether used or not
            if self.model.noise_variance_m2 is not None:
                self.link_std_m[pair] = math.sqrt(link_rng.uniform(*self.model.noise_variance_m2))
            else:
                self.link_std_m[pair] = self.model.noise_std_m
        self.link_bias_m: dict[tuple[int, int], float] = {}
        for link in self.model.nlos.links:
            self.link_bias_m[link_key(link.a, link.b)] = link.bias_m
        candidates = [p for p in pairs if p not in self.link_bias_m]
        for pair in link_rng.sample(candidates, self.model.nlos.random_links):
            self.link_bias_m[pair] = link_rng.uniform(*self.model.nlos.random_bias_m)

    def reachable(self, a: int, b: int, t_s: float) -> bool:
        return (self.world.has(a) and self.world.has(b)
                and self.world.distance_m(a, b, t_s) <= self.model.max_range_m)

    def measure(self, a: int, b: int, t_s: float) -> RangeOutcome:
        """One two-way ranging attempt between a and b starting at t_s."""
        rng = self._range_rng
        # the same draws for every attempt, so that one attempt's fate does not shift the rest
        u_drop, u_outlier, noise, tail, rss_noise = rng.random(), rng.random(), rng.gauss(0.0, 1.0), \
            rng.expovariate(1.0), rng.gauss(0.0, RSS_NOISE_DB)
        if not self.reachable(a, b, t_s):
            return RangeOutcome(False, error_code=POZYX_RANGING_TIMEOUT)
        if u_drop < self.model.dropout_probability:
            return RangeOutcome(False, error_code=POZYX_RANGING_FAILED)
        key = link_key(a, b)
        true_m = self.world.distance_m(a, b, t_s)
        bias_m = self.link_bias_m.get(key, 0.0)
        outlier_m = self.model.nlos.outlier_mean_m * tail if u_outlier < self.model.nlos.outlier_probability else 0.0
        measured_m = measured_range_m(true_m, noise, self.link_std_m[key], bias_m, self.model.scale, outlier_m)
        distance_mm = int(min(0xFFFFFFFF, max(0, round(measured_m * 1000.0))))
        rss = RSS_AT_1M_DBM - 20.0 * math.log10(max(true_m, 0.1)) + rss_noise
        if bias_m > 0.0:
            rss -= self.model.nlos.rss_loss_db
        rss_dbm = int(min(-40, max(-110, round(rss))))
        return RangeOutcome(True, distance_mm, rss_dbm)
