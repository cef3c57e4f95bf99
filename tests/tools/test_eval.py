"""cdro-eval: alignment, the Cramer-Rao bound, the baselines, convergence from traces, the
CLI end to end on simulated networks, and what it does with bad input."""
import json
import math
import subprocess
import sys

import numpy as np
import pytest

from cdro_tools import evaluation as ev

GUARD_S = 60                                # a hung subprocess fails the test instead of hanging it


def run_eval(*args):
    return subprocess.run([sys.executable, "-m", "cdro_tools.eval", *map(str, args)], capture_output=True, text=True,
                          timeout=GUARD_S)


def run_sim(*args):
    subprocess.run([sys.executable, "-m", "cdro_tools.sim", *map(str, args)], check=True, capture_output=True,
                   timeout=GUARD_S)


def rigid_motion(rng, reflect=True):
    """(Q, t): a random rotation, with a reflection, and a shift of tens of metres."""
    angle = rng.uniform(-math.pi, math.pi)
    q = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    if reflect:
        q = q @ np.diag([1.0, -1.0])
    return q, rng.uniform(-50, 50, size=2)


def non_rigid_perturbation(points, rng, std_m):
    """Gaussian errors with their rigid part taken out (zero mean, no net rotation about the
    centroid), so that the best rigid fit of points + e to points is the identity and the
    aligned error of node i is exactly |e_i|."""
    e = rng.normal(0.0, std_m, size=points.shape)
    e -= e.mean(axis=0)
    centred = points - points.mean(axis=0)
    turn = np.column_stack([-centred[:, 1], centred[:, 0]])          # the direction of a small rotation
    cross = centred[:, 0] * e[:, 1] - centred[:, 1] * e[:, 0]
    e -= cross.sum() / (centred ** 2).sum() * turn
    return e


def read_truth_csv(path):
    rows = [line.split(",") for line in path.read_text().splitlines()[1:]]
    return {int(r[0]): np.array([float(r[1]), float(r[2])]) for r in rows}


def write_estimates(path, positions, covariances=None, converged=None):
    lines = ["id,x,y,var_x,cov_xy,var_y,converged"]
    for i, p in sorted(positions.items()):
        c = covariances[i] if covariances else np.diag([0.01, 0.02])
        flag = 1 if converged is None or i in converged else 0
        values = ",".join(repr(float(v)) for v in (p[0], p[1], c[0, 0], c[0, 1], c[1, 1]))
        lines.append(f"{i},{values},{flag}")
    path.write_text("\n".join(lines) + "\n")


def write_ranges(path, rows, with_t=True):
    header = "t,from,to,range_m" if with_t else "from,to,range_m"
    body = [(f"{k * 0.05:.3f}," if with_t else "") + f"{a},{b},{float(r)!r}" for k, (a, b, r) in enumerate(rows)]
    path.write_text("\n".join([header, *body]) + "\n")


def assert_png(path, width, height):
    import matplotlib.image
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    image = matplotlib.image.imread(path)
    assert image.shape[:2] == (height, width)
    assert (image[..., :3] < 0.9).any(axis=2).mean() > 0.005          # not blank


# ----------------------------------------------------------------------------- alignment

def test_that_a_moved_and_perturbed_truth_aligns_back_to_the_perturbation():
    # Fixture
    seed = 41
    print(f"seed {seed}")
    rng = np.random.default_rng(seed)
    truth = rng.uniform(0, 30, size=(12, 2))
    e = non_rigid_perturbation(truth, rng, 0.3)
    q, t = rigid_motion(rng)
    engine = (truth + e) @ q.T + t
    ids = list(range(100, 112))

    # Test
    alignment = ev.align(dict(zip(ids, engine)), dict(zip(ids, truth)))

    # Assert: the motion is undone, the error left is the perturbation's, node by node
    assert alignment.reflected and alignment.nodes == 12
    assert np.allclose(alignment.rotation, q.T, atol=1e-12)
    assert alignment.rmse_m == pytest.approx(math.sqrt((e ** 2).sum(axis=1).mean()), abs=1e-9)
    for i, err in zip(ids, np.linalg.norm(e, axis=1)):
        assert alignment.errors_m[i] == pytest.approx(err, abs=1e-9)


