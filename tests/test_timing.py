"""Time in the chain: stamped poses and late images (scenarios.run.runner with
scenarios.run.streams).

The oracles: the scenario's own keyframes interpolated by SciPy (the true pose at any time),
the pose samples the run sent (``RunResult.poses``) interpolated by SciPy's ``Slerp``, the
same scenario run synchronously, and the true cone positions.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from scenarios import pipeline
from scenarios.cli import main
from scenarios.judge import checks
from scenarios.scenario import builtin, check_kinds
from scenarios.scenario.spec import ScenarioSpec, Timing
from vnav.methods import method
from vnav.noise_model import NoiseModel


def _keyframe_pose(spec: ScenarioSpec):
    """The true pose at any time, from the scenario's keyframes: position linear, attitude by
    SciPy's Slerp (the kinematic flight's definition)."""
    keys = spec.flight.keyframes
    times = np.array([k.t_s for k in keys])
    positions = np.array([k.position_w for k in keys])
    slerp = Slerp(times, Rotation.from_quat([k.quat_xyzw for k in keys]))

    def pose(t_s: float) -> tuple[np.ndarray, Rotation]:
        t = min(max(t_s, times[0]), times[-1])  # held outside the keyframes
        p = np.array([np.interp(t, times, positions[:, i]) for i in range(3)])
        return p, slerp([t])[0]

    return pose


def _stream_pose(poses, t_s: float) -> np.ndarray:
    """The pose stream interpolated at ``t_s`` by SciPy: position linear, attitude Slerp."""
    stamps = poses.stamps_s
    slerp = Slerp(stamps, Rotation.from_matrix(poses.T_w_b[:, :3, :3]))
    T = np.eye(4)
    T[:3, :3] = slerp([t_s])[0].as_matrix()
    T[:3, 3] = [np.interp(t_s, stamps, poses.T_w_b[:, i, 3]) for i in range(3)]
    return T


def _bound_m(range_m: float) -> float:
    bound = method("depth_image").bound
    return float(bound.allowed_m(np.array([range_m]))[0])


@pytest.fixture(scope="module")
def latency_runs():
    """The latency built-in as it is, and the same flight with synchronous sensors."""
    spec = builtin.load("latency")
    late = pipeline.run(spec, seed=3)
    sync = pipeline.run(dataclasses.replace(spec, timing=Timing()), seed=3)
    return spec, late, sync


def test_every_image_is_evaluated_even_those_arriving_after_the_flight(latency_runs):
    spec, late, _ = latency_runs
    assert [t.tick for t in late.result.ticks] == list(range(spec.n_ticks))
    last = late.result.ticks[-1].timing
    assert last.arrival_s > spec.end_s  # it arrived after the last exposure, and still counts


def test_stamps_follow_the_scenarios_clocks(latency_runs):
    spec, late, _ = latency_runs
    timing = spec.timing
    poses = late.result.poses
    for tick in late.result.ticks:
        stamps = tick.timing
        # The image is stamped on the camera clock; read on the pose clock it is the exposure.
        assert stamps.stamp_cam_s == pytest.approx(tick.t_s - timing.camera_clock_offset_s)
        assert stamps.exposure_pose_s == pytest.approx(tick.t_s, abs=1e-12)
        assert stamps.arrival_s >= tick.t_s
        # The newest pose at arrival: the latest stamp among the samples arrived by then.
        arrived = poses.stamps_s[poses.arrivals_s <= stamps.arrival_s]
        assert stamps.latest_pose_s == arrived.max()
    latency = np.array([t.timing.image_latency_s for t in late.result.ticks])
    # Gaussian jitter around the latency (2 ms sigma over 51 images).
    assert latency.mean() == pytest.approx(timing.image_latency_s, abs=3 * timing.jitter_s)
    assert np.all(np.abs(latency - timing.image_latency_s) < 6 * timing.jitter_s)


def test_at_exposure_estimates_are_the_synchronous_ones_and_within_the_bound(latency_runs):
    _, late, sync = latency_runs
    n = 0
    for t_late, t_sync in zip(late.result.ticks, sync.result.ticks, strict=True):
        np.testing.assert_allclose(t_late.T_w_b_est, t_sync.T_w_b, atol=1e-12)
        for d_late, d_sync in zip(t_late.detections, t_sync.detections, strict=True):
            np.testing.assert_allclose(
                d_late.estimates_w["depth_image"], d_sync.estimates_w["depth_image"], atol=1e-12
            )
            cone_w = late.result.cones_w[d_late.cone_index]
            error_m = np.linalg.norm(d_late.estimates_w["depth_image"] - cone_w)
            assert error_m <= _bound_m(d_late.range_m)
            n += 1
    assert n == len(late.result.ticks)  # one cone, seen in every image


def test_newest_pose_error_is_the_first_order_prediction_from_the_keyframes(latency_runs):
    spec, late, _ = latency_runs
    pose = _keyframe_pose(spec)
    ratios = []
    for tick in late.result.ticks:
        stamps = tick.timing
        p_a, R_a = pose(stamps.exposure_pose_s)
        p_b, R_b = pose(stamps.latest_pose_s)
        moved_m = np.linalg.norm(p_b - p_a)
        turned_rad = (R_a.inv() * R_b).magnitude()
        assert stamps.true_motion_m == pytest.approx(moved_m, abs=1e-9)
        assert stamps.true_motion_rad == pytest.approx(turned_rad, abs=1e-9)
        (d,) = tick.detections
        predicted_m = moved_m + d.range_m * turned_rad
        assert d.predicted_latest_error_m == pytest.approx(predicted_m, abs=1e-9)
        # The error with the newest pose, against the true cone.
        error_m = np.linalg.norm(d.latest_w - late.result.cones_w[d.cone_index])
        assert d.latest_error_m == pytest.approx(error_m, abs=1e-12)
        if predicted_m > checks.MOTION_FLOOR_M:
            ratios.append(error_m / predicted_m)
    ratios = np.array(ratios)
    assert ratios.size > 40  # the drone moves all flight long but at the turns
    assert np.median(np.abs(ratios - 1.0)) < 0.25
    # While yawing at 100 deg/s the stale pose is off by decimetres.
    assert max(d.latest_error_m for t in late.result.ticks for d in t.detections) > 0.3


def test_report_compares_the_two_lookups(latency_runs):
    _, late, sync = latency_runs
    lookup = late.report["pose_lookup"]
    exposure = lookup["at_exposure"]["position_error_m"]
    latest = lookup["latest_at_arrival"]["position_error_m"]
    assert exposure == late.report["methods"]["depth_image"]["position_error_m"]
    assert latest["median"] > 5 * exposure["median"]
    errors = [d.latest_error_m for t in late.result.ticks for d in t.detections]
    assert latest["max"] == pytest.approx(max(errors), abs=1e-9)
    assert lookup["latest_minus_exposure_s"]["min"] > 0.0  # newer than the exposure
    # Synchronous: the newest pose at arrival is the exposure pose, the two agree.
    s = sync.report["pose_lookup"]
    assert s["latest_at_arrival"]["position_error_m"] == s["at_exposure"]["position_error_m"]
    assert s["latest_minus_exposure_s"] == {"mean": 0.0, "min": 0.0, "max": 0.0}
    assert s["image_latency_s"]["max"] == 0.0


def test_latency_prediction_check_has_no_data_without_motion(latency_runs):
    _, _, sync = latency_runs
    judged = checks.judge(check_kinds.Check("latency_prediction", 0.25), sync.result)
    assert judged.outcome is checks.Outcome.NO_DATA
    assert "did not move" in judged.shown


def test_latency_prediction_ignores_a_body_holding_still(latency_runs):
    """The flight ends holding its position: there the newest pose predicts rounding noise
    (~1e-15 m) and any error over it is an absurd ratio; the check leaves those out and
    judges the detections taken in motion (every other prediction is over a millimetre)."""
    _, late, _ = latency_runs
    latest, predicted = late.result.latest_pose_errors()
    still = predicted <= checks.MOTION_FLOOR_M
    assert still.any()
    assert np.all(predicted[~still] > 1e-3)
    judged = checks.judge(check_kinds.Check("latency_prediction", 0.25), late.result)
    moving = predicted > 1e-3
    assert judged.value == pytest.approx(np.median(np.abs(latest[moving] / predicted[moving] - 1)))
    assert judged.outcome is checks.Outcome.PASSED


def test_estimator_pose_is_the_noisy_stream_interpolated_at_the_exposure():
    # 47 Hz poses on 200 Hz physics: most exposures fall between two samples.
    spec = builtin.load("latency")
    spec = dataclasses.replace(
        spec,
        duration_s=2.0,
        noise=NoiseModel(position_std_m=0.01, attitude_std_deg=0.5),
        timing=Timing(pose_rate_hz=47.0, image_latency_s=0.03, pose_latency_s=0.01),
    )
    result = pipeline.run(spec, seed=7).result
    poses = result.poses
    between = 0
    for tick in result.ticks:
        t_s = tick.timing.exposure_pose_s
        np.testing.assert_allclose(tick.T_w_b_est, _stream_pose(poses, t_s), atol=1e-9)
        between += not np.any(poses.stamps_s == t_s)
        # Not the truth: the stream carries the noise.
        assert not np.allclose(tick.T_w_b_est, tick.T_w_b, atol=1e-6)
    assert between > len(result.ticks) // 2
    # Pose samples on the physics steps nearest j / 47 Hz, stamped with the simulator's time.
    expected = np.round(np.arange(poses.stamps_s.size) / 47.0 / 0.005) * 0.005
    np.testing.assert_allclose(poses.stamps_s, expected, atol=1e-9)
    np.testing.assert_allclose(poses.arrivals_s, poses.stamps_s + 0.01, atol=1e-12)


def _random_timing_toml(rng: np.random.Generator) -> tuple[str, dict]:
    timing = {
        "pose_rate_hz": float(rng.choice([50.0, 100.0, 200.0])),
        "pose_latency_s": round(float(rng.uniform(0.0, 0.03)), 4),
        "image_latency_s": round(float(rng.uniform(0.02, 0.1)), 4),
        "camera_clock_offset_s": round(float(rng.uniform(-0.05, 0.05)), 4),
        "jitter_s": round(float(rng.uniform(0.0, 0.004)), 4),
    }
    yaw_deg = float(rng.uniform(30.0, 60.0))
    text = f"""
