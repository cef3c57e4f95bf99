"""A node carried and put down again, run offline as docs/results.md measures it ("A carried node"):

    cdro-sim --scenario demo --seed S --ranges-csv ... --motion-csv M ...
    cdro-hostd --ranges-csv R --heights-csv H --motion-csv M --trace-csv T --trace-every 1
    cdro-eval-motion --trace T --tracks ... --truth ... --motion M --node 0x6006

- with the defaults, the carried node (0x6006: 5.2 m at 1.3 m/s) is converged again within
  RECONVERGED_WITHIN_S of being put down (docs/results.md: 1.5-1.7 s on seeds 1-5; the product's
  goal is 2 s), in each seeded draw;
- the global solve's adoption lag is what sets that time: adopted a whole sweep of the network
  after it started instead of a quarter, the same draw takes longer;
- without the motion reports (the fallback detector), the carry is seen from the ranges, its stop
  within STOP_SEEN_WITHIN_S (and not before it happened), and the node converges again soon after.

Seeded; CDRO_TEST_SEED replays one draw (printed)."""
import json
import subprocess
import sys

import pytest
from offline_run import GUARD_S, run, seed_of

RECONVERGED_WITHIN_S = 2.5  # s, the goal (2 s) with room for one more solve's lag
STOP_SEEN_WITHIN_S = 2.0  # s, without motion reports (the goal is 1 s; docs/results.md: 0.6-1.4 s in 10 seeds)
CARRIED = "0x6006"


def simulate(folder, seed):
    """The demo scenario's files for one seed; their paths by name."""
    paths = {name: folder / f"{name}.csv" for name in ("ranges", "truth", "heights", "tracks", "motion")}
    args = [sys.executable, "-m", "cdro_tools.sim", "--scenario", "demo", "--seed", str(seed)]
    for name, path in paths.items():
        args += [f"--{name}-csv", str(path)]
    subprocess.run(args, check=True, capture_output=True, timeout=GUARD_S)
    return paths


def reconverged_after_s(hostd, folder, paths, *settings):
    """Seconds from the carried node's stop to its first converged estimate (None: never)."""
    trace = folder / f"trace{len(settings)}.csv"
    result = run(hostd, "--ranges-csv", paths["ranges"], "--heights-csv", paths["heights"], "--motion-csv",
                 paths["motion"], "--out-csv", folder / "estimates.csv", "--trace-csv", trace, "--trace-every", "1",
                 *[arg for setting in settings for arg in ("--set", setting)])
    assert result.returncode == 0, result.stderr
    scored = subprocess.run([sys.executable, "-m", "cdro_tools.eval_motion", "--trace", str(trace), "--tracks",
                             str(paths["tracks"]), "--truth", str(paths["truth"]), "--motion", str(paths["motion"]),
                             "--node", CARRIED, "--json", "-"], capture_output=True, text=True, timeout=GUARD_S)
    assert scored.returncode == 0, scored.stderr
    return json.loads(scored.stdout)["track"]["reconverged_after_s"][0]


@pytest.mark.parametrize("default_seed", [1, 2])
def test_that_a_carried_node_is_converged_again_soon_after_it_is_put_down(hostd, tmp_path, default_seed):
    # Fixture
    seed = seed_of(default_seed)
    paths = simulate(tmp_path, seed)

    # Act
    again_s = reconverged_after_s(hostd, tmp_path, paths)
    print(f"converged again {again_s} s after the stop")

    # Assert
    assert again_s is not None and again_s <= RECONVERGED_WITHIN_S


def test_that_a_later_adoption_of_the_global_solve_reconverges_later(hostd, tmp_path):
    # Fixture
    seed = seed_of(5)
    paths = simulate(tmp_path, seed)

    # Act
    default_s = reconverged_after_s(hostd, tmp_path, paths)
    late_s = reconverged_after_s(hostd, tmp_path, paths, "engine.solve.adopt_after_sweeps=1.0")
    print(f"converged again {default_s} s after the stop by default, {late_s} s with a sweep's lag")

    # Assert
    assert default_s is not None and late_s is not None
    assert late_s > default_s + 0.5


@pytest.mark.parametrize("default_seed", [1, 2])
def test_that_without_motion_reports_the_stop_is_seen_from_the_ranges_within_two_seconds(hostd, tmp_path,
                                                                                         default_seed):
    # Fixture: the same carry, the motion CSV not given: the fallback detector must see it.
    seed = seed_of(default_seed)
    paths = simulate(tmp_path, seed)
    trace = tmp_path / "trace.csv"

    # Act
    result = run(hostd, "--ranges-csv", paths["ranges"], "--heights-csv", paths["heights"], "--out-csv",
                 tmp_path / "estimates.csv", "--trace-csv", trace, "--trace-every", "1")
    assert result.returncode == 0, result.stderr
    scored = subprocess.run([sys.executable, "-m", "cdro_tools.eval_motion", "--trace", str(trace), "--tracks",
                             str(paths["tracks"]), "--truth", str(paths["truth"]), "--motion", str(paths["motion"]),
                             "--node", CARRIED, "--json", "-"], capture_output=True, text=True, timeout=GUARD_S)
    assert scored.returncode == 0, scored.stderr
    track = json.loads(scored.stdout)["track"]
    print(f"start seen after {track['start_seen_after_s']} s, stop after {track['stop_seen_after_s']} s, "
          f"converged again after {track['reconverged_after_s']} s")

    # Assert: seen moving, then seen still again soon after the stop (not before it), converged soon after
    [start_s], [stop_s], [again_s] = (track[k] for k in ("start_seen_after_s", "stop_seen_after_s",
                                                          "reconverged_after_s"))
    assert start_s is not None and start_s <= 2.0
    assert stop_s is not None and 0.3 <= stop_s <= STOP_SEEN_WITHIN_S
    assert again_s is not None and again_s <= 4.0