def test_that_the_alignment_turns_covariances_into_the_truth_frame():
    seed = 42
    print(f"seed {seed}")
    rng = np.random.default_rng(seed)
    truth = rng.uniform(0, 10, size=(5, 2))
    q, t = rigid_motion(rng)
    alignment = ev.align(dict(enumerate(truth @ q.T + t)), dict(enumerate(truth)))
    # long along truth's x, in the engine's frame: Q C Q^T
    along_x = np.diag([0.04, 0.01])
    assert np.allclose(alignment.rotate_covariance(q @ along_x @ q.T), along_x, atol=1e-12)
    assert alignment.rmse_m == pytest.approx(0.0, abs=1e-9)


def test_that_the_rigid_fit_takes_no_scale():
    # a map 10 % too large keeps an error that no rigid motion removes
    square = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
    alignment = ev.align(dict(enumerate(square * 1.1)), dict(enumerate(square)))
    assert alignment.rmse_m == pytest.approx(math.sqrt(50.0) * 0.1, abs=1e-9)   # each corner 0.1 x 7.07 m off


# ----------------------------------------------------------------------------- Cramer-Rao bound

def test_that_least_squares_on_gaussian_ranges_reaches_the_crb():
    # Fixture: 8 nodes, every pair ranged once with N(0, sigma^2); plain least squares is the
    # efficient estimator at this noise, so its aligned MSE over many draws is tr(J^+)/M
    seed = 43
    print(f"seed {seed}")
    rng = np.random.default_rng(seed)
    truth = dict(enumerate(rng.uniform(0, 20, size=(8, 2))))
    sigma_m = 0.05
    pairs = [(a, b) for a in truth for b in truth if a < b]
    bound = ev.anchor_free_crb(truth, pairs, sigma_m)
    trials = 200
    squared = []
    for _ in range(trials):
        exact = np.array([np.linalg.norm(truth[a] - truth[b]) for a, b in pairs])
        measured = exact + rng.normal(0, sigma_m, len(pairs))
        links = ev.Links(pairs, measured, np.ones(len(pairs), dtype=np.int64))
        solution = ev.solve_lsq(links, truth, loss="linear")
        squared.append(ev.align(solution.positions_m, truth).rmse_m ** 2)

    # Assert: within 20 % in MSE (the Monte Carlo mean has a relative std of about 3 % here)
    assert bound.rigid and bound.nodes == 8 and bound.entries == len(pairs)
    assert np.mean(squared) / bound.rmse_m ** 2 == pytest.approx(1.0, abs=0.2)


def test_that_the_crb_scales_with_sigma_and_the_ranges_per_link():
    seed = 44
    print(f"seed {seed}")
    rng = np.random.default_rng(seed)
    truth = dict(enumerate(rng.uniform(0, 20, size=(6, 2))))
    pairs = [(a, b) for a in truth for b in truth if a < b]
    one = ev.anchor_free_crb(truth, pairs, 0.1).rmse_m
    assert ev.anchor_free_crb(truth, pairs, 0.3).rmse_m == pytest.approx(3 * one, rel=1e-9)
    assert ev.anchor_free_crb(truth, pairs * 4, 0.1).rmse_m == pytest.approx(one / 2, rel=1e-9)


def test_that_a_flexible_network_is_reported_as_not_rigid():
    # a square without diagonals can shear: one flexible direction besides the rigid motions
    square = {1: np.array([0.0, 0.0]), 2: np.array([10.0, 0.0]), 3: np.array([10.0, 10.0]), 4: np.array([0.0, 10.0])}
    sides = [(1, 2), (2, 3), (3, 4), (4, 1)]
    assert not ev.anchor_free_crb(square, sides, 0.1).rigid
    braced = ev.anchor_free_crb(square, sides + [(1, 3)], 0.1)
    assert braced.rigid and braced.rank == 5
    # an entry with an end that has no truth is left out, and counted
    assert ev.anchor_free_crb(square, sides + [(1, 3), (1, 99)], 0.1).skipped == 1


# ----------------------------------------------------------------------------- baselines

