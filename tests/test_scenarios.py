"""Every built-in scenario runs and passes its own checks; the report agrees with the truth.

Scenarios run once per session (module fixture) at 5 Hz instead of 10 Hz: the same flights,
half the frames.
"""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest
from conftest import BUILTIN_TEST_RATE_HZ as TEST_RATE_HZ

from scenarios import builtin, checks
from scenarios.spec import from_dict
from vnav import quat, se3, so3
from vnav.methods import METHOD_NAMES


@pytest.fixture(scope="module")
def runs(builtin_runs):
    return {n: (r.spec, r.result, r.judged, r.report) for n, r in builtin_runs.items()}


@pytest.mark.parametrize("name", builtin.names())
def test_builtin_scenario_passes_its_checks(runs, name):
    spec, _result, judged, rep = runs[name]
    assert spec.checks, f"{name} declares no checks"
    failed = [c.as_dict() for c in judged if not c.passed]
    assert not failed, f"{name} failed checks: {failed}"
    assert rep["passed"] is True
    assert rep["camera_ticks"] == math.floor(spec.end_s * TEST_RATE_HZ + 1e-9) + 1
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


@pytest.mark.parametrize("name", builtin.names())
def test_report_errors_are_distances_to_the_true_cone(runs, name):
    """Recompute every error from the estimates and the scene's cone list (the truth)."""
    spec, result, _, rep = runs[name]
    cones_w = np.array(spec.scene.cones_w)
    for method in METHOD_NAMES:
        errors = []
        for f in result.ticks:
            for d in f.detections:
                if d.cone_index is not None and method in d.estimates_w:
                    errors.append(np.linalg.norm(d.estimates_w[method] - cones_w[d.cone_index]))
        stats = rep["methods"][method]["position_error_m"]
        assert stats["count"] == len(errors)
        if errors:
            assert stats["max"] == pytest.approx(max(errors), abs=1e-8)
            assert stats["rmse"] == pytest.approx(np.sqrt(np.mean(np.square(errors))), abs=1e-8)


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


@pytest.mark.parametrize("kind", sorted(checks.KINDS))
def test_every_registered_check_kind_is_accepted_by_the_parser_and_documented(kind):
    scenario = builtin.REGISTRY["frame-problem"]()
    scenario["checks"] = [{"kind": kind, "limit": 1.0}]
    (check,) = from_dict(scenario).checks
    assert check.kind == kind and checks.KINDS[kind].doc


@pytest.mark.parametrize("name", builtin.names())
def test_error_against_range_bins_partition_the_detections(runs, name):
    spec, result, _, rep = runs[name]
    cones_w = np.array(spec.scene.cones_w)
    for method in METHOD_NAMES:
        bins = rep["methods"][method]["by_range"]
        assert (
            sum(b["position_error_m"]["count"] for b in bins)
            == (rep["methods"][method]["position_error_m"]["count"])
        )
        for b in bins:
            lo, hi = b["range_m"]
            hi = math.inf if hi is None else hi
            # Recompute this bin from the frames: range from the camera to the true cone.
            errors = [
                np.linalg.norm(d.estimates_w[method] - cones_w[d.cone_index])
                for f in result.ticks
                for d in f.detections
                if d.cone_index is not None
                and method in d.estimates_w
                and lo <= np.linalg.norm(d.p_c_true) < hi
            ]
            assert len(errors) == b["position_error_m"]["count"]
            assert max(errors) == pytest.approx(b["position_error_m"]["max"], abs=1e-8)
