"""Read a scenario's .rrd back and hold it against the simulator's ground truth and the report."""

from __future__ import annotations

import json
import re
import warnings

import mujoco
import numpy as np
import pytest
from helpers import R_GLC_TO_OPTICAL, mat3x3, mujoco_T_w_c, read_rows

from scenarios.scenario import builtin
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
    truth = _static(rrd, "world/cones/truth", "Points3D:positions")
    assert np.allclose(truth, spec.scene.cones_w, atol=1e-6)
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
        # The nearest cone is the matched one only while every error is under half the
        # spacing of the cones (the calibration built-in's wrong mount moves estimates further).
        spacing = min(
            (np.linalg.norm(a - b) for i, a in enumerate(cones_w) for b in cones_w[i + 1 :]),
            default=np.inf,
        )
        if stats["max"] >= 0.5 * spacing:
            continue
        assert max(errors) == pytest.approx(stats["max"], abs=FLOAT32_ATOL_M)
        assert np.median(errors) == pytest.approx(stats["median"], abs=FLOAT32_ATOL_M)


def test_error_series_logged_per_frame(recorded):
    """Every tick has a value: the mean error where depth_image scored a detection, NaN (a
    gap in the plot, not a line drawn across it) where it scored none."""
    _, result, rrd, _ = recorded
    rows = {
        r["tick"]: r["Scalars:scalars"][0]
        for r in read_rows(rrd, "metrics/error/depth_image")
        if "tick" in r
    }
    assert sorted(rows) == [f.tick for f in result.ticks]
    expected = {
        f.tick: np.mean(
            [d.errors_m["depth_image"] for d in f.detections if "depth_image" in d.errors_m]
        )
        for f in result.ticks
        if any("depth_image" in d.errors_m for d in f.detections)
    }
    assert {k: v for k, v in rows.items() if k in expected} == pytest.approx(expected)
    assert all(np.isnan(v) for k, v in rows.items() if k not in expected)


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


# ------------------------------------------------------------ what the viewer draws


def _static(rrd, path: str, column: str):
    """The value of a static column logged at ``path`` (static rows have no timeline)."""
    return next(r[column] for r in read_rows(rrd, path) if column in r and "tick" not in r)


def _world_at(spec, f) -> World:
    """A fresh world placed as the run was at tick record ``f`` (pose and camera mount)."""
    world = World.from_config(spec.scene)
    world.set_pose(f.T_w_b)
    if getattr(spec.flight, "moves_camera", False):
        world.set_camera_position_b(_camera_offset_b(spec, f.t_s))
    return world