def exact_links(truth, pairs, counts=1):
    return ev.Links(sorted(pairs), np.array([np.linalg.norm(truth[a] - truth[b]) for a, b in sorted(pairs)]),
                    np.full(len(pairs), counts, dtype=np.int64))


def test_that_exact_ranges_give_exact_maps():
    seed = 45
    print(f"seed {seed}")
    rng = np.random.default_rng(seed)
    truth = dict(enumerate(rng.uniform(0, 30, size=(10, 2))))
    everything = [(a, b) for a in truth for b in truth if a < b]
    # complete graph: the distance matrix is exact, classical MDS recovers the shape
    mds = ev.mds_map(exact_links(truth, everything))
    assert ev.align(mds, truth).rmse_m == pytest.approx(0.0, abs=1e-9)
    # a multi-hop graph (links up to 15 m): shortest paths are longer than the straight
    # lines, MDS-MAP is off, least squares from it repairs the map
    near = [(a, b) for a, b in everything if np.linalg.norm(truth[a] - truth[b]) < 15.0]
    links = exact_links(truth, near)
    assert len(ev.components(links)) == 1 and len(near) < len(everything)
    results = {r.name: r for r in ev.run_baselines(links, ["mds", "lsq-huber", "lsq-drop"], f_scale_m=0.13)}
    assert ev.align(results["mds"].positions_m, truth).rmse_m > 0.05
    assert ev.align(results["lsq-huber"].positions_m, truth).rmse_m == pytest.approx(0.0, abs=1e-6)
    assert results["lsq-drop"].details["dropped_links"] == []


def test_that_drop_and_resolve_removes_the_link_that_reads_long():
    # Fixture: exact ranges on a well-braced network, but one link reads 2 m long (NLOS)
    seed = 46
    print(f"seed {seed}")
    rng = np.random.default_rng(seed)
    truth = dict(enumerate(rng.uniform(0, 20, size=(9, 2))))
    links = exact_links(truth, [(a, b) for a in truth for b in truth if a < b])
    links.range_m[5] += 2.0

    # Test
    results = {r.name: r for r in ev.run_baselines(links, ["lsq-huber", "lsq-drop"], f_scale_m=0.13)}

    # Assert: Huber leaves an error, dropping the link removes it
    dropped = results["lsq-drop"].details["dropped_links"]
    assert [(d["from"], d["to"]) for d in dropped] == [links.pairs[5]] and dropped[0]["residual_m"] > 1.0
    assert ev.align(results["lsq-huber"].positions_m, truth).rmse_m > 1e-3
    assert ev.align(results["lsq-drop"].positions_m, truth).rmse_m == pytest.approx(0.0, abs=1e-6)
    assert results["lsq-drop"].details["links"] == len(links.pairs) - 1


def test_that_drop_and_resolve_keeps_a_link_that_reads_short():
    # NLOS reads long, never short: a short link is noise to average, not a link to drop
    seed = 48
    print(f"seed {seed}")
    rng = np.random.default_rng(seed)
    truth = dict(enumerate(rng.uniform(0, 20, size=(9, 2))))
    links = exact_links(truth, [(a, b) for a in truth for b in truth if a < b])
    links.range_m[5] -= 1.5
    results = {r.name: r for r in ev.run_baselines(links, ["lsq-huber", "lsq-drop"], f_scale_m=0.13)}
    huber_residuals = ev.solve_lsq(links, results["lsq-huber"].positions_m, "huber", 0.13).residuals_m
    assert huber_residuals[5] < -0.6
    assert results["lsq-drop"].details["dropped_links"] == []


def test_that_a_solve_cut_short_by_the_evaluation_limit_says_so(monkeypatch):
    from cdro_tools.evaluation import baselines
    monkeypatch.setattr(baselines, "MAX_EVALUATIONS", 2)
    seed = 49
    print(f"seed {seed}")
    rng = np.random.default_rng(seed)
    truth = dict(enumerate(rng.uniform(0, 30, size=(10, 2))))
    near = [(a, b) for a in truth for b in truth if a < b and np.linalg.norm(truth[a] - truth[b]) < 15.0]
    results = {r.name: r for r in ev.run_baselines(exact_links(truth, near), ["lsq-huber", "lsq-drop"], 0.13)}
    assert results["lsq-huber"].details["status"] == 0
    assert any("limit of 2 evaluations: not converged" in note for note in results["lsq-huber"].notes)
    assert any("started from a Huber solution that stopped" in note for note in results["lsq-drop"].notes)


