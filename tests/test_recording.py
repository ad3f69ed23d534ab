"""Read a scenario's .rrd back and hold it against the simulator's ground truth and the report."""

from __future__ import annotations

import dataclasses
import json

import mujoco
import numpy as np
import pytest
from rrd_tools import mat3x3, read_rows

from scenarios import builtin, checks, report
from scenarios.runner import run_scenario
from sim.world import World
from vnav import quat, se3
from vnav.cone import TRAFFIC_CONE

FLOAT32_ATOL_M = 1e-5  # Rerun stores positions as float32: ~1e-6 relative at 10 m.


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp("rrd")
    spec = dataclasses.replace(builtin.load("transform-composer"), camera_rate_hz=5.0)
    rrd = out / f"{spec.name}.rrd"
    result = run_scenario(spec, seed=1, rrd_path=rrd)
    rep = report.build(result, [checks.evaluate(c, result) for c in spec.checks])
    json_path = out / f"{spec.name}.json"
    report.write(json_path, rep)
    return spec, result, rrd, json.loads(json_path.read_text())


def test_no_partial_file_left_beside_the_recording(recorded):
    _, _, rrd, _ = recorded
    assert sorted(p.name for p in rrd.parent.iterdir()) == sorted(
        [rrd.name, rrd.with_suffix(".json").name]
    )


def test_body_transform_every_frame_on_both_timelines(recorded):
    _, result, rrd, _ = recorded
    rows = [r for r in read_rows(rrd, "world/body") if "frame" in r]
    assert [r["frame"] for r in rows] == [f.frame for f in result.frames]
    for row, f in zip(rows, result.frames, strict=True):
        assert row["sim_time"] == pytest.approx(f.t_s * 1e9, abs=1e3)
        t_w_b = np.array(row["Transform3D:translation"][0])
        q_xyzw = np.array(row["Transform3D:quaternion"][0])
        # Ground truth straight from MuJoCo's state at that frame (xpos / xmat of the body).
        assert np.allclose(t_w_b, f.T_w_b[:3, 3], atol=FLOAT32_ATOL_M)
        assert np.allclose(quat.to_matrix(q_xyzw, normalize=True), f.T_w_b[:3, :3], atol=1e-6)


def test_camera_mount_and_pinhole_match_mujoco(recorded):
    spec, _, rrd, _ = recorded
    rows = read_rows(rrd, "world/body/camera")
    mount = next(r for r in rows if "Transform3D:translation" in r)
    pinhole = next(r for r in rows if "Pinhole:image_from_camera" in r)

    # Independent truth: MuJoCo's own camera pose (cam_xpos / cam_xmat, OpenGL axes) turned
    # into the optical frame by flipping y and z, expressed in the body frame.
    world = World.from_config(spec.scene)
    R_w_b = quat.to_matrix(quat.from_axis_angle([0.3, -0.2, 1.0], 0.7))
    world.set_pose(se3.make(R_w_b, [1.0, -2.0, 4.0]))
    cam = world.camera_id
    R_w_c = world.data.cam_xmat[cam].reshape(3, 3) @ np.diag([1.0, -1.0, -1.0])
    T_w_c = se3.make(R_w_c, world.data.cam_xpos[cam])
    T_b_c_mujoco = se3.invert(world.T_w_b()) @ T_w_c

    q_xyzw = np.array(mount["Transform3D:quaternion"][0])
    assert np.allclose(mount["Transform3D:translation"][0], T_b_c_mujoco[:3, 3], atol=1e-6)
    assert np.allclose(quat.to_matrix(q_xyzw, normalize=True), T_b_c_mujoco[:3, :3], atol=1e-6)

    # Rerun's pinhole is in continuous pixel coordinates: MuJoCo's principal point is exactly
    # the image centre (W/2, H/2) there, and f = (H/2) / tan(fovy/2) (MuJoCo's model).
    K = mat3x3(pinhole["Pinhole:image_from_camera"][0])
    W, H = spec.scene.camera.width, spec.scene.camera.height
    f = (H / 2) / np.tan(np.radians(world.model.cam_fovy[cam]) / 2)
    assert np.allclose(K, [[f, 0, W / 2], [0, f, H / 2], [0, 0, 1]], rtol=1e-6)
    assert pinhole["Pinhole:resolution"][0] == [W, H]
    # Rerun's ViewCoordinates codes: 3 = Right, 2 = Down, 5 = Forward (optical frame).
    assert pinhole["Pinhole:camera_xyz"][0] == [3, 2, 5]