name = "random-timing"
camera_rate_hz = 10.0
[camera]
pitch_down_deg = 20.0
[[cones]]
position_w = [7.0, 0.5, 0.0]
[flight]
mode = "kinematic"
keyframes = [
  {{ t = 0.0, position_w = [0.0, -1.0, 2.0], rpy_deg = [0.0, 0.0, {-yaw_deg / 2}] }},
  {{ t = 1.5, position_w = [0.0, 1.0, 2.0], rpy_deg = [0.0, 0.0, {yaw_deg / 2}] }},
  {{ t = 3.0, position_w = [1.0, 0.0, 2.0], rpy_deg = [0.0, 0.0, 0.0] }},
]
[timing]
{chr(10).join(f"{k} = {v!r}" for k, v in timing.items())}
[[checks]]
kind = "error_bound"
method = "depth_image"
limit = 1.0
[[checks]]
kind = "latency_prediction"
limit = 0.25
"""
    return text, timing


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_scenario_file_with_random_latency_and_offset(tmp_path, capsys, seed):
    text, timing = _random_timing_toml(np.random.default_rng(seed))
    path = tmp_path / "random.toml"
    path.write_text(text)
    status = main(["run", str(path), "--out", str(tmp_path), "--quiet", "--seed", str(seed)])
    report = json.loads((tmp_path / "random-timing.json").read_text())
    assert report["timing"] == timing
    assert status == 0, capsys.readouterr().out
    # At the exposure stamp: within the synchronous bound; with the newest pose: off by what
    # the drone moved meanwhile, as predicted to first order.
    by_name = {c["kind"]: c for c in report["checks"]}
    assert by_name["error_bound"]["outcome"] == "passed"
    assert by_name["latency_prediction"]["value"] < 0.25
    lookup = report["pose_lookup"]
    latest = lookup["latest_at_arrival"]
    assert latest["position_error_m"]["count"] == report["matched_detections"]
    mean_latency = lookup["image_latency_s"]["mean"]
    assert mean_latency == pytest.approx(
        timing["image_latency_s"], abs=4 * timing["jitter_s"] + 1e-9
    )
    assert math.isfinite(lookup["latest_minus_exposure_s"]["mean"])