def test_that_a_group_of_nodes_without_links_to_the_rest_is_not_solved():
    square = {1: np.array([0.0, 0.0]), 2: np.array([10.0, 0.0]), 3: np.array([10.0, 10.0]), 4: np.array([0.0, 10.0]),
              7: np.array([50.0, 50.0]), 8: np.array([55.0, 50.0])}
    links = exact_links(square, [(1, 2), (2, 3), (3, 4), (1, 4), (1, 3), (2, 4), (7, 8)])
    (mds,) = ev.run_baselines(links, ["mds"], f_scale_m=0.13)
    assert sorted(mds.positions_m) == [1, 2, 3, 4] and mds.details["nodes_not_solved"] == [7, 8]
    with pytest.raises(ev.BaselineError, match="at least 3"):
        ev.run_baselines(exact_links(square, [(7, 8)]), ["mds"], f_scale_m=0.13)


# ----------------------------------------------------------------------------- inputs

def test_that_known_heights_project_ranges_to_the_plane(tmp_path):
    write_ranges(tmp_path / "r.csv", [(1, 2, 5.0), (2, 3, 1.0), (1, 3, 4.0), (1, 9, 2.0)], with_t=False)
    bad = []
    ranges = ev.read_ranges(str(tmp_path / "r.csv"), bad)
    projection = ev.project_ranges(ranges, {1: 0.0, 2: 3.0, 3: 1.0})
    assert projection.ranges.range_m.tolist() == pytest.approx([4.0, 0.0, math.sqrt(15.0), 2.0])
    assert (projection.projected, projection.clamped, projection.without_height) == (3, 1, 1)
    assert projection.nodes_without_height == [9] and bad == []


# ----------------------------------------------------------------------------- traces

def snapshot(positions, converged):
    return {i: ev.NodeEstimate(np.asarray(p, dtype=float), np.eye(2) * 0.01, i in converged)
            for i, p in positions.items()}


def test_that_a_node_converges_when_it_stays_converged():
    xy = {1: (0, 0), 2: (10, 0), 3: (0, 10), 4: (10, 10)}
    snapshots = [(10, snapshot({i: xy[i] for i in (1, 2, 3)}, {1})),
                 (20, snapshot(xy, {1, 2})),
                 (30, snapshot(xy, {1, 3})),            # 2 falls back: its first convergence does not count
                 (40, snapshot(xy, {1, 2, 3})),
                 (50, snapshot({i: xy[i] for i in (1, 2, 4)}, {1, 2, 4}))]    # 3 missing: not converged there
    times = ev.convergence_ranges(snapshots)
    assert times == {1: 10, 2: 40, 3: None, 4: 50}
    assert ev.all_converged_at(times) is None
    assert ev.all_converged_at({1: 10, 2: 40}) == 40


def write_trace(path, snapshots):
    lines = ["ranges,id,x,y,var_x,cov_xy,var_y,converged"]
    for count, positions, converged in snapshots:
        for i, p in sorted(positions.items()):
            lines.append(f"{count},{i},{float(p[0])!r},{float(p[1])!r},0.01,0.0,0.01,{int(i in converged)}")
    path.write_text("\n".join(lines) + "\n")


# ----------------------------------------------------------------------------- the CLI end to end

