"""scenarios.scenario.builtin: every built-in scenario runs and passes its own checks, with no NaN
anywhere, and teaches its lesson (the frame problem, the yaw sweep, the gimbal lock).

Scenarios run once per session (the ``builtin_runs`` fixture in conftest.py) at 5 Hz instead
of 10 Hz: the same flights, half the frames.
"""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest
from helpers import BUILTIN_TEST_RATE_HZ as TEST_RATE_HZ

from scenarios.scenario import builtin
from vnav import quat, se3, so3


@pytest.mark.parametrize("name", builtin.names())
def test_builtin_scenario_passes_its_checks(runs, name):
    spec, _result, judged, rep = runs[name]
    assert spec.checks, f"{name} declares no checks"
    failed = [c.as_dict() for c in judged if not c.passed]
    assert not failed, f"{name} failed checks: {failed}"
    assert rep["passed"] is True
    n_ticks = math.floor(spec.end_s * TEST_RATE_HZ + 1e-9) + 1
    if "navigation" in rep:  # a navigating flight ends at its goal or at a cone
        nav = rep["navigation"]
        ended_s = nav["first_contact_s"] if nav["collided"] else nav["time_to_goal_s"]
        assert rep["camera_ticks"] == math.floor(ended_s * TEST_RATE_HZ - 1e-9) + 1
    else:
        assert rep["camera_ticks"] == n_ticks
    assert rep["matched_detections"] > 0


@pytest.mark.parametrize("name", builtin.names())
def test_registry_no_nan_anywhere(runs, name):
    _, result, _, rep = runs[name]
    for f in result.ticks:
        assert np.isfinite(f.T_w_b).all() and np.isfinite(f.quat_xyzw).all()
        assert np.isfinite(f.rpy_rad).all()
        for d in f.detections:
            for p_w in d.estimates_w.values():
                assert np.isfinite(p_w).all()
            assert all(math.isfinite(e) for e in d.errors_m.values())
    # The report is strict JSON (no NaN tokens); statistics of empty series are null.
    text = json.dumps(rep, allow_nan=False)
    assert "NaN" not in text


def test_frame_problem_naive_is_far_off_and_camera_coords_match_the_lecture(runs):
    """Chapter 0: p_w = T_w_b T_b_c p_c holds; adding p_c to the drone's position does not."""
    spec, result, _, rep = runs["frame-problem"]
    depth = rep["methods"]["depth_image"]["position_error_m"]
    naive = rep["methods"]["naive"]["position_error_m"]
    assert naive["median"] > 5.0 and depth["max"] < 0.1
    # After the 90 deg clockwise yaw the body's x axis points along world -y (the quiz).
    last = result.ticks[-1]
    assert np.allclose(last.T_w_b[:3, 0], [0.0, -1.0, 0.0], atol=1e-9)
    # The cone at [2, 1, 0] is then 1 m behind the body and 2 m to its left (FLU):
    p_b = se3.apply(se3.invert(last.T_w_b), np.array(spec.scene.cones_w[0]))
    assert np.allclose(p_b, [-1.0, 2.0, -10.0], atol=1e-9)


def test_yaw_sweep_camera_coordinates_move_world_estimates_do_not(runs):
    _, result, _, _ = runs["yaw-sweep"]
    p_c = np.array(
        [d.p_c_true for f in result.ticks for d in f.detections if d.p_c_true is not None]
    )
    p_w = np.array(
        [
            d.estimates_w["depth_image"]
            for f in result.ticks
            for d in f.detections
            if "depth_image" in d.estimates_w
        ]
    )
    assert np.linalg.norm(np.ptp(p_c, axis=0)) > 2.0
    assert np.linalg.norm(np.ptp(p_w, axis=0)) < 0.1


def test_gimbal_lock_flagged_while_quaternion_stays_smooth(runs):
    _, result, _, _ = runs["gimbal-lock"]
    locked = [f for f in result.ticks if f.gimbal_locked]
    assert locked, "no frame at pitch -90 deg flagged"
    for f in locked:
        assert f.rpy_rad[1] == pytest.approx(-math.pi / 2, abs=1e-6)
        # The angles returned at the lock still reproduce the attitude (lecture chapter 4).
        assert np.allclose(so3.from_rpy(*f.rpy_rad), f.T_w_b[:3, :3], atol=1e-6)
    # Successive frames' quaternions differ by small rotations: no jump through the lock.
    q = np.array([f.quat_xyzw for f in result.ticks])
    steps = [
        np.linalg.norm(so3.log(quat.to_matrix(a).T @ quat.to_matrix(b)))
        for a, b in itertools.pairwise(q)
    ]
    assert max(steps) < math.radians(10.0)
