"""Read a scenario's .rrd back and hold it against the simulator's ground truth and the report."""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest
from helpers import R_GLC_TO_OPTICAL, mat3x3, mujoco_T_w_c, read_rows

from scenarios import builtin
from sim.render import Renderer
from sim.world import World
from vnav import quat, se3
from vnav.detect import detect_cones

FLOAT32_ATOL_M = 1e-5  # Rerun stores positions as float32: ~1e-6 relative at 10 m.


NAMES = builtin.names()


@pytest.fixture(params=NAMES)
def recorded(request, builtin_runs):
    """(spec, result, rrd path, report read back from its JSON file) of one built-in."""
    run = builtin_runs[request.param]
    return run.spec, run.result, run.rrd, json.loads(run.json_path.read_text())


def test_no_partial_file_left_beside_the_recordings(builtin_runs):
    out = next(iter(builtin_runs.values())).rrd.parent
    expected = {f"{n}{ext}" for n in NAMES for ext in (".rrd", ".json")}
    assert {p.name for p in out.iterdir()} == expected


def test_body_transform_every_frame_on_both_timelines(recorded):
    _, result, rrd, _ = recorded
    rows = [r for r in read_rows(rrd, "world/body") if "tick" in r]
    assert [r["tick"] for r in rows] == [f.tick for f in result.ticks]
    for row, f in zip(rows, result.ticks, strict=True):
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
    T_b_c_mujoco = se3.invert(world.T_w_b) @ mujoco_T_w_c(world)

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
        if not errors:  # e.g. known height, refused when the cone is seen from straight above
            assert stats["max"] is None
            continue
        assert max(errors) == pytest.approx(stats["max"], abs=FLOAT32_ATOL_M)
        assert np.median(errors) == pytest.approx(stats["median"], abs=FLOAT32_ATOL_M)


def test_error_series_logged_per_frame(recorded):
    _, result, rrd, _ = recorded
    rows = [r for r in read_rows(rrd, "metrics/error/depth_image") if "tick" in r]
    expected = {
        f.tick: np.mean(
            [d.errors_m["depth_image"] for d in f.detections if "depth_image" in d.errors_m]
        )
        for f in result.ticks
        if any("depth_image" in d.errors_m for d in f.detections)
    }
    assert {r["tick"]: r["Scalars:scalars"][0] for r in rows} == pytest.approx(expected)


def test_detections_logged_in_rerun_pixel_convention(recorded):
    """Re-render logged frames from the logged body pose, detect again: the logged keypoints
    and boxes are the detector's OpenCV pixels moved by +0.5 (Rerun's pixel centres)."""
    spec, result, rrd, _ = recorded
    keypoints = {
        r["tick"]: np.array(r["Points2D:positions"])
        for r in read_rows(rrd, "world/body/camera/detections/keypoints")
        if "tick" in r and r.get("Points2D:positions")
    }
    boxes = {
        r["tick"]: r
        for r in read_rows(rrd, "world/body/camera/detections")
        if "tick" in r and r.get("Boxes2D:centers")
    }
    poses = {r["tick"]: r for r in read_rows(rrd, "world/body") if "tick" in r}
    frames = sorted(keypoints)[:: max(1, len(keypoints) // 3)][:3]
    assert frames, "no detections logged"
    world = World.from_config(spec.scene)
    with Renderer(world) as renderer:
        for k in frames:
            # The pose as logged (float32) is close enough to re-render the same pixels only
            # up to rounding, so use the run's own float64 pose for frame k.
            assert np.allclose(
                poses[k]["Transform3D:translation"][0],
                result.ticks[k].T_w_b[:3, 3],
                atol=FLOAT32_ATOL_M,
            )
            world.set_pose(result.ticks[k].T_w_b)
            if getattr(spec.flight, "moves_camera", False):  # slide the camera as the run did
                world.set_camera_position_b(_camera_offset_b(spec, result.ticks[k].t_s))
            detections = detect_cones(renderer.render(depth=False).rgb)
            expected = np.concatenate([[d.apex_uv, d.base_uv] for d in detections]) + 0.5
            assert np.allclose(keypoints[k], expected, atol=1e-4)
            x, y, w, h = np.array([d.bbox for d in detections], dtype=np.float64).T
            # Pixels x .. x+w-1 cover Rerun's [x, x + w]: centre x + w/2, half size w/2.
            assert np.allclose(boxes[k]["Boxes2D:centers"], np.column_stack([x + w / 2, y + h / 2]))
            assert np.allclose(boxes[k]["Boxes2D:half_sizes"], np.column_stack([w / 2, h / 2]))


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
    R_b_c = R_b_glc.reshape(3, 3) @ R_GLC_TO_OPTICAL
    mount = next(r for r in read_rows(rrd, "world/body/camera") if "Transform3D:translation" in r)
    q_xyzw = np.array(mount["Transform3D:quaternion"][0])
    assert np.allclose(quat.to_matrix(q_xyzw, normalize=True), R_b_c, atol=1e-6)
    assert np.allclose(
        mount["Transform3D:translation"][0], model.cam_pos[world.camera_id], atol=1e-6
    )


def _camera_offset_b(spec, t_s: float) -> list[float]:
    """The keyframes' camera offset interpolated linearly at t_s (computed here, not by the
    runner)."""
    times = [k.t_s for k in spec.flight.keyframes]
    offsets_b = np.array([k.camera_position_b for k in spec.flight.keyframes])
    return [float(np.interp(t_s, times, offsets_b[:, i])) for i in range(3)]


def test_sliding_camera_mount_logged_every_frame(builtin_runs):
    """transform-composer slides the camera on the body: the mount logged at each frame is
    the keyframes' offset interpolated at that time, with the configured orientation."""
    run = builtin_runs["transform-composer"]
    rows = [r for r in read_rows(run.rrd, "world/body/camera") if "tick" in r]
    assert len(rows) == len(run.result.ticks)
    R_b_c = World.from_config(run.spec.scene).T_b_c[:3, :3]
    for row, f in zip(rows, run.result.ticks, strict=True):
        expected_b = _camera_offset_b(run.spec, f.t_s)
        assert np.allclose(row["Transform3D:translation"][0], expected_b, atol=1e-6)
        q_xyzw = np.array(row["Transform3D:quaternion"][0])
        assert np.allclose(quat.to_matrix(q_xyzw, normalize=True), R_b_c, atol=1e-6)
    moved = np.ptp(np.array([r["Transform3D:translation"][0] for r in rows]), axis=0)
    assert np.linalg.norm(moved) > 0.3