def test_that_cdro_eval_scores_a_simulated_network_end_to_end(tmp_path):
    # Fixture: the paper's Fig. 3 network from cdro-sim; engine estimates made of the truth
    # plus a seeded non-rigid error, moved by a random rigid motion with a reflection; two
    # traces whose errors shrink over the ranges, each snapshot in its own random frame
    seed = 47
    print(f"seed {seed}")
    rng = np.random.default_rng(seed)
    run_sim("--scenario", "paper-fig3", "--seed", 1, "--ranges-csv", tmp_path / "ranges.csv", "--truth-csv",
            tmp_path / "truth.csv")
    truth = read_truth_csv(tmp_path / "truth.csv")
    ids = sorted(truth)
    points = np.array([truth[i] for i in ids])
    e = non_rigid_perturbation(points, rng, 0.4)
    q, t = rigid_motion(rng)
    engine = dict(zip(ids, (points + e) @ q.T + t))
    covariances = {i: q @ np.diag([0.09, 0.01]) @ q.T for i in ids}
    write_estimates(tmp_path / "est.csv", engine, covariances, converged=set(ids[:4]))
    expected_rmse = math.sqrt((e ** 2).sum(axis=1).mean())
    traces = {}
    for name, shrink in (("wt", 0.5), ("no-wt", 0.8)):
        snapshots, expected = [], []
        for k, count in enumerate(range(100, 1100, 100)):
            factor = shrink ** k
            qk, tk = rigid_motion(rng)
            moved = dict(zip(ids, (points + factor * e) @ qk.T + tk))
            converged = set(ids) if count >= 500 else {ids[0]}
            if name == "wt" and count == 700:
                converged -= {ids[1]}                                   # falls back once: converged at 800
            if name == "no-wt":
                converged -= {ids[2]}                                   # never converges
            snapshots.append((count, moved, converged))
            expected.append(factor * expected_rmse)
        write_trace(tmp_path / f"{name}.csv", snapshots)
        traces[name] = expected

    # Test
    result = run_eval("--truth", tmp_path / "truth.csv", "--ranges", tmp_path / "ranges.csv", "--estimates",
                      tmp_path / "est.csv", "--sigma-m", 0.7, "--trace", tmp_path / "wt.csv", "--label", "with WT",
                      "--trace", tmp_path / "no-wt.csv", "--label", "without WT", "--rmse-png", tmp_path / "rmse.png",
                      "--map-png", tmp_path / "map.png", "--map-baselines", "--json", tmp_path / "eval.json")

    # Assert
    assert result.returncode == 0, result.stderr
    report = json.loads((tmp_path / "eval.json").read_text())
    engine_report = report["methods"]["engine"]
    assert engine_report["rmse_m"] == pytest.approx(expected_rmse, abs=1e-9)
    assert engine_report["reflected"] is True and engine_report["nodes"] == 5 and engine_report["converged"] == 4
    for item, err in zip(engine_report["per_node"], np.linalg.norm(e, axis=1)):
        assert item["error_m"] == pytest.approx(err, abs=1e-9)
    # the baselines solve this easy network (all pairs, ~290 ranges a link) to centimetres
    for name in ("mds", "lsq-huber", "lsq-drop"):
        assert report["methods"][name]["nodes"] == 5 and report["methods"][name]["rmse_m"] < 0.2, name
    # every link has ~1/10 of the ranges: one entry per range bounds sqrt(ranges per link) lower
    ranges = report["ranges"]
    assert ranges["used"] == ranges["rows"] > 1000 and ranges["links"] == 10 and ranges["projected"] == 0
    per_link = run_eval("--truth", tmp_path / "truth.csv", "--ranges", tmp_path / "ranges.csv", "--sigma-m", 0.7,
                        "--baselines", "crb", "--crb-per-link", "--json", "-")
    assert per_link.returncode == 0, per_link.stderr
    crb_link = json.loads(per_link.stdout)["crb"]
    assert crb_link["per"] == "link" and crb_link["entries"] == 10 and report["crb"]["entries"] == ranges["used"]
    assert report["crb"]["rmse_m"] == pytest.approx(crb_link["rmse_m"] / math.sqrt(ranges["used"] / 10), rel=0.01)
    assert "method" in per_link.stderr and "CRB" in per_link.stderr              # the table moved to stderr
    # convergence in ranges, and the RMSE of every snapshot in its own frame
    with_wt, without_wt = report["convergence"]
    assert with_wt["label"] == "with WT" and with_wt["all_converged_at_ranges"] == 800
    assert {n["id"]: n["converged_at_ranges"] for n in with_wt["nodes"]} == {
        ids[0]: 100, ids[1]: 800, ids[2]: 500, ids[3]: 500, ids[4]: 500}
    assert without_wt["all_converged_at_ranges"] is None and without_wt["never_converged"] == [ids[2]]
    for trace, name in ((with_wt, "wt"), (without_wt, "no-wt")):
        assert [p["ranges"] for p in trace["rmse_over_ranges"]] == list(range(100, 1100, 100))
        assert [p["rmse_m"] for p in trace["rmse_over_ranges"]] == pytest.approx(traces[name], abs=1e-9)
    assert "never" in result.stdout and "with WT" in result.stdout
    assert_png(tmp_path / "map.png", 800, 700)
    assert_png(tmp_path / "rmse.png", 800, 400)


