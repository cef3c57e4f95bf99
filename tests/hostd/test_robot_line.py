"""The robot line of the real engine, end to end: a simulated robot's capture (the device's
frames and the robot's odometry records, as a live run records them) replayed through
cdro-hostd. The line says its frame, and carries the full 3x3 covariance, the heading
hypotheses and the range model the filter estimates (docs/outputs.md); its times are the
capture's, the same in every replay. Timeouts are deadlock guards only."""
from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from robot_capture import ROBOT, write_robot_capture

GUARD_S = 300.0


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """plaza-like for 120 s: its capture with the odometry records put in their place."""
    path, start_us = write_robot_capture(tmp_path_factory.mktemp("robot"), GUARD_S)
    return path, start_us


def replay(build_dir, path) -> list[str]:
    result = subprocess.run([str(build_dir / "bin" / "cdro-hostd"), "--replay", str(path), "--speed", "max",
                             "--set", f"movement.robot_id={ROBOT:#06x}"], capture_output=True, text=True,
                            timeout=GUARD_S)
    assert result.returncode == 0, result.stderr
    return [line for line in result.stdout.splitlines() if line.startswith('{"type":"node"')
            or line.startswith('{"type":"robot"')]


def covariance_of(line) -> np.ndarray:
    """The 3x3 covariance of (x, y, heading) from its six keys."""
    return np.array([[line["var_x_m2"], line["cov_xy_m2"], line["cov_x_heading_m_rad"]],
                     [line["cov_xy_m2"], line["var_y_m2"], line["cov_y_heading_m_rad"]],
                     [line["cov_x_heading_m_rad"], line["cov_y_heading_m_rad"], line["var_heading_rad2"]]])


def test_the_robot_line_gives_its_frame_full_covariance_hypotheses_and_range_model(build_dir, capture):
    path, start_us = capture
    lines = replay(build_dir, path)
    robot = [json.loads(line) for line in lines if line.startswith('{"type":"robot"')]
    assert len(robot) > 100

    for line in robot:
        assert line["schema"] == 2 and line["id"] == ROBOT and line["id_hex"] == "0x6001"
        assert line["frame"] in ("odometry", "map")
        assert line["t_unix_s"] == pytest.approx(start_us / 1e6 + line["t_s"], abs=1e-6)
        position = covariance_of(line)[:2, :2]
        assert np.linalg.eigvalsh(position).min() >= -1e-12 and line["var_heading_rad2"] > 0
        assert line["heading_hypotheses"] >= 1
        assert line["range_scale_sigma"] > 0 and line["range_offset_sigma_m"] > 0
    # The filter correlates heading with position once the robot drives, and decides its heading.
    assert any(line["cov_x_heading_m_rad"] != 0.0 for line in robot)
    assert robot[-1]["heading_hypotheses"] == 1 and robot[-1]["frame"] == "map"
    # The range model it estimates moved from its prior (scale 1, offset 0).
    assert robot[-1]["range_scale"] != 1.0 and robot[-1]["range_offset_m"] != 0.0


def test_a_replay_writes_the_same_times_and_estimates_every_time(build_dir, capture):
    path, _ = capture
    assert replay(build_dir, path) == replay(build_dir, path)


def test_the_full_covariance_is_a_covariance(build_dir, capture):
    path, _ = capture
    robot = [json.loads(line) for line in replay(build_dir, path) if line.startswith('{"type":"robot"')]
    assert min(np.linalg.eigvalsh(covariance_of(line)).min() for line in robot) >= -1e-12