def _sampled_ticks(result, n: int = 3) -> list:
    """Up to n ticks spread over the run, preferring ticks with detections."""
    seen = [f for f in result.ticks if f.detections] or list(result.ticks)
    return seen[:: max(1, len(seen) // n)][:n]


def test_frames_named_with_axes_that_tell_them_apart(recorded):
    """world -> body -> camera -> image, as vnav.frames names them, each with its axes: the
    world's and the body's named at their origins, the camera's drawn as arrows in its own
    frame (tests/test_recording_views.py: thin, named on one axis)."""
    _, result, rrd, _ = recorded
    assert _static(rrd, "world", "CoordinateFrame:frame") == ["world"]
    lengths = {
        path: _static(rrd, path, "TransformAxes3D:axis_length")[0]
        for path in ("world", "world/body")
    }
    arrows = np.array(_static(rrd, "world/body/camera/axes", "Arrows3D:vectors"))
    lengths["world/body/camera"] = float(np.linalg.norm(arrows, axis=1).max())
    assert lengths["world"] > lengths["world/body"] > lengths["world/body/camera"] > 0.0
    for path in ("world", "world/body"):
        assert _static(rrd, path, "TransformAxes3D:show_frame") == [True]  # labelled
    assert _static(rrd, "world/body/camera/axes", "CoordinateFrame:frame") == ["camera"]

    body = [r for r in read_rows(rrd, "world/body") if "tick" in r]
    assert len(body) == len(result.ticks)
    assert all(r["Transform3D:child_frame"] == ["body"] for r in body)
    assert all(r["Transform3D:parent_frame"] == ["world"] for r in body)
    mount = [r for r in read_rows(rrd, "world/body/camera") if "Transform3D:translation" in r]
    assert mount and all(r["Transform3D:child_frame"] == ["camera"] for r in mount)
    assert all(r["Transform3D:parent_frame"] == ["body"] for r in mount)
    assert _static(rrd, "world/body/camera", "Pinhole:parent_frame") == ["camera"]
    assert _static(rrd, "world/body/camera", "Pinhole:child_frame") == ["image"]
    # Everything else is placed by naming its frame, not by where its path hangs.
    for path, frame in [
        ("world/body/drone", "body"),
        ("world/body/camera/image", "image"),
        ("world/body/camera/detections", "image"),
        ("world/cones/mesh", "world"),
        ("world/cones/truth", "world"),
        ("world/rays", "world"),
        ("world/rays/ground_hits", "world"),
        ("world/naive_offset", "world"),
        ("world/cones/estimate/depth_image", "world"),
        ("world/cones/error/ground_plane", "world"),
    ]:
        assert _static(rrd, path, "CoordinateFrame:frame") == [frame], path


def test_drone_mesh_is_mujocos_geoms_in_the_body_frame(recorded):
    spec, _, rrd, _ = recorded
    world = World.from_config(spec.scene)
    model = world.model
    vertices_b = np.array(_static(rrd, "world/body/drone", "Mesh3D:vertex_positions"))
    triangles = np.array(_static(rrd, "world/body/drone", "Mesh3D:triangle_indices"))
    assert triangles.max() < len(vertices_b)
    # Its extent is the union of MuJoCo's own bounding boxes of the drone's geoms, each placed
    # by its geom_pos / geom_quat in the body (the meshes reach every box's extreme points).
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for g in np.flatnonzero(model.geom_bodyid == world.body_id):
        centre, half = model.geom_aabb[g][:3], model.geom_aabb[g][3:]
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
        corners = centre + half * signs
        R_b_g = np.zeros(9)
        mujoco.mju_quat2Mat(R_b_g, model.geom_quat[g])
        corners_b = corners @ R_b_g.reshape(3, 3).T + model.geom_pos[g]
        lo, hi = np.minimum(lo, corners_b.min(0)), np.maximum(hi, corners_b.max(0))
    # The rotated boxes of the capsule arms are looser than the arms themselves: the mesh is
    # inside the union and touches its extremes along the axes the boxes are aligned with.
    assert np.all(vertices_b.min(0) >= lo - FLOAT32_ATOL_M)
    assert np.all(vertices_b.max(0) <= hi + FLOAT32_ATOL_M)
    hull = model.geom("drone_hull").id
    hull_hi = model.geom_pos[hull] + model.geom_size[hull]
    assert np.any(np.all(np.abs(vertices_b - hull_hi) < FLOAT32_ATOL_M, axis=1))
    # Cones: the base plate and shell of every cone, at the scene's cone positions.
    cones = np.array(_static(rrd, "world/cones/mesh", "Mesh3D:vertex_positions"))
    near = np.linalg.norm(cones[:, None, :2] - np.array(spec.scene.cones_w)[None, :, :2], axis=2)
    assert np.all(near.min(axis=1) < 0.3)  # every vertex belongs to some cone
    assert np.all(near.min(axis=0) < 1e-5)  # every cone has its apex (on its axis)


def test_rays_pass_from_the_camera_through_each_detection(recorded):
    """At sampled ticks, with MuJoCo's camera as the oracle: each ray starts at the camera
    centre (cam_xpos), projects onto its detection's logged base pixel, and its ground hit is
    on the ray at z = 0."""
    spec, result, rrd, _ = recorded
    rays = {r["tick"]: r for r in read_rows(rrd, "world/rays") if "tick" in r}
    hits = {r["tick"]: r for r in read_rows(rrd, "world/rays/ground_hits") if "tick" in r}
    keypoints = {
        r["tick"]: np.array(r["Points2D:positions"])
        for r in read_rows(rrd, "world/body/camera/detections/keypoints")
        if "tick" in r
    }
    W, H = spec.scene.camera.width, spec.scene.camera.height
    for f in _sampled_ticks(result):
        strips = np.array(rays[f.tick]["LineStrips3D:strips"]).reshape(-1, 2, 3)
        assert len(strips) == len(f.detections)
        if not len(strips):
            continue
        world = _world_at(spec, f)
        # The rays are the estimator's: from the camera where its (noisy) pose puts it.
        world.set_pose(f.T_w_b_est)
        T_w_c = mujoco_T_w_c(world)
        fy = (H / 2) / np.tan(np.radians(world.model.cam_fovy[world.camera_id]) / 2)
        assert np.allclose(strips[:, 0], T_w_c[:3, 3], atol=FLOAT32_ATOL_M)
        p_c = se3.apply(se3.invert(T_w_c), strips[:, 1].astype(np.float64))
        uv = fy * p_c[:, :2] / p_c[:, 2:] + [W / 2, H / 2]
        assert np.allclose(uv, keypoints[f.tick][1::2], atol=1e-3)  # apex, base, apex, ...
        ground = np.array(hits[f.tick]["Points3D:positions"]).reshape(-1, 3)
        assert np.allclose(ground[:, 2], 0.0, atol=FLOAT32_ATOL_M)
        ends_on_ground = strips[np.abs(strips[:, 1, 2]) < FLOAT32_ATOL_M, 1]
        assert np.allclose(ends_on_ground, ground, atol=FLOAT32_ATOL_M)


def test_error_segments_join_each_truth_to_its_estimate(recorded):
    spec, result, rrd, _ = recorded
    cones_w = np.array(spec.scene.cones_w)
    for method in ("depth_image", "ground_plane", "known_height", "naive"):
        rows = {
            r["tick"]: np.array(r["LineStrips3D:strips"]).reshape(-1, 2, 3)
            for r in read_rows(rrd, f"world/cones/error/{method}")
            if "tick" in r
        }
        points = {
            r["tick"]: np.array(r["Points3D:positions"]).reshape(-1, 3)
            for r in read_rows(rrd, f"world/cones/estimate/{method}")
            if "tick" in r
        }
        for f in _sampled_ticks(result):
            segments = rows[f.tick]
            scored = [d for d in f.detections if method in d.errors_m]
            assert len(segments) == len(scored)
            for s, d in zip(segments, scored, strict=True):
                assert np.allclose(s[0], cones_w[d.cone_index], atol=FLOAT32_ATOL_M)
                assert np.min(np.linalg.norm(points[f.tick] - s[1], axis=1)) < FLOAT32_ATOL_M
                assert np.linalg.norm(s[1] - s[0]) == pytest.approx(
                    d.errors_m[method], abs=FLOAT32_ATOL_M
                )


def test_naive_estimate_drawn_from_the_drone(recorded):
    """The naive estimate t_w_b + p_c hangs off the drone (where the estimator believes it
    is), so it can always be found from the drone, however far off it is."""
    _, result, rrd, _ = recorded
    rows = {
        r["tick"]: np.array(r["LineStrips3D:strips"]).reshape(-1, 2, 3)
        for r in read_rows(rrd, "world/naive_offset")
        if "tick" in r
    }
    for f in _sampled_ticks(result):
        segments = rows[f.tick]
        assert len(segments) == len(f.estimates_w("naive"))
        assert np.allclose(segments[:, 0], f.T_w_b_est[:3, 3], atol=FLOAT32_ATOL_M)
        assert np.allclose(segments[:, 1], f.estimates_w("naive"), atol=FLOAT32_ATOL_M)


_NUMBER = r"-?\d+\.\d+"


def _panel_vector(text: str, label: str) -> np.ndarray:
    """The bracketed vector that follows ``label`` in the state panel."""
    match = re.search(re.escape(label) + r"[^\[]*\[([^\]]*)\]", text)
    assert match, f"{label!r} not in the state panel"
    return np.array([float(x) for x in match.group(1).split()])


def test_state_panel_shows_the_chain_at_each_tick(recorded):
    """Parse the panel's numbers back and hold them against MuJoCo at sampled ticks and SciPy
    (test-only oracle) for the attitude: T_w_b, T_b_c, T_w_c; cone 0 in camera, body and
    world; roll/pitch/yaw, the quaternion and the axis-angle."""
    from scipy.spatial.transform import Rotation

    spec, result, rrd, _ = recorded
    panels = {r["tick"]: r["TextDocument:text"][0] for r in read_rows(rrd, "state") if "tick" in r}
    assert sorted(panels) == [f.tick for f in result.ticks]
    cone0_w = np.array(spec.scene.cones_w[0], dtype=np.float64)
    for f in _sampled_ticks(result):
        text = panels[f.tick]
        world = _world_at(spec, f)
        T_w_c = mujoco_T_w_c(world)
        T_w_b = world.T_w_b
        lines = text.split("```")[1].strip("\n").splitlines()
        numbers = np.array([[float(x) for x in re.findall(_NUMBER, ln)] for ln in lines[1:5]])
        assert numbers.shape == (4, 12)
        for k, T in enumerate((T_w_b, se3.invert(T_w_b) @ T_w_c, T_w_c)):
            shown = numbers[:, 4 * k : 4 * k + 4]
            assert np.allclose(shown[:, :3], T[:, :3], atol=5e-4 + 1e-9)  # 3 decimals
            assert np.allclose(shown[:, 3], T[:, 3], atol=5e-3 + 1e-9)  # centimetres

        p_c = se3.apply(se3.invert(T_w_c), cone0_w)
        assert np.allclose(_panel_vector(text, "p_c "), p_c, atol=5e-3 + 1e-9)
        assert np.allclose(
            _panel_vector(text, "p_b = T_b_c p_c"),
            se3.apply(se3.invert(T_w_b), cone0_w),
            atol=5e-3 + 1e-9,
        )
        assert np.allclose(_panel_vector(text, "p_w = T_w_b p_b"), cone0_w, atol=5e-3 + 1e-9)
        assert np.allclose(_panel_vector(text, "t_w_b + p_c"), T_w_b[:3, 3] + p_c, atol=5e-3 + 1e-9)

        rotation = Rotation.from_matrix(T_w_b[:3, :3])
        with warnings.catch_warnings():  # SciPy warns at the lock; the branch below handles it
            warnings.simplefilter("ignore", UserWarning)
            yaw, pitch, roll = rotation.as_euler("ZYX", degrees=True)
        shown_rpy = np.array(
            [float(re.search(rf"{n}\s+({_NUMBER})", text).group(1)) for n in ("roll", "pitch")]
            + [float(re.search(rf"yaw\s+({_NUMBER})", text).group(1))]
        )
        wrapped_deg = (shown_rpy - [roll, pitch, yaw] + 180.0) % 360.0 - 180.0  # -180 is 180
        if "gimbal lock: no" in text:
            assert np.all(np.abs(wrapped_deg) < 0.05 + 1e-9)
        else:  # at the lock only the pitch and one combination of roll and yaw are defined
            assert abs(wrapped_deg[1]) < 0.05 + 1e-9
        q = _panel_vector(text, "quaternion xyzw")
        q_true = rotation.as_quat()
        assert min(np.abs(q - q_true).max(), np.abs(q + q_true).max()) < 5e-4 + 1e-9
        angle_deg = float(re.search(rf"angle\s+({_NUMBER}) deg", text).group(1))
        if "axis any (no rotation)" in text:  # no axis is printed for no rotation
            assert angle_deg == 0.0 and rotation.magnitude() < np.radians(0.05)
            continue
        axis = _panel_vector(text, "axis-angle  axis")
        shown_R = Rotation.from_rotvec(np.radians(angle_deg) * axis / np.linalg.norm(axis))
        assert (shown_R.inv() * rotation).magnitude() < np.radians(0.15)


def test_quaternion_plotted_with_a_continuous_sign(recorded):
    """q and -q are one rotation: the plotted quaternion never jumps between them, and each
    value is the body's attitude (SciPy's, up to that sign)."""
    from scipy.spatial.transform import Rotation

    _, result, rrd, _ = recorded
    rows = [r for r in read_rows(rrd, "attitude/quat_xyzw") if "tick" in r]
    q = np.array([r["Scalars:scalars"] for r in rows])
    assert len(q) == len(result.ticks)
    assert np.all(np.einsum("ij,ij->i", q[1:], q[:-1]) > 0.0)
    q_true = Rotation.from_matrix(np.array([f.T_w_b[:3, :3] for f in result.ticks])).as_quat()
    assert np.allclose(np.abs(np.einsum("ij,ij->i", q, q_true)), 1.0, atol=1e-9)
    signs = [r["StateChange:state"][0] for r in read_rows(rrd, "attitude/quat_sign") if "tick" in r]
    assert signs == ["w<0" if x[3] < 0.0 else "w>=0" for x in q]
    locks = [
        r["StateChange:state"][0] for r in read_rows(rrd, "attitude/gimbal_lock") if "tick" in r
    ]
    assert locks == ["locked" if f.gimbal_locked else "free" for f in result.ticks]


def test_depth_for_display_keeps_depth_to_a_64th_and_draws_no_return_as_far():
    from scenarios.record.recording import DEPTH_METER, depth_for_display_mm

    depth_m = np.geomspace(0.05, 65.0, 2000)
    shown_m = depth_for_display_mm(depth_m).astype(np.float64) / DEPTH_METER
    assert np.all(np.abs(shown_m - depth_m) <= depth_m / 64 + 0.5 / DEPTH_METER)
    far = depth_for_display_mm(np.array([70.0, np.inf, np.nan]))
    assert np.all(far == np.iinfo(np.uint16).max)  # the sky is far, not 0 m (nearest)


# ------------------------------------------------------------------ time: stamps and latency


def _latency_run(builtin_runs):
    """The built-in run whose images arrive late (its [timing] is not synchronous)."""
    run = builtin_runs["latency"]
    assert not run.spec.timing.synchronous
    return run


def _timed_rows(rrd, path: str) -> list[dict]:
    """The rows of ``path`` logged on a timeline (static style rows left out)."""
    return [r for r in read_rows(rrd, path) if "sim_time" in r]


def _yaw_deg(T_w_b: np.ndarray) -> np.ndarray:
    """Yaw of body poses (N, 4, 4) in degrees, by SciPy (intrinsic z-y'-x'')."""
    from scipy.spatial.transform import Rotation

    R_w_b = np.asarray(T_w_b, dtype=np.float64).reshape(-1, 4, 4)[:, :3, :3]
    return Rotation.from_matrix(R_w_b).as_euler("ZYX", degrees=True)[:, 0]


def test_each_image_logged_at_its_exposure_time(recorded):
    """The image is on sim_time at its true exposure: its camera-clock stamp plus the
    scenario's clock offset (not its arrival), and on tick at its tick."""
    spec, result, rrd, _ = recorded
    rows = [r for r in read_rows(rrd, "world/body/camera/image") if "tick" in r]
    assert [r["tick"] for r in rows] == [f.tick for f in result.ticks]
    offset_s = spec.timing.camera_clock_offset_s
    for row, f in zip(rows, result.ticks, strict=True):
        exposure_s = f.timing.stamp_cam_s + offset_s
        assert row["sim_time"] == pytest.approx(exposure_s * 1e9, abs=1e3)
        assert f.t_s == pytest.approx(exposure_s, abs=1e-9)
        # It arrives no earlier than its exposure, later when the link has a latency (a clock
        # offset alone changes the stamp, not the arrival).
        assert f.timing.arrival_s >= exposure_s
        if spec.timing.image_latency_s > 0.0:
            assert f.timing.arrival_s > exposure_s


def test_newest_pose_drawn_only_for_runs_with_latency(recorded):
    """Where nothing arrives late the newest pose is the exposure pose: no second estimate, no
    error series for it, no pose-stream plots; a synchronous run's panel says so in one line.
    A run with latency has all of them, and any run off the synchronous clocks (a clock
    offset) a time block in its panel instead."""
    spec, result, rrd, _ = recorded
    paths = ("/world/cones/newest_pose/**", "/metrics/newest_pose/**", "/time/**")
    panels = [r["TextDocument:text"][0] for r in read_rows(rrd, "state") if "tick" in r]
    synchronous_note = "image processed at its exposure: no latency"
    assert len(panels) == len(result.ticks)
    if not spec.timing.delivers_late:
        for path in paths:
            assert read_rows(rrd, path) == [], path
        assert all(t.timing.latest_minus_exposure_s in (0.0, None) for t in result.ticks)
    else:
        for path in paths:
            assert _timed_rows(rrd, path), path
    if spec.timing.synchronous:
        assert all(synchronous_note in p.split("\n")[0] for p in panels)
        assert all("camera clock" not in p for p in panels)
    else:
        assert all(synchronous_note not in p and "camera clock" in p for p in panels)


def test_newest_pose_estimate_is_the_same_ray_moved_by_the_stale_pose(builtin_runs):
    """Both estimates come from one detection and one depth image, so the camera-frame point
    is the same: the newest-pose one is the exposure one moved by T_w_b_latest T_w_b_est^-1.
    Computed here from the logged depth_image points, held against the logged violet points,
    their segments from the true cones and the plotted error."""
    run = _latency_run(builtin_runs)
    cones_w = np.array(run.spec.scene.cones_w)
    newest = {r["tick"]: r for r in _timed_rows(run.rrd, "world/cones/newest_pose/estimate")}
    segments = {r["tick"]: r for r in _timed_rows(run.rrd, "world/cones/newest_pose/error")}
    errors = {r["tick"]: r for r in _timed_rows(run.rrd, "metrics/newest_pose/error")}
    exposure = {r["tick"]: r for r in _timed_rows(run.rrd, "world/cones/estimate/depth_image")}
    assert sorted(newest) == sorted(errors) == [f.tick for f in run.result.ticks]
    largest_apart_m = 0.0
    for f in run.result.ticks:
        scored = [d for d in f.detections if d.latest_w is not None]
        points = np.array(newest[f.tick]["Points3D:positions"] or []).reshape(-1, 3)
        strips = np.array(segments[f.tick]["LineStrips3D:strips"] or []).reshape(-1, 2, 3)
        assert len(points) == len(strips) == len(scored)
        if not scored:
            assert np.isnan(errors[f.tick]["Scalars:scalars"][0])
            continue
        # Every newest-pose estimate is of a detection that also has a depth_image estimate.
        logged_w = np.array(exposure[f.tick]["Points3D:positions"]).reshape(-1, 3)
        T_stale = f.timing.T_w_b_latest @ se3.invert(f.T_w_b_est)
        expected_w = []
        for d in scored:
            k = np.argmin(np.linalg.norm(logged_w - d.estimates_w["depth_image"], axis=1))
            expected_w.append(se3.apply(T_stale, logged_w[k].astype(np.float64)))
        assert np.allclose(points, expected_w, atol=1e-4)
        assert np.allclose(points, [d.latest_w for d in scored], atol=FLOAT32_ATOL_M)
        assert np.allclose(strips[:, 0], cones_w[[d.cone_index for d in scored]], atol=1e-6)
        assert np.allclose(strips[:, 1], points, atol=1e-6)
        lengths_m = np.linalg.norm(strips[:, 1] - strips[:, 0], axis=1)
        assert errors[f.tick]["Scalars:scalars"][0] == pytest.approx(
            float(np.mean(lengths_m)), abs=FLOAT32_ATOL_M
        )
        apart_m = np.linalg.norm(points - [d.estimates_w["depth_image"] for d in scored], axis=1)
        largest_apart_m = max(largest_apart_m, float(apart_m.max()))
    # The fast yaw's lesson: about range |omega| dt = 6 m * 1.7 rad/s * 0.05 s apart.
    assert largest_apart_m > 0.3


def test_pose_samples_plotted_at_their_stamps(builtin_runs):
    """Every pose sample the estimator was sent is on sim_time at its stamp (one column, on no
    tick): its yaw (SciPy's) and its position."""
    run = _latency_run(builtin_runs)
    poses = run.result.poses
    for quantity, expected in (
        ("yaw_deg", _yaw_deg(poses.T_w_b)[:, None]),
        ("position_m", poses.T_w_b[:, :3, 3]),
    ):
        rows = _timed_rows(run.rrd, f"time/{quantity}/pose_samples")
        assert all("tick" not in r for r in rows)
        stamps_ns = np.array([r["sim_time"] for r in rows])
        assert len(stamps_ns) == len(poses.stamps_s)
        assert np.allclose(stamps_ns, poses.stamps_s * 1e9, atol=1e3)
        values = np.array([r["Scalars:scalars"] for r in rows])
        assert np.allclose(values, expected, atol=1e-9)
    # The samples are the stream's: 1 / pose_rate_hz apart.
    assert np.allclose(np.diff(poses.stamps_s), 1.0 / run.spec.timing.pose_rate_hz, atol=1e-9)


def test_exposure_and_arrival_marked_on_the_pose_stream(builtin_runs):
    """Each image's exposure is marked with the pose it was given, its arrival with the newest
    pose received by then: the arrival comes image_latency_s (plus jitter) after the exposure,
    and the newest pose is a sample of the stream, stamped ahead of the exposure."""
    run = _latency_run(builtin_runs)
    ticks, poses, timing = run.result.ticks, run.result.poses, run.spec.timing
    exposure = _timed_rows(run.rrd, "time/yaw_deg/exposure")
    arrival = _timed_rows(run.rrd, "time/yaw_deg/arrival")
    arrival_xyz = _timed_rows(run.rrd, "time/position_m/arrival")
    assert len(exposure) == len(arrival) == len(arrival_xyz) == len(ticks)
    exposure_s = np.array([r["sim_time"] for r in exposure]) / 1e9
    arrival_s = np.array([r["sim_time"] for r in arrival]) / 1e9
    assert np.allclose(exposure_s, [f.t_s for f in ticks], atol=1e-6)
    assert np.allclose(arrival_s, [f.timing.arrival_s for f in ticks], atol=1e-6)
    # Late by the configured latency; jitter is Gaussian with jitter_s: 5 sigma is generous.
    late_s = arrival_s - exposure_s
    assert np.all(np.abs(late_s - timing.image_latency_s) < 5.0 * timing.jitter_s + 1e-6)
    assert np.allclose(
        [r["Scalars:scalars"][0] for r in exposure],
        _yaw_deg(np.array([f.T_w_b_est for f in ticks])),
        atol=1e-9,
    )
    for row, row_xyz, f in zip(arrival, arrival_xyz, ticks, strict=True):
        j = int(np.argmin(np.abs(poses.stamps_s - f.timing.latest_pose_s)))
        assert poses.stamps_s[j] == pytest.approx(f.timing.latest_pose_s, abs=1e-12)
        assert poses.arrivals_s[j] <= f.timing.arrival_s  # it had arrived
        assert row["Scalars:scalars"][0] == pytest.approx(_yaw_deg(poses.T_w_b[j])[0], abs=1e-9)
        assert np.allclose(row_xyz["Scalars:scalars"], poses.T_w_b[j][:3, 3], atol=1e-9)
        # Newest: no sample stamped after it had arrived by then.
        later = poses.stamps_s > f.timing.latest_pose_s
        assert np.all(poses.arrivals_s[later] > f.timing.arrival_s)
        assert f.timing.latest_pose_s > f.t_s  # ahead of the exposure pose


_TIME_BLOCK = re.compile(
    rf"exposure\s+({_NUMBER}) s camera clock = ({_NUMBER}) s pose clock "
    r"\(t_pose = t_cam ([+-]) (\d+) ms\)\n"
    rf"\s+arrival\s+({_NUMBER}) s, (\d+) ms after the exposure\n"
    rf"\s+poses\s+used: ({_NUMBER}) s, the exposure stamp\s+newest: ({_NUMBER}) s, "
    r"(\d+) ms ahead of it\n"
    rf"\s+motion\s+between the two the body moved ({_NUMBER}) m and turned ({_NUMBER}) deg"
)


def test_state_panel_time_block_matches_the_stamps(builtin_runs):
    """The latency run's panel shows, per tick, the stamps of the records: exposure on both
    clocks (their difference the scenario's clock offset), arrival and latency, the pose
    used and the newest pose with its lead, and the true motion in between."""
    run = _latency_run(builtin_runs)
    panels = {
        r["tick"]: r["TextDocument:text"][0] for r in read_rows(run.rrd, "state") if "tick" in r
    }
    offset_ms = 1e3 * run.spec.timing.camera_clock_offset_s
    for f in run.result.ticks:
        match = _TIME_BLOCK.search(panels[f.tick])
        assert match, panels[f.tick]
        cam_s, pose_s, sign, shown_offset_ms, arr_s, late_ms, used_s, new_s, lead_ms = (
            match.groups()[:9]
        )
        t = f.timing
        assert float(cam_s) == pytest.approx(t.stamp_cam_s, abs=5e-4 + 1e-9)
        assert float(pose_s) == pytest.approx(f.t_s, abs=5e-4 + 1e-9)
        assert float(sign + shown_offset_ms) == pytest.approx(offset_ms, abs=0.5 + 1e-9)
        assert float(arr_s) == pytest.approx(t.arrival_s, abs=5e-4 + 1e-9)
        assert float(late_ms) == pytest.approx(1e3 * (t.arrival_s - f.t_s), abs=0.5 + 1e-9)
        assert float(used_s) == pytest.approx(f.t_s, abs=5e-4 + 1e-9)
        assert float(new_s) == pytest.approx(t.latest_pose_s, abs=5e-4 + 1e-9)
        assert float(lead_ms) == pytest.approx(1e3 * t.latest_minus_exposure_s, abs=0.5 + 1e-9)
        assert float(match.group(10)) == pytest.approx(t.true_motion_m, abs=5e-4 + 1e-9)
        assert float(match.group(11)) == pytest.approx(
            np.degrees(t.true_motion_rad), abs=0.05 + 1e-9
        )


def test_ellipsoids_rebuild_each_estimates_covariance(builtin_runs):
    """The uncertainty built-in's recording: at every tick, each checked method's ellipsoids
    sit on its estimates, and ``R diag((h / 3)^2) R^T`` from the logged quaternion (turned into
    a matrix by SciPy) and half-sizes ``h`` gives back the run's covariance (float32 in the
    file: 1e-4 relative)."""
    from scipy.spatial.transform import Rotation

    run = builtin_runs["uncertainty"]
    checked = 0
    for method in ("depth_image", "ground_plane", "known_height"):
        rows = {
            r["tick"]: r
            for r in read_rows(run.rrd, f"world/cones/uncertainty/{method}")
            if "tick" in r
        }
        for tick in run.result.ticks:
            dets = [d for d in tick.detections if method in d.covariances_w]
            if not dets:
                continue
            row = rows[tick.tick]
            centers = np.array(row["Ellipsoids3D:centers"], dtype=np.float64)
            halves = np.array(row["Ellipsoids3D:half_sizes"], dtype=np.float64)
            quats = np.array(row["Ellipsoids3D:quaternions"], dtype=np.float64)
            for d, c, h, q in zip(dets, centers, halves, quats, strict=True):
                np.testing.assert_allclose(c, d.estimates_w[method], atol=FLOAT32_ATOL_M)
                R = Rotation.from_quat(q).as_matrix()
                rebuilt = R @ np.diag((h / 3.0) ** 2) @ R.T
                cov = d.covariances_w[method]
                np.testing.assert_allclose(rebuilt, cov, atol=1e-4 * np.abs(cov).max())
                checked += 1
    assert checked > 50


def test_nees_mean_and_band_at_the_last_tick_are_the_reports(builtin_runs):
    """The NEES tab's running mean and band, read back at the last tick, are the JSON report's
    mean NEES and band for each method (one figure, two files)."""
    run = builtin_runs["uncertainty"]
    last = run.result.ticks[-1].tick
    for method in ("depth_image", "ground_plane", "known_height"):
        summary = run.report["methods"][method]["nees"]
        (mean_row,) = [
            r for r in read_rows(run.rrd, f"metrics/nees_mean/{method}") if r.get("tick") == last
        ]
        (band_row,) = [
            r for r in read_rows(run.rrd, f"metrics/nees_band/{method}") if r.get("tick") == last
        ]
        assert mean_row["Scalars:scalars"][0] == pytest.approx(summary["mean"], rel=1e-9)
        assert band_row["Scalars:scalars"] == pytest.approx(summary["band"], rel=1e-6)


@pytest.mark.parametrize("x", [1e-4, 0.0575, 0.0999, 0.1, 0.2006, 0.42, 0.56, 1.0, 3.7, 8.4, 250.0])
def test_plot_axis_tops_hold_a_labelled_tick(x):
    """The viewer labels its y ticks at powers of ten some 20 pixels apart, never at the very
    top: an axis from 0 must hold a power of ten p <= top (inside) with top / p small enough
    (<= 2.3) that p is labelled in a 60-pixel plot, and must show x."""
    from scenarios.record.recording import _axis_top

    top = _axis_top(x)
    assert top >= x
    p = 10.0 ** np.floor(np.log10(top))
    assert p < top and top / p <= 2.3
    assert top <= 11.2 * x + 1e-12  # and the data is not squashed beyond a tenth of it