def test_that_known_heights_make_the_ranges_planar(tmp_path):
    # Fixture: a random network with heights 0-3 m and 5 cm noise: unprojected, the 3D
    # ranges are too long for the plane and the map cannot fit them
    run_sim("--random-network", 12, "--degree", 7, "--noise-m", 0.05, "--height-range-m", 0, 3, "--seed", 5,
            "--ranges-csv", tmp_path / "ranges.csv", "--truth-csv", tmp_path / "truth.csv", "--heights-csv",
            tmp_path / "heights.csv")
    common = ["--truth", tmp_path / "truth.csv", "--ranges", tmp_path / "ranges.csv", "--sigma-m", 0.05,
              "--baselines", "lsq-huber", "--json", "-"]

    # Test
    reports = {}
    for name, extra in (("truth", ["--heights-from-truth"]), ("csv", ["--heights-csv", tmp_path / "heights.csv"]),
                        ("none", [])):
        result = run_eval(*common, *extra)
        assert result.returncode == 0, result.stderr
        reports[name] = json.loads(result.stdout)

    # Assert
    rows = reports["truth"]["ranges"]["rows"]
    assert reports["truth"]["ranges"]["projected"] == rows and reports["none"]["ranges"]["projected"] == 0
    assert reports["truth"]["inputs"]["heights"] == "truth"
    projected = reports["truth"]["methods"]["lsq-huber"]["rmse_m"]
    assert reports["csv"]["methods"]["lsq-huber"]["rmse_m"] == pytest.approx(projected, abs=1e-4)   # z to 1 mm
    assert projected < 0.1 < reports["none"]["methods"]["lsq-huber"]["rmse_m"]


def test_that_bad_rows_are_reported_by_line_and_skipped(tmp_path):
    # Fixture: a square with diagonals, exact ranges, then five bad rows
    square = {1: (0.0, 0.0), 2: (10.0, 0.0), 3: (10.0, 10.0), 4: (0.0, 10.0)}
    (tmp_path / "truth.csv").write_text("id,x,y\n" + "".join(f"{i},{x},{y}\n" for i, (x, y) in square.items()))
    rows = [(a, b, math.dist(square[a], square[b])) for a in square for b in square if a < b]
    lines = ["from,to,range_m"] + [f"{a},{b},{r!r}" for a, b, r in rows]
    lines[3:3] = ["1,2,abc", "2,3,-0.5", "3,3,1.0", "x,1,2.0", "1,2,nan"]    # lines 4-8 of the file
    (tmp_path / "ranges.csv").write_text("\n".join(lines) + "\n")
    (tmp_path / "est.csv").write_text("id,x,y,var_x,cov_xy,var_y,converged\n1,0,0,0.01,0,0.01,1\n2,10,0,0.01,0,0.01,2\n"
                                      "3,10,10,-1,0,0.01,1\n4,0,10,0.01,0,0.01,1\n2,10,0,0.01,0,0.01,1\n"
                                      "3,10,10,0.01,0,0.01,0\n")

    # Test
    result = run_eval("--truth", tmp_path / "truth.csv", "--ranges", tmp_path / "ranges.csv", "--estimates",
                      tmp_path / "est.csv", "--baselines", "lsq-huber", "--json", tmp_path / "eval.json")

    # Assert
    assert result.returncode == 0, result.stderr
    report = json.loads((tmp_path / "eval.json").read_text())
    ranges_csv = str(tmp_path / "ranges.csv")
    est_csv = str(tmp_path / "est.csv")
    reasons = {(b["file"], b["line"]): b["reason"] for b in report["bad_rows"]["rows"]}
    assert reasons == {
        (ranges_csv, 4): "range_m 'abc' is not a finite number",
        (ranges_csv, 5): "negative range -0.5 m",
        (ranges_csv, 6): "node 3 ranging itself",
        (ranges_csv, 7): "from 'x' is not a node id (1..65535, decimal or 0x hex; 0 is not a node on the live link "
                         "either)",
        (ranges_csv, 8): "range_m 'nan' is not a finite number",
        (est_csv, 3): "converged must be 0 or 1",
        (est_csv, 4): "negative variance (var_x -1, var_y 0.01 m^2)",
    }
    assert report["bad_rows"]["count"] == 7
    assert report["ranges"] == {**report["ranges"], "rows": 11, "used": 6, "bad_rows": 5, "links": 6}
    assert f"{ranges_csv}:5: negative range -0.5 m: row skipped" in result.stderr
    assert f"{ranges_csv}: 5 bad row(s) skipped" in result.stderr
    # the good rows still make the figures: the later rows of nodes 2 and 3 are taken
    engine = report["methods"]["engine"]
    assert engine["nodes"] == 4 and engine["rmse_m"] == pytest.approx(0.0, abs=1e-9) and engine["converged"] == 3
    assert report["methods"]["lsq-huber"]["rmse_m"] == pytest.approx(0.0, abs=1e-6)


