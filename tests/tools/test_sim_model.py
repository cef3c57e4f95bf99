"""The simulator's models: UWB errors (statistics, seeded), the world's truth (motion, robot path,
odometry, accelerometer), and random networks."""
import math
import random
import statistics

import pytest

from cdro_tools.simulation.network import random_network
from cdro_tools.simulation.scenario import ScenarioError, parse_scenario
from cdro_tools.simulation.uwb import POZYX_RANGING_FAILED, POZYX_RANGING_TIMEOUT, UwbModel
from cdro_tools.simulation.world import World

A, B, C3, D = 0x6001, 0x6002, 0x6003, 0x6004


def two_nodes(distance_m=10.0, **uwb):
    return parse_scenario({"own_id": A, "nodes": [{"id": A, "x_m": 0, "y_m": 0, "z_m": 1.0},
                                                  {"id": B, "x_m": distance_m, "y_m": 0, "z_m": 1.0},
                                                  {"id": C3, "x_m": 0, "y_m": 6, "z_m": 2.0}],
                           "uwb": uwb}, "test")


def model(sc, seed):
    print(f"seed {seed}")
    world = World(sc)
    return UwbModel(sc, world, random.Random(f"{seed}l"), random.Random(f"{seed}r"))


def errors_m(uwb, a, b, count):
    true_m = uwb.world.distance_m(a, b, 0.0)
    outcomes = [uwb.measure(a, b, 0.0) for _ in range(count)]
    return [o.distance_mm / 1000.0 - true_m for o in outcomes if o.ok], outcomes


def test_that_gaussian_noise_has_the_configured_std_and_no_bias():
    uwb = model(two_nodes(noise_std_m=0.1), seed=11)
    errors, _ = errors_m(uwb, A, B, 4000)
    assert statistics.pstdev(errors) == pytest.approx(0.1, rel=0.05)
    assert abs(statistics.fmean(errors)) < 0.01


def test_that_per_link_variances_are_drawn_from_the_configured_range():
    sc = two_nodes(noise_variance_m2=[0.3, 0.8])
    uwb = model(sc, seed=12)
    stds = list(uwb.link_std_m.values())
    assert all(math.sqrt(0.3) <= s <= math.sqrt(0.8) for s in stds) and len(set(stds)) == 3
    errors, _ = errors_m(uwb, A, B, 4000)
    assert statistics.pstdev(errors) == pytest.approx(uwb.link_std_m[(A, B)], rel=0.05)


def test_that_a_listed_nlos_link_reads_long_by_its_bias_and_others_do_not():
    uwb = model(two_nodes(noise_std_m=0.05, nlos={"links": [[B, A, 0.8]]}), seed=13)
    biased, _ = errors_m(uwb, A, B, 500)
    clean, _ = errors_m(uwb, A, C3, 500)
    assert statistics.fmean(biased) == pytest.approx(0.8, abs=0.01)
    assert abs(statistics.fmean(clean)) < 0.01


def test_that_random_nlos_links_get_a_positive_bias_in_the_range():
    sc = parse_scenario({"own_id": A,
                         "nodes": [{"id": 0x6001 + i, "x_m": i * 3.0, "y_m": (i % 2) * 4.0} for i in range(6)],
                         "uwb": {"nlos": {"random_links": 4, "random_bias_m": [0.5, 1.0]}}}, "test")
    uwb = model(sc, seed=14)
    assert len(uwb.link_bias_m) == 4 and all(0.5 <= b <= 1.0 for b in uwb.link_bias_m.values())


def test_that_outliers_read_long_with_the_configured_rate_and_mean():
    uwb = model(two_nodes(noise_std_m=0.02, nlos={"outlier_probability": 0.1, "outlier_mean_m": 1.0}), seed=15)
    errors, _ = errors_m(uwb, A, B, 5000)
    outliers = [e for e in errors if e > 0.1]
    assert min(errors) > -0.1                                 # never short
    # P(e > 0.1) = 0.1 exp(-0.1 / 1.0) for the exponential tail (noise is 0.02 m)
    assert len(outliers) / len(errors) == pytest.approx(0.1 * math.exp(-0.1), abs=0.015)
    assert statistics.fmean(outliers) == pytest.approx(1.1, rel=0.1)


