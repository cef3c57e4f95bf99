"""Baselines solved from the ranges alone (no truth), for comparison with the engine.

Choices (docs/tools.md, cdro-eval, says why; data/README's PLANT figures are reproduced
with them):
- A link's range is the mean of its ranges (r_ij and r_ji together), in every baseline.
- MDS-MAP: the link ranges fill a distance matrix, shortest paths over the link graph
  complete it (Dijkstra), classical MDS (double centring, the two largest eigenpairs) gives
  the 2D map.
- Batch least squares: one residual per link, |p_i - p_j| - r_ij, scipy's
  least_squares (trust region reflective, analytic Jacobian) with loss='huber' and
  f_scale = 1.345 sigma (Huber's 95 %-efficiency tuning; 0.175 m for sigma 0.13 m),
  started from MDS-MAP.
- Drop and re-solve: after the Huber solution, drop the links whose measured range exceeds
  the fitted distance by more than 0.6 m (NLOS reads long, never short), then re-solve the
  kept links by plain least squares, started from the Huber solution.
Only the largest connected component of the link graph is solved: the others have no
relation to it.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import numpy as np

HUBER_K = 1.345                     # Huber's tuning constant, in units of sigma
DROP_THRESHOLD_M = 0.6
# The exact trust-region steps (dense SVD) converge in tens to hundreds of evaluations where
# lsmr steps took thousands (random networks of 60-200 nodes: 70-207 against 3800-40000
# evaluations, 4-15x slower overall); at 400 nodes a dense solve took about 2 minutes, so
# beyond 300 nodes the sparse steps run, up to the evaluation limit.
DENSE_JACOBIAN_MAX_PARAMETERS = 600
MAX_EVALUATIONS = 2000              # PLANT needs 40; a solve that hits this says so in its notes
NAMES = ("mds", "lsq-huber", "lsq-drop")


class BaselineError(ValueError):
    """A network a baseline cannot solve (too few nodes, ...)."""


@dataclasses.dataclass
class Links:
    """One entry per link (smaller id, larger id): the link's range (m) and how many ranges."""
    pairs: list[tuple[int, int]]
    range_m: np.ndarray
    counts: np.ndarray

    @classmethod
    def from_ranges(cls, links: Mapping[tuple[int, int], list[float]]) -> "Links":
        pairs = sorted(links)
        return cls(pairs, np.array([float(np.mean(links[p])) for p in pairs]),
                   np.array([len(links[p]) for p in pairs], dtype=np.int64))

    def subset(self, keep: np.ndarray) -> "Links":
        return Links([p for p, k in zip(self.pairs, keep) if k], self.range_m[keep], self.counts[keep])

    def node_ids(self) -> list[int]:
        return sorted({i for pair in self.pairs for i in pair})

    def degrees(self) -> dict[int, int]:
        out: dict[int, int] = {}
        for a, b in self.pairs:
            out[a] = out.get(a, 0) + 1
            out[b] = out.get(b, 0) + 1
        return out


def components(links: Links) -> list[list[int]]:
    """Connected components of the link graph, largest first (ties: the smallest id first)."""
    neighbours: dict[int, set[int]] = {i: set() for i in links.node_ids()}
    for a, b in links.pairs:
        neighbours[a].add(b)
        neighbours[b].add(a)
    seen: set[int] = set()
    out = []
    for start in sorted(neighbours):
        if start in seen:
            continue
        component, stack = [], [start]
        seen.add(start)
        while stack:
            node = stack.pop()
            component.append(node)
            for other in neighbours[node] - seen:
                seen.add(other)
                stack.append(other)
        out.append(sorted(component))
    return sorted(out, key=lambda c: (-len(c), c[0]))