def test_truth_points_and_estimates_agree_with_report(recorded):
    spec, _result, rrd, rep = recorded
    truth = read_rows(rrd, "world/cones/truth")
    assert np.allclose(truth[0]["Points3D:positions"], spec.scene.cones_w, atol=1e-6)
    cones_w = np.array(spec.scene.cones_w)

    for method in ("depth_image", "ground_plane", "known_height"):
        rows = [
            r
            for r in read_rows(rrd, f"world/cones/estimate/{method}")
            if r.get("Points3D:positions")
        ]
        errors = [
            np.min(np.linalg.norm(np.array(p) - cones_w, axis=1))
            for r in rows
            for p in r["Points3D:positions"]
        ]
        stats = rep["methods"][method]["position_error_m"]
        assert len(errors) == stats["count"]
        assert max(errors) == pytest.approx(stats["max"], abs=FLOAT32_ATOL_M)
        assert np.median(errors) == pytest.approx(stats["median"], abs=FLOAT32_ATOL_M)


def test_error_series_logged_per_frame(recorded):
    _, result, rrd, _ = recorded
    rows = [r for r in read_rows(rrd, "metrics/error/depth_image") if "frame" in r]
    expected = {
        f.frame: np.mean(
            [d.errors_m["depth_image"] for d in f.detections if "depth_image" in d.errors_m]
        )
        for f in result.frames
        if any("depth_image" in d.errors_m for d in f.detections)
    }
    assert {r["frame"]: r["Scalars:scalars"][0] for r in rows} == pytest.approx(expected)


def test_detection_keypoints_in_rerun_pixel_convention(recorded):
    """Logged apex keypoints land on the true apex projected with the logged intrinsics."""
    spec, result, rrd, _ = recorded
    T_b_c = World.from_config(spec.scene).T_b_c
    K = mat3x3(
        next(r for r in read_rows(rrd, "world/body/camera") if "Pinhole:image_from_camera" in r)[
            "Pinhole:image_from_camera"
        ][0]
    )
    rows = {
        r["frame"]: r
        for r in read_rows(rrd, "world/body/camera/detections/keypoints")
        if "frame" in r and r.get("Points2D:positions")
    }
    apex_w = np.array(spec.scene.cones_w[0]) + np.array([0.0, 0.0, TRAFFIC_CONE.height_m])
    offsets = []
    for f in result.frames:
        if f.frame not in rows or not f.cones_in_view:
            continue
        apex_c = se3.apply(se3.invert(f.T_w_b @ T_b_c), apex_w)
        uv_true = (K @ apex_c)[:2] / apex_c[2]
        offsets.append(np.array(rows[f.frame]["Points2D:positions"][0]) - uv_true)
    offsets = np.array(offsets)
    assert len(offsets) > 5
    assert np.max(np.linalg.norm(offsets, axis=1)) < 2.0


def test_recording_reads_back_with_mujoco_independent_of_sim(recorded):
    """The mount logged in the file equals the one MuJoCo compiles from the scene spec."""
    spec, _, rrd, _ = recorded
    world = World.from_config(spec.scene)
    model = world.model
    body = model.body(world.body_id)
    assert model.cam_bodyid[world.camera_id] == body.id
    q_wxyz = model.cam_quat[world.camera_id]
    R_b_glc = np.zeros(9)
    mujoco.mju_quat2Mat(R_b_glc, q_wxyz)
    R_b_c = R_b_glc.reshape(3, 3) @ np.diag([1.0, -1.0, -1.0])
    mount = next(r for r in read_rows(rrd, "world/body/camera") if "Transform3D:translation" in r)
    q_xyzw = np.array(mount["Transform3D:quaternion"][0])
    assert np.allclose(quat.to_matrix(q_xyzw, normalize=True), R_b_c, atol=1e-6)
    assert np.allclose(
        mount["Transform3D:translation"][0], model.cam_pos[world.camera_id], atol=1e-6
    )
