"""cdro-plot's views that need no truth: per-link residuals (median range minus the distance on
the map, computed here again from the inputs) and convergence over time (2-sigma radius per
node, converged nodes), from JSON Lines and from the engine's trace."""
import json
import math
import statistics
import subprocess
import sys

import numpy as np
import pytest

GUARD_S = 60
# Estimates in some frame of the engine's (residuals do not depend on it).
NODES = {0x6001: (0.0, 0.0), 0x6002: (6.0, 0.0), 0x6003: (6.0, 4.0), 0x6004: (0.0, 4.0)}
HEIGHTS = {0x6001: 1.0, 0x6002: 2.5, 0x6003: 1.0, 0x6004: 1.0}
NLOS_LINK = (0x6002, 0x6004)                  # reads 1.2 m long
OFF_LINK = (0x6001, 0x6003)                   # reads 0.3 m short
RED = np.array([0xB5, 0x2B, 0x27]) / 255      # the bad band's colour


def plot(*args):
    return subprocess.run([sys.executable, "-m", "cdro_tools.plot", *map(str, args)], capture_output=True, text=True,
                          timeout=GUARD_S)


def write_nodes_csv(path, nodes):
    path.write_text("id,x,y,var_x,cov_xy,var_y,converged\n"
                    + "".join(f"{i},{x},{y},0.01,0,0.01,1\n" for i, (x, y) in nodes.items()))


def write_ranges(path, nlos_extra_m):
    """Every pair, 5 ranges each way: the 3D distance with a spread, the two odd links off."""
    rows, rng = [], np.random.default_rng(7)
    ids = sorted(NODES)
    t = 0.0
    for k, a in enumerate(ids):
        for b in ids[k + 1:]:
            flat = math.dist(NODES[a], NODES[b])
            true_3d = math.hypot(flat, HEIGHTS[a] - HEIGHTS[b])
            extra = nlos_extra_m if (a, b) == NLOS_LINK else -0.3 if (a, b) == OFF_LINK else 0.0
            for j in range(10):
                t += 0.1
                src, dst = (a, b) if j % 2 else (b, a)
                rows.append(f"{t:.1f},{src},{dst},{true_3d + extra + rng.normal(0, 0.03):.4f}\n")
    rows.append(f"{t + 0.1:.1f},{0x6001},{0x6009},3.0\n")     # a node without an estimate
    path.write_text("t,from,to,range_m\n" + "".join(rows))


def expected_residuals(ranges_path, heights):
    """The test's own computation: per link, the median of the ranges projected to the plane."""
    links = {}
    for line in ranges_path.read_text().splitlines()[1:]:
        _, a, b, r = line.split(",")
        a, b, r = int(a), int(b), float(r)
        if a in heights and b in heights:
            r = math.sqrt(max(r * r - (heights[a] - heights[b]) ** 2, 0.0))
        links.setdefault((min(a, b), max(a, b)), []).append(r)
    return {k: statistics.median(v) - math.dist(NODES[k[0]], NODES[k[1]]) for k, v in links.items()
            if k[0] in NODES and k[1] in NODES}


def red_fraction(path):
    import matplotlib.image
    image = matplotlib.image.imread(path)[..., :3]
    return float((np.abs(image - RED) < 0.06).all(axis=2).mean())


def test_link_residuals_are_the_median_range_minus_the_distance_on_the_map(tmp_path):
    # Fixture
    write_nodes_csv(tmp_path / "nodes.csv", NODES)
    write_ranges(tmp_path / "ranges.csv", nlos_extra_m=1.2)
    (tmp_path / "heights.csv").write_text("id,z\n" + "".join(f"{i},{z}\n" for i, z in HEIGHTS.items()))

    # Test
    result = plot(tmp_path / "nodes.csv", "--ranges", tmp_path / "ranges.csv", "--heights", tmp_path / "heights.csv",
                  "--residuals", tmp_path / "residuals.png")

    # Assert
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout)
    expected = expected_residuals(tmp_path / "ranges.csv", HEIGHTS)
    got = {(r["a"], r["b"]): r for r in out["link_residuals"]}
    assert set(got) == set(expected) and len(got) == 6
    for link, residual in expected.items():
        assert got[link]["residual_m"] == pytest.approx(residual, abs=2e-6)
        assert got[link]["ranges"] == 10
    assert [(r["a"], r["b"]) for r in out["link_residuals"]][:2] == [NLOS_LINK, OFF_LINK]   # largest first
    assert got[NLOS_LINK]["band"] == "bad" and got[OFF_LINK]["band"] == "warn"
    assert all(got[k]["band"] == "ok" for k in got if k not in (NLOS_LINK, OFF_LINK))
    assert "1 link(s) without an estimate at one end" in result.stderr
    assert red_fraction(tmp_path / "residuals.png") > 0.001                       # the NLOS link drawn red

    # Without the heights the 2.5 m node's links read long by the height difference.
    flat = plot(tmp_path / "nodes.csv", "--ranges", tmp_path / "ranges.csv", "--residuals", tmp_path / "flat.png")
    assert flat.returncode == 0, flat.stderr
    flat_got = {(r["a"], r["b"]): r["residual_m"] for r in json.loads(flat.stdout)["link_residuals"]}
    for link, residual in expected_residuals(tmp_path / "ranges.csv", {}).items():
        assert flat_got[link] == pytest.approx(residual, abs=2e-6)
    assert flat_got[(0x6001, 0x6002)] > got[(0x6001, 0x6002)]["residual_m"] + 0.1


