"""The paper's Algorithm 1 as it is written, for the Fig. 3 comparison (docs/results.md).

The engine (host/engine) is a streaming filter with a robust placement, a weight floor, a
collapse reset, rings that follow their centre and a refinement; the paper's Algorithm 1 is a
batch loop. To tell whether weight transfer (eq. 15) lowers the steady-state RMSE in the paper's
own algorithm, this module runs that algorithm and nothing else, on the paper's Fig. 3 setting
(five nodes, range noise variance 0.3-0.8 m^2):

  1. iterative multilateration, eqs. 1-4 (nodes 0 and 1 define the frame, node 2 the +y side,
     every later node from nodes 0 and 1, its sign from its range to node 2);
  2. a ring SoG per ordered pair (i, j) around p_i describing node j, eqs. 5-7: N components
     on the circle of radius r_ij, radial std sigma, tangential std arc / 2.5, weights 1/N;
  3. each iteration: a new range for every pair; every component's EKF update to r_ij (by
     default from the ring's centre where it was generated); the cooperative weight update with every
     other node m, eqs. 8-11; the merge, eqs. 12-13; the weight transfer, eq. 15 (switchable);
  4. the aligned RMSE (rotation, translation, reflection) of the merged positions after every
     iteration.

Nothing here is tuned: where the paper is silent (N, the tangential spread, the filter's sigma)
the engine's defaults are used, and a ring whose weights all underflow starts again from 1/N.
Where the paper can be read two ways, `Reading` holds the choice, so that each reading can be
measured: the filter's sigma (eqs. 6 and 8), the side of the square, and the centre a ring's EKF
update measures from ("p_i will be p_i in the next iteration": the ring's own centre, or the
node's current merged position). A range is the UWB error model's (simulation.uwb.measured_range_m:
the link's Gaussian noise, no bias) reflected at 0 and averaged over both directions. Randomness:
numpy's PCG64 from the seed, printed.

    python -m cdro_tools.evaluation.paper_algorithm1 [--seeds 10] [--seed 1] [--iterations 100]
        [--arc-spacing-m 1.0] [--components N] [--range-noise-m SD] [--filter-sigma-m SD]
        [--side-m M] [--ring-centre generated|merged] [--sweep] [--png PATH]
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, replace

import numpy as np

from cdro_tools.evaluation.alignment import rigid_fit
from cdro_tools.simulation.uwb import measured_range_m

NODES = 5
NOISE_VARIANCE_M2 = (0.3, 0.8)  # m^2, each link's range noise variance, drawn once per link
TRANSFER_SIGMA_M = 0.5         # m, eq. 15's sigma (the paper's example)
TANGENTIAL_OVERLAP = 2.5       # sigma_t = arc spacing / this (the engine's default)
MIN_COMPONENTS = 8


RING_CENTRES = ("generated", "merged")


@dataclass(frozen=True)
class Reading:
    """What the paper leaves open, as one choice per field (defaults: the engine's)."""
    components: int | None = None  # N of every ring; None: from the arc spacing
    arc_spacing_m: float = 1.0      # m between neighbouring components when N is not given
    filter_sigma_m: float = 0.75    # m, the sigma of eqs. 6 and 8 (the middle of the noise setting)
    side_m: float = 20.0            # m, nodes uniform in a square of this side
    ring_centre: str = "generated"  # the EKF update's centre: "generated" (p_i at eq. 5) or "merged"
    range_noise_m: float | None = None  # m, one noise std for every link instead of the setting's


@dataclass
class Ring:
    center_m: np.ndarray       # (2,) m, what the EKF update measures from (Reading.ring_centre)
    means_m: np.ndarray        # (N, 2) m
    covariances_m2: np.ndarray  # (N, 2, 2) m^2
    weights: np.ndarray        # (N,), sum 1


def _multilaterate(ranges_m: np.ndarray) -> np.ndarray:
    """Eqs. 1-4: the initial positions from one set of ranges (m)."""
    r = ranges_m
    p = np.zeros((NODES, 2))
    p[1] = [r[0, 1], 0.0]
    x2 = (r[0, 1] ** 2 + r[0, 2] ** 2 - r[1, 2] ** 2) / (2.0 * p[1, 0])
    p[2] = [x2, np.sqrt(max(r[0, 2] ** 2 - x2 ** 2, 0.0))]
    for node in range(3, NODES):
        x = (r[0, 1] ** 2 + r[0, node] ** 2 - r[1, node] ** 2) / (2.0 * p[1, 0])
        y = np.sqrt(max(r[0, node] ** 2 - x ** 2, 0.0))
        # "The sign of y_l is chosen as the one whose distance |p_2 - p_l| is closer to r_2l."
        above, below = np.array([x, y]), np.array([x, -y])
        p[node] = min((above, below), key=lambda c: abs(np.linalg.norm(p[2] - c) - r[2, node]))
    return p


def _ring(center_m: np.ndarray, range_m: float, reading: Reading) -> Ring:
    """Eqs. 5-7."""
    count = reading.components or max(MIN_COMPONENTS, int(2.0 * np.pi * range_m / reading.arc_spacing_m) + 1)
    angle_rad = 2.0 * np.pi * np.arange(count) / count
    radial = np.stack([np.cos(angle_rad), np.sin(angle_rad)], axis=1)
    tangential = np.stack([-radial[:, 1], radial[:, 0]], axis=1)
    tangential_sigma_m = 2.0 * np.pi * range_m / count / TANGENTIAL_OVERLAP
    covariances = (reading.filter_sigma_m ** 2 * np.einsum("ki,kj->kij", radial, radial)
                   + tangential_sigma_m ** 2 * np.einsum("ki,kj->kij", tangential, tangential))
    return Ring(center_m.copy(), center_m + range_m * radial, covariances, np.full(count, 1.0 / count))


def _ekf_update(ring: Ring, range_m: float, sigma_m: float) -> None:
    """Every component's EKF update to the range from the ring's centre."""
    offset = ring.means_m - ring.center_m
    predicted_m = np.linalg.norm(offset, axis=1)
    jacobian = offset / predicted_m[:, None]                     # d|m - c| / dm
    innovation_variance = np.einsum("ki,kij,kj->k", jacobian, ring.covariances_m2, jacobian) + sigma_m ** 2
    gain = np.einsum("kij,kj->ki", ring.covariances_m2, jacobian) / innovation_variance[:, None]
    ring.means_m = ring.means_m + gain * (range_m - predicted_m)[:, None]
    ring.covariances_m2 = ring.covariances_m2 - np.einsum(
        "ki,kj->kij", gain, np.einsum("kj,kji->ki", jacobian, ring.covariances_m2))


def _weight_update(ring: Ring, other_m: np.ndarray, other_range_m: float, sigma_m: float) -> None:
    """Eqs. 8-11 for one other node m: its position and its range to the ring's node."""
    predicted_m = np.linalg.norm(ring.means_m - other_m, axis=1)
    likelihood = np.exp(-((predicted_m - other_range_m) ** 2) / (2.0 * sigma_m ** 2))
    if likelihood.sum() <= 0.0:
        return
    weights = ring.weights * likelihood / likelihood.sum()
    total = weights.sum()
    ring.weights = weights / total if total > 0.0 else np.full(len(weights), 1.0 / len(weights))


def _transfer(ring: Ring) -> None:
    """Eq. 15: a Gaussian of the distance to the heaviest component, normalised."""
    heaviest = ring.means_m[int(np.argmax(ring.weights))]
    distance_m = np.linalg.norm(ring.means_m - heaviest, axis=1)
    weights = np.exp(-(distance_m ** 2) / (2.0 * TRANSFER_SIGMA_M ** 2))
    ring.weights = weights / weights.sum()


def aligned_rmse_m(estimate_m: np.ndarray, truth_m: np.ndarray) -> float:
    """RMSE after the rigid fit (rotation, translation, reflection allowed, no scale): the one
    fit of the tools (alignment.rigid_fit), rows in the same node order."""
    rotation, translation = rigid_fit(estimate_m, truth_m)
    moved = np.asarray(estimate_m, dtype=float) @ rotation.T + translation
    return float(np.sqrt(np.mean(np.sum((moved - truth_m) ** 2, axis=1))))


def run(seed: int, weight_transfer: bool, iterations: int = 100, reading: Reading = Reading()) -> np.ndarray:
    """The aligned RMSE (m) after each iteration of Algorithm 1 on one draw of the setting.

    The draw (positions, noise variances, every range) depends on the seed and the reading's
    side only, so that the runs with and without weight transfer see the same ranges."""
    rng = np.random.Generator(np.random.PCG64(seed))
    truth_m = rng.uniform(0.0, reading.side_m, (NODES, 2))
    variance_m2 = np.triu(rng.uniform(*NOISE_VARIANCE_M2, (NODES, NODES)), 1)
    noise_m = np.sqrt(variance_m2 + variance_m2.T)
    if reading.range_noise_m is not None:
        noise_m = np.full((NODES, NODES), reading.range_noise_m)
    distance_m = np.linalg.norm(truth_m[:, None] - truth_m[None], axis=2)
    sigma_m = reading.filter_sigma_m

    def measure() -> np.ndarray:
        ranges = np.abs(measured_range_m(distance_m, rng.standard_normal((NODES, NODES)), noise_m))
        return (ranges + ranges.T) / 2.0         # one range per link, both directions

    ranges_m = measure()
    position_m = _multilaterate(ranges_m)
    rings = {(i, j): _ring(position_m[i], ranges_m[i, j], reading)
             for i in range(NODES) for j in range(NODES) if i != j}
    history = np.empty(iterations)
    for iteration in range(iterations):
        ranges_m = measure()
        for (i, j), ring in rings.items():
            if reading.ring_centre == "merged":
                ring.center_m = position_m[i].copy()
            _ekf_update(ring, ranges_m[i, j], sigma_m)
            for m in range(NODES):
                if m not in (i, j):
                    _weight_update(ring, position_m[m], ranges_m[m, j], sigma_m)
        merged_m = position_m.copy()
        for j in range(NODES):
            weights = np.concatenate([rings[i, j].weights for i in range(NODES) if i != j])
            means = np.concatenate([rings[i, j].means_m for i in range(NODES) if i != j])
            merged_m[j] = weights @ means / weights.sum()
        position_m = merged_m
        if weight_transfer:
            for ring in rings.values():
                _transfer(ring)
        history[iteration] = aligned_rmse_m(position_m, truth_m)
    return history


def steady_state_m(history: np.ndarray) -> float:
    """The mean over the second half of the run, as docs/results.md reads "steady state"."""
    return float(history[len(history) // 2:].mean())


def compare(seeds: list[int], iterations: int = 100, reading: Reading = Reading()) -> dict[bool, list[np.ndarray]]:
    """The RMSE histories of every seed, with (True) and without (False) weight transfer."""
    return {transfer: [run(seed, transfer, iterations, reading) for seed in seeds] for transfer in (True, False)}


@dataclass(frozen=True)
class Comparison:
    """Steady-state RMSEs (m) of both modes over the same draws."""
    with_transfer_m: list[float]
    without_transfer_m: list[float]

    def draws_where_transfer(self, better: bool, margin_m: float = 0.01) -> int:
        pairs = zip(self.with_transfer_m, self.without_transfer_m)
        return sum((w < wo - margin_m) if better else (w > wo + margin_m) for w, wo in pairs)


def steady_states(seeds: list[int], iterations: int = 100, reading: Reading = Reading()) -> Comparison:
    histories = compare(seeds, iterations, reading)
    return Comparison([steady_state_m(h) for h in histories[True]], [steady_state_m(h) for h in histories[False]])


def sweep(seeds: list[int], iterations: int = 100) -> list[tuple[str, Reading, Comparison]]:
    """The readings docs/results.md reports, one line each: the default, then one choice changed."""
    base = Reading()
    readings = [("the engine's defaults (sigma 0.75 m, rings 1 m apart, 20 m square)", base),
                ("rings of 16 components", replace(base, components=16))]
    readings += [(f"filter sigma {sigma:g} m", replace(base, filter_sigma_m=sigma)) for sigma in (0.1, 0.3, 0.5)]
    readings += [(f"{side:g} m square", replace(base, side_m=side)) for side in (5.0, 10.0, 40.0)]
    readings += [("EKF from the merged position", replace(base, ring_centre="merged")),
                 ("EKF from the merged position, 16 components", replace(base, ring_centre="merged", components=16))]
    return [(name, reading, steady_states(seeds, iterations, reading)) for name, reading in readings]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m cdro_tools.evaluation.paper_algorithm1",
        description="The paper's Algorithm 1 as written, on its Fig. 3 setting, with and without weight "
                    "transfer: the steady-state RMSE per seed and the mean.",
        epilog="example: python -m cdro_tools.evaluation.paper_algorithm1 --seeds 10 --png fig3-batch.png")
    parser.add_argument("--seeds", type=int, default=10, help="draws (default 10)")
    parser.add_argument("--seed", type=int, default=1, help="the first draw's seed (default 1)")
    parser.add_argument("--iterations", type=int, default=100, help="iterations of Algorithm 1 (default 100)")
    parser.add_argument("--arc-spacing-m", type=float, default=1.0, help="m between ring components (default 1)")
    parser.add_argument("--components", type=int, help="N for every ring instead of the arc spacing")
    parser.add_argument("--range-noise-m", type=float, help="m, one range noise std for every link instead of "
                                                            "the setting's variances")
    parser.add_argument("--filter-sigma-m", type=float, default=0.75, help="m, the sigma of eqs. 6 and 8 "
                                                                           "(default 0.75)")
    parser.add_argument("--side-m", type=float, default=20.0, help="m, the side of the nodes' square (default 20)")
    parser.add_argument("--ring-centre", choices=RING_CENTRES, default="generated",
                        help="what a ring's EKF update measures from: its centre at generation (default) or "
                             "the node's current merged position")
    parser.add_argument("--sweep", action="store_true", help="every reading docs/results.md reports, a line each "
                                                             "(the reading options are then ignored)")
    parser.add_argument("--png", help="the RMSE over iterations of the first seed, both modes")
    args = parser.parse_args(argv)
    if args.seeds < 1 or args.iterations < 2 or args.arc_spacing_m <= 0.0 or args.filter_sigma_m <= 0.0 or \
            args.side_m <= 0.0 or (args.components is not None and args.components < 3):
        parser.error("--seeds >= 1, --iterations >= 2, --arc-spacing-m, --filter-sigma-m and --side-m > 0, "
                     "--components >= 3")
    seeds = list(range(args.seed, args.seed + args.seeds))
    if args.sweep:
        print(f"paper's Algorithm 1, {NODES} nodes, {args.iterations} iterations, seeds {seeds[0]}..{seeds[-1]}: "
              "steady-state RMSE mean with / without weight transfer, draws where transfer is better / worse")
        for name, _, result in sweep(seeds, args.iterations):
            print(f"  {name:70s} {np.mean(result.with_transfer_m):.3f} / {np.mean(result.without_transfer_m):.3f} m"
                  f"  {result.draws_where_transfer(better=True)} / {result.draws_where_transfer(better=False)}")
        return 0
    reading = Reading(args.components, args.arc_spacing_m, args.filter_sigma_m, args.side_m, args.ring_centre,
                      args.range_noise_m)
    print(f"paper's Algorithm 1, {NODES} nodes in {reading.side_m:g} m x {reading.side_m:g} m, "
          f"{args.iterations} iterations, seeds {seeds[0]}..{seeds[-1]}")
    curves = {}
    for transfer, histories in compare(seeds, args.iterations, reading).items():
        label = "with weight transfer" if transfer else "without weight transfer"
        figures = [steady_state_m(history) for history in histories]
        curves[label] = histories[0]
        print(f"  {label:24s} steady-state RMSE mean {np.mean(figures):.3f} m; per seed "
              + " ".join(f"{f:.2f}" for f in figures))
    if args.png:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(figsize=(7, 4))
        for label, history in curves.items():
            ax.plot(np.arange(1, len(history) + 1), history, label=label)
        ax.set_xlabel("iteration")
        ax.set_ylabel("aligned RMSE (m)")
        ax.set_title(f"paper's Algorithm 1, Fig. 3 setting, seed {seeds[0]}")
        ax.grid(alpha=0.3)
        ax.legend()
        fig.tight_layout()
        fig.savefig(args.png)
        plt.close(fig)
        print(f"  wrote {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