def mds_map(links: Links) -> dict[int, np.ndarray]:
    """MDS-MAP of a connected link graph: shortest-path distances, classical MDS to 2D."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import shortest_path
    ids = links.node_ids()
    if len(ids) < 3:
        raise BaselineError(f"MDS-MAP needs at least 3 nodes (got {len(ids)})")
    index = {node_id: k for k, node_id in enumerate(ids)}
    rows = [index[a] for a, _ in links.pairs]
    cols = [index[b] for _, b in links.pairs]
    # a zero range would vanish from a sparse matrix: keep it as a tiny positive weight
    graph = csr_matrix((np.maximum(links.range_m, 1e-9), (rows, cols)), shape=(len(ids), len(ids)))
    distance = shortest_path(graph, method="D", directed=False)
    if not np.isfinite(distance).all():
        raise BaselineError("MDS-MAP needs a connected link graph")
    m = len(ids)
    centring = np.eye(m) - np.full((m, m), 1.0 / m)
    gram = -0.5 * centring @ (distance ** 2) @ centring
    values, vectors = np.linalg.eigh(gram)
    top = np.argsort(values)[::-1][:2]
    xy = vectors[:, top] * np.sqrt(np.clip(values[top], 0.0, None))
    return {node_id: xy[k] for node_id, k in index.items()}


@dataclasses.dataclass
class LsqSolution:
    positions_m: dict[int, np.ndarray]
    residuals_m: np.ndarray             # per link: measured range - fitted distance
    evaluations: int
    status: int                         # scipy's: > 0 converged by a tolerance, 0 evaluation limit

    @property
    def converged(self) -> bool:
        return self.status > 0


def solve_lsq(links: Links, start_m: Mapping[int, np.ndarray], loss: str = "huber",
              f_scale_m: float = HUBER_K * 0.13) -> LsqSolution:
    """Batch least squares over the links' ranges, one residual per link, from start_m
    (which must hold every node of the links). The solution keeps the start's gauge only
    roughly: compare it after a rigid alignment."""
    from scipy.optimize import least_squares
    from scipy.sparse import csr_matrix
    ids = links.node_ids()
    missing = [i for i in ids if i not in start_m]
    if missing:
        raise BaselineError(f"no start position for node(s) {missing}")
    index = {node_id: k for k, node_id in enumerate(ids)}
    a = np.array([index[p[0]] for p in links.pairs], dtype=np.int64)
    b = np.array([index[p[1]] for p in links.pairs], dtype=np.int64)
    measured = links.range_m
    n, parameters = len(links.pairs), 2 * len(ids)
    rows = np.repeat(np.arange(n), 4)
    cols = np.stack([2 * a, 2 * a + 1, 2 * b, 2 * b + 1], axis=1).ravel()
    sparse = parameters > DENSE_JACOBIAN_MAX_PARAMETERS

    def residuals(x):
        xy = x.reshape(-1, 2)
        return np.linalg.norm(xy[a] - xy[b], axis=1) - measured

    def jacobian(x):
        xy = x.reshape(-1, 2)
        d = xy[a] - xy[b]
        # d |p_i - p_j| / d p_i = u, / d p_j = -u; two coincident nodes get a zero row
        u = d / np.maximum(np.linalg.norm(d, axis=1), 1e-12)[:, None]
        values = np.stack([u[:, 0], u[:, 1], -u[:, 0], -u[:, 1]], axis=1).ravel()
        matrix = csr_matrix((values, (rows, cols)), shape=(n, parameters))
        return matrix if sparse else matrix.toarray()

    x0 = np.concatenate([np.asarray(start_m[i], dtype=float)[:2] for i in ids])
    result = least_squares(residuals, x0, jac=jacobian, loss=loss, f_scale=f_scale_m,
                           tr_solver="lsmr" if sparse else "exact", max_nfev=MAX_EVALUATIONS)
    xy = result.x.reshape(-1, 2)
    return LsqSolution({node_id: xy[k] for node_id, k in index.items()}, -residuals(result.x), int(result.nfev),
                       int(result.status))


@dataclasses.dataclass
class BaselineResult:
    name: str
    positions_m: dict[int, np.ndarray]
    notes: list[str]
    details: dict


def run_baselines(links_all: Links, names: list[str], f_scale_m: float, drop_threshold_m: float = DROP_THRESHOLD_M,
                  resolve_loss: str = "linear") -> list[BaselineResult]:
    """The requested baselines (of NAMES, in NAMES' order) on the largest component; a
    baseline that needs another one computes it even when it is not requested."""
    unknown = [n for n in names if n not in NAMES]
    if unknown:
        raise BaselineError(f"unknown baseline(s) {', '.join(unknown)} (known: {', '.join(NAMES)})")
    parts = components(links_all)
    if not parts or len(parts[0]) < 3:
        raise BaselineError(f"the largest connected group of ranged nodes has {len(parts[0]) if parts else 0} "
                            f"node(s); the baselines need at least 3")
    main = set(parts[0])
    keep = np.array([p[0] in main for p in links_all.pairs], dtype=bool)
    links = links_all.subset(keep)
    left_out = sorted(i for part in parts[1:] for i in part)
    common = [f"{len(left_out)} node(s) outside the largest connected component not solved"] if left_out else []
    base = {"links": len(links.pairs), "ranges": int(links.counts.sum()), "nodes_not_solved": left_out}
    out: list[BaselineResult] = []
    mds = mds_map(links)
    if "mds" in names:
        out.append(BaselineResult("mds", mds, common + ["per-link mean, shortest paths, classical MDS"], dict(base)))
    if "lsq-huber" not in names and "lsq-drop" not in names:
        return out
    huber = solve_lsq(links, mds, "huber", f_scale_m)
    limit = [f"stopped at the limit of {MAX_EVALUATIONS} evaluations: not converged"]
    if "lsq-huber" in names:
        out.append(BaselineResult("lsq-huber", huber.positions_m,
                                  common + [f"Huber f_scale {f_scale_m:.3g} m, from MDS-MAP"]
                                  + (limit if not huber.converged else []),
                                  {**base, "f_scale_m": f_scale_m, "evaluations": huber.evaluations,
                                   "status": huber.status}))
    if "lsq-drop" in names:
        long = huber.residuals_m > drop_threshold_m
        kept = links.subset(~long)
        dropped = [{"from": a, "to": b, "residual_m": round(float(r), 6)}
                   for (a, b), r, d in zip(links.pairs, huber.residuals_m, long) if d]
        degrees = kept.degrees()
        weak = sorted(i for i in main if degrees.get(i, 0) < 2)
        notes = common + [f"{len(dropped)} link(s) dropped (read > {drop_threshold_m:g} m long), "
                          f"re-solved {'by plain LS' if resolve_loss == 'linear' else 'with ' + resolve_loss} "
                          f"from the Huber solution"]
        if weak:
            notes.append(f"node(s) {weak} left with fewer than 2 links: not fixed by the ranges")
        if not huber.converged:
            notes.append(f"started from a Huber solution that {limit[0]}")
        if kept.pairs:
            start = huber.positions_m
            solution = solve_lsq(kept, start, resolve_loss, f_scale_m)
            positions = {**start, **solution.positions_m}      # a node with no link left stays put
            evaluations, status = solution.evaluations, solution.status
            if not solution.converged:
                notes += limit
        else:
            positions, evaluations, status = dict(huber.positions_m), 0, 0
        out.append(BaselineResult("lsq-drop", positions, notes,
                                  {**base, "links": len(kept.pairs), "ranges": int(kept.counts.sum()),
                                   "dropped_links": dropped, "drop_threshold_m": drop_threshold_m,
                                   "resolve_loss": resolve_loss, "evaluations": evaluations, "status": status}))
    return out