def test_a_map_without_an_nlos_link_has_nothing_red(tmp_path):
    write_nodes_csv(tmp_path / "nodes.csv", NODES)
    write_ranges(tmp_path / "ranges.csv", nlos_extra_m=0.0)
    (tmp_path / "heights.csv").write_text("id,z\n" + "".join(f"{i},{z}\n" for i, z in HEIGHTS.items()))
    result = plot(tmp_path / "nodes.csv", "--ranges", tmp_path / "ranges.csv", "--heights", tmp_path / "heights.csv",
                  "--residuals", tmp_path / "residuals.png")
    assert result.returncode == 0, result.stderr
    assert all(r["band"] != "bad" for r in json.loads(result.stdout)["link_residuals"])
    assert red_fraction(tmp_path / "residuals.png") < 0.0002


def node_line(t, node_id, var, converged, placed=True):
    return json.dumps({"type": "node", "t_s": t, "id": node_id,
                       "x_m": 1.0 if placed else None, "y_m": 2.0 if placed else None,
                       "var_x_m2": var if placed else None, "cov_xy_m2": 0.0 if placed else None,
                       "var_y_m2": var / 4 if placed else None, "converged": converged, "moving": False,
                       "placed": placed})


def test_convergence_from_json_lines_counts_converged_nodes_over_time(tmp_path):
    # Fixture: node k's variance shrinks from t = k on; it converges at t = 2 + k; node 3 never
    lines = []
    for step in range(20):
        t = step * 0.5
        for k in range(4):
            var = 1.0 / (1.0 + max(0.0, t - k) * 4)
            lines.append(node_line(t, 0x6001 + k, var, k < 3 and t >= 2 + k))
    lines.append(node_line(0.0, 0x6009, 0.0, False, placed=False))
    lines.append(json.dumps({"type": "health", "t_s": 1.0, "link": "connected", "counters": {}}))
    (tmp_path / "est.jsonl").write_text("\n".join(lines) + "\n")

    # Test
    result = plot(tmp_path / "est.jsonl", "--convergence", tmp_path / "convergence.png")

    # Assert
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout)["convergence"]
    assert out["axis"] == "t_s" and out["points"] == 20
    expected = [[step * 0.5, sum(1 for k in range(3) if step * 0.5 >= 2 + k)] for step in range(20)]
    assert out["converged_over_time"] == expected
    assert out["final_converged"] == 3
    for k in range(4):
        var = 1.0 / (1.0 + max(0.0, 9.5 - k) * 4)
        assert out["final_two_sigma_m"][f"0x{0x6001 + k:04X}"] == pytest.approx(2 * math.sqrt(var), abs=1e-6)
    assert "0x6009" not in out["final_two_sigma_m"]
    import matplotlib.image
    assert matplotlib.image.imread(tmp_path / "convergence.png").shape[:2] == (600, 800)


def test_convergence_from_a_trace_over_ranges_or_its_times(tmp_path):
    rows = ["ranges,id,x,y,var_x,cov_xy,var_y,converged,status,reason,t"]
    for ranges in (10, 20, 30):
        for node_id in (1, 2, 3):
            converged = int(ranges >= 10 * node_id)
            rows.append(f"{ranges},{node_id},0,0,{1.0 / ranges},0.0,{4.0 / ranges},{converged},x,,")
    (tmp_path / "trace.csv").write_text("\n".join(rows) + "\n")
    result = plot(tmp_path / "trace.csv", "--convergence", tmp_path / "c.png")
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout)["convergence"]
    assert out["axis"] == "ranges"
    assert out["converged_over_time"] == [[10, 1], [20, 2], [30, 3]]
    assert out["final_two_sigma_m"]["0x0001"] == pytest.approx(2 * math.sqrt(4.0 / 30), abs=1e-6)
    # With a t on every row the axis is time.
    timed = [rows[0]] + [r + f"{int(r.split(',')[0]) / 10:.1f}" for r in rows[1:]]
    (tmp_path / "timed.csv").write_text("\n".join(timed) + "\n")
    result = plot(tmp_path / "timed.csv", "--convergence", tmp_path / "t.png")
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["convergence"]["converged_over_time"] == [[1.0, 1], [2.0, 2], [3.0, 3]]


@pytest.mark.parametrize("args, message", [
    (["--residuals", "r.png"], "--residuals needs --ranges"),
    ([], "nothing to draw"),
    (["--heights", "h.csv", "--map", "m.png"], "--heights goes with --residuals"),
])
def test_wrong_options_say_what_is_missing(tmp_path, args, message):
    write_nodes_csv(tmp_path / "nodes.csv", NODES)
    result = plot(tmp_path / "nodes.csv", *[tmp_path / a if a.endswith((".png", ".csv")) else a for a in args])
    assert result.returncode == 2 and message in result.stderr


def test_convergence_needs_estimates_over_time(tmp_path):
    write_nodes_csv(tmp_path / "nodes.csv", NODES)
    result = plot(tmp_path / "nodes.csv", "--convergence", tmp_path / "c.png")
    assert result.returncode == 2 and "--convergence needs estimates over time" in result.stderr