def test_that_a_node_the_engine_has_not_placed_is_reported_as_such_not_as_a_bad_row(tmp_path):
    # Fixture: cdro-hostd's --out-csv writes an empty row for a node it has ranges of but has not
    # placed; node 4 here. Node 5's row is damaged (x empty, y given): that one is a bad row.
    square = {1: (0.0, 0.0), 2: (10.0, 0.0), 3: (10.0, 10.0), 4: (0.0, 10.0)}
    (tmp_path / "truth.csv").write_text("id,x,y\n" + "".join(f"{i},{x},{y}\n" for i, (x, y) in square.items()))
    (tmp_path / "est.csv").write_text("id,x,y,var_x,cov_xy,var_y,converged\n1,0,0,0.01,0,0.01,1\n"
                                      "2,10,0,0.01,0,0.01,1\n3,10,10,0.01,0,0.01,1\n4,,,,,,0\n5,,3,0.01,0,0.01,0\n")

    # Test
    result = run_eval("--truth", tmp_path / "truth.csv", "--estimates", tmp_path / "est.csv", "--no-baselines",
                      "--json", tmp_path / "eval.json")

    # Assert
    assert result.returncode == 0, result.stderr
    report = json.loads((tmp_path / "eval.json").read_text())
    engine = report["methods"]["engine"]
    assert engine["unplaced"] == [4]
    assert engine["nodes"] == 3 and engine["rmse_m"] == pytest.approx(0.0, abs=1e-9)
    assert "1 not placed (4)" in engine["notes"]
    reasons = {b["line"]: b["reason"] for b in report["bad_rows"]["rows"]}
    assert reasons == {6: "x '' is not a finite number"}
    assert "1 not placed (4)" in result.stdout


def test_that_unusable_input_is_a_clear_error(tmp_path):
    (tmp_path / "truth.csv").write_text("id,x,y,z\n1,0,0,0\n2,10,0,0\n3,0,10,0\n")
    (tmp_path / "flat.csv").write_text("id,x,y\n1,0,0\n2,10,0\n3,0,10\n")
    (tmp_path / "ranges.csv").write_text("from,to,range_m\n1,2,10\n2,3,14.14\n1,3,10\n")
    (tmp_path / "no-range.csv").write_text("from,to,distance\n1,2,10\n")
    (tmp_path / "other-ids.csv").write_text("id,x,y,var_x,cov_xy,var_y,converged\n24577,0,0,0.01,0,0.01,1\n")
    truth, ranges = tmp_path / "truth.csv", tmp_path / "ranges.csv"
    for args, message in (
            (["--truth", tmp_path / "missing.csv", "--ranges", ranges],
             "missing.csv: cannot open the file (No such file"),
            (["--truth", truth, "--ranges", tmp_path / "no-range.csv"],
             "no-range.csv:1: the header has no column 'range_m'"),
            (["--truth", tmp_path / "flat.csv", "--ranges", ranges, "--heights-from-truth"], "has no z column"),
            (["--truth", truth, "--estimates", tmp_path / "other-ids.csv"], "none of its ids is in"),
            (["--truth", truth, "--ranges", ranges, "--rmse-png", tmp_path / "r.png"], "--rmse-png needs"),
            (["--truth", truth, "--trace", ranges, "--label", "a", "--label", "b"], "one label per trace"),
            (["--truth", truth, "--ranges", ranges, "--baselines", "mds,magic"], "unknown baseline(s) magic"),
            (["--truth", truth, "--estimates", tmp_path / "other-ids.csv", "--baselines", "mds"], "--baselines needs"),
            (["--truth", truth, "--ranges", ranges, "--sigma-m", "0"], "must be above 0"),
            (["--truth", truth, "--ranges", ranges, "--json", tmp_path / "no-dir" / "e.json"], "no such directory"),
            (["--truth", truth], "nothing to evaluate"),
            (["--truth", truth, "--trace", ranges], "ranges.csv:1: the header has no column 'ranges'")):
        result = run_eval(*args)
        assert result.returncode == 2 and message in result.stderr, (args, result.stderr)
    help_text = run_eval("--help").stdout
    assert "examples:" in help_text and "cdro-eval --truth" in help_text


