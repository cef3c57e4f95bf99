"""Random geometric networks for the engine's offline tests (cdro-sim --random-network).

N nodes uniform in a square of side sqrt(N) x 10 m (one node per 100 m^2 on average). The
radio range R is the distance that links exactly round(N D / 2) pairs, so the mean degree is
D (up to ties); a drawing that is not connected is drawn again (up to 200 times). Ranges are
measured over every linked pair, round robin, `sweeps` times, with Gaussian noise and
optionally a persistent positive NLOS bias on a fraction of the links. There is no device
here: no Pozyx limits, no failures, no timing beyond a nominal 50 ms per range.
"""
from __future__ import annotations

import dataclasses
import math
import random

from .scenario import ScenarioError
from .uwb import measured_range_m

FIRST_ID = 0x6001
AREA_PER_NODE_M2 = 100.0
RANGE_PERIOD_S = 0.05
ATTEMPTS = 200


@dataclasses.dataclass
class RandomNetwork:
    nodes: list[tuple[int, float, float, float]]     # (id, x_m, y_m, z_m)
    links: list[tuple[int, int]]                     # pairs of indices into nodes, i < j
    radius_m: float
    ranges: list[tuple[float, int, int, float]]      # (t_s, from, to, range_m)
    biased_links: int = 0

    @property
    def mean_degree(self) -> float:
        return 2.0 * len(self.links) / len(self.nodes)


def _connected(count: int, links: list[tuple[int, int]]) -> bool:
    neighbours: list[list[int]] = [[] for _ in range(count)]
    for a, b in links:
        neighbours[a].append(b)
        neighbours[b].append(a)
    seen = {0}
    stack = [0]
    while stack:
        for other in neighbours[stack.pop()]:
            if other not in seen:
                seen.add(other)
                stack.append(other)
    return len(seen) == count


def random_network(count: int, degree: float, seed: int, noise_m: float = 0.1, sweeps: int = 10,
                   height_range_m: tuple[float, float] | None = None, nlos_fraction: float = 0.0,
                   nlos_bias_m: tuple[float, float] = (0.3, 1.5)) -> RandomNetwork:
    if count < 3:
        raise ScenarioError(f"--random-network {count}: need at least 3 nodes")
    if count > 0xFFFF - FIRST_ID:
        raise ScenarioError(f"--random-network {count}: too many nodes for 16-bit ids")
    if not 2.0 <= degree <= count - 1:
        raise ScenarioError(f"--degree {degree}: must be between 2 and {count - 1} (nodes - 1)")
    if noise_m < 0 or sweeps < 1 or not 0.0 <= nlos_fraction <= 1.0:
        raise ScenarioError("--noise-m must be >= 0, --sweeps >= 1, --nlos-fraction in [0, 1]")
    rng = random.Random(f"cdro-sim:{seed}:random-network")
    side_m = math.sqrt(count * AREA_PER_NODE_M2)
    wanted = max(count - 1, round(count * degree / 2.0))
    for _ in range(ATTEMPTS):
        xy = [(rng.uniform(0.0, side_m), rng.uniform(0.0, side_m)) for _ in range(count)]
        z = [rng.uniform(*height_range_m) if height_range_m else 0.0 for _ in range(count)]
        pairs = sorted((math.dist(xy[i], xy[j]), i, j) for i in range(count) for j in range(i + 1, count))
        radius_m = pairs[wanted - 1][0]
        links = [(i, j) for d, i, j in pairs if d <= radius_m]
        if _connected(count, links):
            break
    else:
        raise ScenarioError(f"no connected network with {count} nodes and mean degree {degree} in {ATTEMPTS} "
                            f"drawings; raise --degree")
    links.sort()
    ids = [FIRST_ID + i for i in range(count)]
    nodes = [(ids[i], xy[i][0], xy[i][1], z[i]) for i in range(count)]
    std = {link: noise_m for link in links}
    bias = {}
    for link in rng.sample(links, round(nlos_fraction * len(links))):
        bias[link] = rng.uniform(*nlos_bias_m)
    ranges = []
    t_s = 0.0
    for _ in range(sweeps):
        for i, j in links:
            true_m = math.dist((*xy[i], z[i]), (*xy[j], z[j]))
            measured_m = max(0.0, measured_range_m(true_m, rng.gauss(0.0, 1.0), std[(i, j)], bias.get((i, j), 0.0)))
            ranges.append((round(t_s, 3), ids[i], ids[j], round(measured_m, 3)))
            t_s += RANGE_PERIOD_S
    return RandomNetwork(nodes, links, radius_m, ranges, len(bias))