def test_that_dropouts_fail_at_the_configured_rate_with_the_pozyx_code():
    uwb = model(two_nodes(dropout_probability=0.2), seed=16)
    _, outcomes = errors_m(uwb, A, B, 5000)
    failed = [o for o in outcomes if not o.ok]
    assert len(failed) / len(outcomes) == pytest.approx(0.2, abs=0.02)
    assert {o.error_code for o in failed} == {POZYX_RANGING_FAILED}


def test_that_ranges_beyond_the_maximum_fail_with_a_timeout():
    uwb = model(two_nodes(distance_m=30.0, max_range_m=20.0), seed=17)
    far = [uwb.measure(A, B, 0.0) for _ in range(50)]
    near = [uwb.measure(A, C3, 0.0) for _ in range(50)]
    assert all(not o.ok and o.error_code == POZYX_RANGING_TIMEOUT for o in far)
    assert all(o.ok for o in near)
    assert not uwb.measure(A, 0x7777, 0.0).ok           # no such node


def test_that_rss_is_plausible():
    # (how long a ranging takes is the Pozyx model's, sim/pozyx_sim, not this model's)
    uwb = model(two_nodes(), seed=18)
    direct = [uwb.measure(A, B, 0.0) for _ in range(200)]
    near = statistics.fmean(o.rss_dbm for o in [uwb.measure(A, C3, 0.0) for _ in range(200)])  # 6.1 m
    far = statistics.fmean(o.rss_dbm for o in direct)                                                 # 10 m
    assert -90 < far < near < -75


def test_that_the_3d_distance_is_measured():
    sc = parse_scenario({"own_id": A,
                         "nodes": [{"id": A, "x_m": 0, "y_m": 0, "z_m": 0.0},
                                   {"id": B, "x_m": 3, "y_m": 0, "z_m": 4.0}],
                         "uwb": {"noise_std_m": 0.0}}, "test")
    assert model(sc, seed=19).measure(A, B, 0.0).distance_mm == 5000


def test_that_a_carried_node_moves_along_its_waypoints_at_its_speed():
    sc = parse_scenario({"own_id": A,
                         "nodes": [{"id": A, "x_m": 0, "y_m": 0}, {"id": B, "x_m": 1, "y_m": 1, "z_m": 1.5}],
                         "motion": [{"node": B, "start_s": 10, "speed_mps": 1.25, "waypoints_m": [[4, 5], [4, 6]]}]},
                        "test")
    world = World(sc)
    assert world.position(B, 9.9) == (1, 1, 1.5)
    assert world.position(B, 12.0) == pytest.approx((2.5, 3.0, 1.5))        # 2.5 m along the first 5 m leg
    assert world.position(B, 14.4) == pytest.approx((4.0, 5.5, 1.5))
    assert world.position(B, 100.0) == pytest.approx((4.0, 6.0, 1.5))
    assert world.moving(B, 11.0) and not world.moving(B, 14.9) and not world.moving(A, 11.0)
    assert world.motion_rows() == [(0.0, A, 0), (0.0, B, 0), (10.0, B, 1), (pytest.approx(14.8), B, 0)]


def test_that_overlapping_motion_segments_are_rejected():
    sc = parse_scenario({"own_id": A, "nodes": [{"id": A, "x_m": 0, "y_m": 0}, {"id": B, "x_m": 0, "y_m": 0}],
                         "motion": [{"node": B, "start_s": 0, "end_s": 10, "waypoints_m": [[5, 0]]},
                                    {"node": B, "start_s": 5, "speed_mps": 1, "waypoints_m": [[0, 0]]}]}, "test")
    with pytest.raises(ScenarioError, match="overlap"):
        World(sc)


def robot_scenario(**odometry):
    return parse_scenario({"own_id": A, "duration_s": 60,
                           "nodes": [{"id": A, "x_m": 0, "y_m": 0, "accelerometer": True},
                                     {"id": B, "x_m": 10, "y_m": 10}],
                           "robot": {"id": A, "start_s": 5, "speed_mps": 0.5, "turn_rate_rad_s": 0.5,
                                     "waypoints_m": [[10, 0], [10, 10], [0, 10]], "odometry": odometry}}, "test")