def test_that_converged_nodes_are_judged_on_their_own_wrong_ones_named_and_ellipses_checked(tmp_path):
    # Fixture: five converged nodes fitted on their own; node 5 is 2 m off (wrong, sigma 0.1 m),
    # nodes 1-4 are 0.1 m off and carry the fit's share of node 5's error, within their 2-sigma
    # ellipses (sigma 0.3 m); node 6 is far off but not converged, so it must not count.
    truth = {1: (0.0, 0.0), 2: (10.0, 0.0), 3: (10.0, 10.0), 4: (0.0, 10.0), 5: (5.0, 5.0), 6: (5.0, 20.0)}
    (tmp_path / "truth.csv").write_text("id,x,y\n" + "".join(f"{i},{x},{y}\n" for i, (x, y) in truth.items()))
    estimates = {i: np.array(p) + np.array([0.1, 0.0]) * (1 if i % 2 else -1) for i, p in truth.items()}
    estimates[5] = np.array([7.0, 5.0])
    estimates[6] = np.array([25.0, 20.0])
    covariances = {i: np.diag([0.09, 0.09]) for i in truth}
    covariances[5] = np.diag([0.01, 0.01])
    write_estimates(tmp_path / "est.csv", estimates, covariances, converged={1, 2, 3, 4, 5})

    # Test
    result = run_eval("--truth", tmp_path / "truth.csv", "--estimates", tmp_path / "est.csv", "--no-baselines",
                      "--json", tmp_path / "eval.json")

    # Assert
    assert result.returncode == 0, result.stderr
    engine = json.loads((tmp_path / "eval.json").read_text())["methods"]["engine"]
    assert engine["converged"] == 5
    assert engine["converged_wrong"] == [5]
    assert engine["ellipse_coverage"] == pytest.approx(0.8)
    assert engine["nees"] > 2.0
    assert "1 converged > 1 m off" in result.stdout


def test_that_a_reader_that_stops_early_gets_no_traceback_and_the_files_are_written(tmp_path):
    # cdro-eval ... | head: the pipe closes while the table is printed.
    truth = {i: (float(i), float(i * i % 7)) for i in range(1, 60)}
    (tmp_path / "truth.csv").write_text("id,x,y\n" + "".join(f"{i},{x},{y}\n" for i, (x, y) in truth.items()))
    write_estimates(tmp_path / "est.csv", {i: np.array(p) for i, p in truth.items()})
    process = subprocess.Popen([sys.executable, "-m", "cdro_tools.eval", "--truth", str(tmp_path / "truth.csv"),
                                "--estimates", str(tmp_path / "est.csv"), "--no-baselines", "--json",
                                str(tmp_path / "eval.json")], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    process.stdout.readline()
    process.stdout.close()
    _, stderr = process.communicate(timeout=GUARD_S)
    assert "Traceback" not in stderr.decode(), stderr.decode()
    assert process.returncode == 0
    assert json.loads((tmp_path / "eval.json").read_text())["methods"]["engine"]["nodes"] == 59