def dead_reckon(rows, start):
    x, y, heading = start
    path = [(x, y, heading)]
    for _, distance_m, dheading_rad in rows:
        x += distance_m * math.cos(heading + dheading_rad / 2)
        y += distance_m * math.sin(heading + dheading_rad / 2)
        heading += dheading_rad
        path.append((x, y, heading))
    return path


def test_that_noise_free_odometry_reproduces_the_robot_path_with_the_midpoint_convention():
    # Fixture
    world = World(robot_scenario(distance_noise_frac=0.0, heading_noise_rad=0.0, heading_drift_rad_s=0.0))

    # Test
    rows, truth = world.odometry(random.Random(1))

    # Assert
    assert len(rows) == 600 and len(truth) == 601
    assert rows[0] == (0.0, 0.0, 0.0)                                      # standing still before 5 s
    path = dead_reckon(rows, truth[0][1:])
    worst = max(math.dist(p[:2], t[1:3]) for p, t in zip(path, truth))
    assert worst < 0.01
    assert truth[0][3] == 0.0 and truth[-1][3] == pytest.approx(math.pi)    # east first, then north, then west


def test_that_odometry_noise_and_drift_make_dead_reckoning_drift():
    seed = 21
    print(f"seed {seed}")
    world = World(robot_scenario(distance_noise_frac=0.02, heading_noise_rad=0.003, heading_drift_rad_s=0.01))
    rows, truth = world.odometry(random.Random(seed))
    still = [r for r in rows if r[0] < 4.9]
    assert all(r[1] == 0.0 and r[2] == pytest.approx(0.001) for r in still)   # only the drift while standing
    path = dead_reckon(rows, truth[0][1:])
    assert path[-1][2] - truth[-1][3] == pytest.approx(0.6, abs=0.1)          # 60 s x 0.01 rad/s (+ noise)
    assert math.dist(path[-1][:2], truth[-1][1:3]) > 0.5


def test_that_the_accelerometer_reads_one_g_still_and_swings_while_moving():
    seed = 22
    print(f"seed {seed}")
    sc = parse_scenario({"own_id": A, "nodes": [{"id": A, "x_m": 0, "y_m": 0, "accelerometer": True},
                                                {"id": B, "x_m": 0, "y_m": 0, "accelerometer": True}],
                         "motion": [{"node": B, "start_s": 10, "end_s": 20, "waypoints_m": [[10, 0]]}],
                         "accelerometer": {"noise_std_mg": 8, "moving_amplitude_mg": 250}}, "test")
    world = World(sc)
    rng = random.Random(seed)
    still = [world.accel_norm_mg(B, t / 10, rng) - 1000 for t in range(0, 90)]
    moving = [world.accel_norm_mg(B, 10 + t / 10, rng) - 1000 for t in range(0, 90)]
    assert statistics.pstdev(still) == pytest.approx(8, rel=0.25) and max(map(abs, still)) < 40
    assert max(map(abs, moving)) > 200


def test_that_a_random_network_has_the_mean_degree_and_is_connected():
    seed = 23
    print(f"seed {seed}")
    net = random_network(40, 6.0, seed, noise_m=0.1, sweeps=5)
    assert net.mean_degree == pytest.approx(6.0, abs=0.1)
    assert len(net.ranges) == 5 * len(net.links)
    positions = {i: (x, y) for i, x, y, _ in net.nodes}
    errors = [r - math.dist(positions[a], positions[b]) for _, a, b, r in net.ranges]
    assert statistics.pstdev(errors) == pytest.approx(0.1, rel=0.1)
    assert all(math.dist(positions[a], positions[b]) <= net.radius_m + 1e-9 for _, a, b, _ in net.ranges)
    assert all(z == 0.0 for *_, z in net.nodes)
    assert random_network(40, 6.0, seed, noise_m=0.1, sweeps=5) == net              # deterministic
    assert random_network(40, 6.0, seed + 1, noise_m=0.1, sweeps=5).nodes != net.nodes


def test_that_random_network_arguments_are_checked():
    with pytest.raises(ScenarioError, match="degree"):
        random_network(10, 12.0, 1)
    with pytest.raises(ScenarioError, match="at least 3"):
        random_network(2, 1.0, 1)
