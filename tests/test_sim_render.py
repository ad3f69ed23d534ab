"""Rendering against ground truth: sphere centroids vs the intrinsics, depth vs the ground plane
and the cone's analytic surface, and the drone invisible to its own camera."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import mujoco_T_w_c
from scipy.spatial.transform import Rotation

import sim.render
from sim import names
from sim.config import MAX_FOVY_DEG, MIN_FOVY_DEG, CameraConfig, SceneConfig
from sim.gl import mujoco
from sim.render import Renderer
from sim.world import World, build_spec
from vnav.cone import TRAFFIC_CONE


def _pixel_grid(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """(v, u) of every pixel centre, OpenCV convention."""
    v, u = np.mgrid[0:height, 0:width]
    return v.astype(np.float64), u.astype(np.float64)


def _back_project_w(world: World, depth: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """World points of the masked pixels through the intrinsics, T_b_c and T_w_b: (N, 3)."""
    v, u = _pixel_grid(*depth.shape)
    cam = world.camera
    z = depth[mask].astype(np.float64)
    p_c = np.column_stack([(u[mask] - cam.cx) * z / cam.fx, (v[mask] - cam.cy) * z / cam.fy, z])
    T_w_c = world.T_w_b @ world.T_b_c
    return p_c @ T_w_c[:3, :3].T + T_w_c[:3, 3]


@pytest.mark.parametrize(
    ("width", "height", "fovy_deg"),
    [
        (640, 480, 45.0),
        (320, 240, 60.0),
        (641, 479, 50.0),
        (640, 360, 90.0),
        (1024, 769, 70.0),
        (640, 480, MIN_FOVY_DEG),  # the narrowest accepted: still within 0.05 px
    ],
)
def test_sphere_centroids_match_projection(width: int, height: int, fovy_deg: float) -> None:
    cfg = SceneConfig(
        camera=CameraConfig(
            position_b=(0.1, 0.02, 0.03),
            pitch_down_deg=12.0,
            fovy_deg=fovy_deg,
            width=width,
            height=height,
        ),
        cones_w=(),
        start_position_w=(3.0, -2.0, 60.0),
        start_quat_xyzw=tuple(Rotation.from_euler("zyx", [30, 4, -7], degrees=True).as_quat()),
    )
    # Where MuJoCo puts the camera (its own cam_xpos / cam_xmat) and the expected intrinsics
    # from the documented formula, independent of the code under test.
    probe = World.from_config(cfg)
    T_w_c = mujoco_T_w_c(probe)
    f_px = (height / 2.0) / math.tan(math.radians(fovy_deg) / 2.0)
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    np.testing.assert_allclose(probe.camera.K, [[f_px, 0, cx], [0, f_px, cy], [0, 0, 1]])

    rng = np.random.default_rng(width * 7919 + height)
    nx, ny = 8, 5
    uv_true, centres_w = [], []
    spec = build_spec(cfg)
    for j in range(ny):
        for i in range(nx):
            u = (i + 0.5 + rng.uniform(-0.3, 0.3)) * width / nx
            v = (j + 0.5 + rng.uniform(-0.3, 0.3)) * height / ny
            z = rng.uniform(4.0, 20.0)
            p_c = np.array([(u - cx) * z / f_px, (v - cy) * z / f_px, z])
            p_w = T_w_c[:3, :3] @ p_c + T_w_c[:3, 3]
            radius = 5.0 * z / f_px  # about 5 px
            spec.worldbody.add_geom(
                name=f"probe_{len(uv_true)}",
                type=mujoco.mjtGeom.mjGEOM_SPHERE,
                size=[radius, 0, 0],
                pos=list(p_w),
                contype=0,
                conaffinity=0,
            )
            uv_true.append((u, v))
            centres_w.append(p_w)
    world = World(spec, cfg)
    with Renderer(world) as renderer:
        seg = renderer.render(depth=False, segmentation=True).segmentation
    assert seg.shape == (height, width)
    v_px, u_px = _pixel_grid(height, width)
    offsets = []
    for k, (u, v) in enumerate(uv_true):
        mask = seg == world.model.geom(f"probe_{k}").id
        assert mask.sum() > 20, f"sphere {k} hardly visible"
        assert not (mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())
        offsets.append((u_px[mask].mean() - u, v_px[mask].mean() - v))
    offsets = np.array(offsets)
    mean_u, mean_v = offsets.mean(axis=0)
    assert abs(mean_u) <= 0.05, f"mean u offset {mean_u:.3f} px"
    assert abs(mean_v) <= 0.05, f"mean v offset {mean_v:.3f} px"
    assert np.median(np.linalg.norm(offsets, axis=1)) <= 0.25


def _cone_surface_distance_m(p_k: np.ndarray) -> np.ndarray:
    """Distance of points (cone frame, origin at the base centre, z up) to the cone's surface:
    a square plate [-a, a]^2 x [0, t] under a right circular cone of base radius R at z = t and
    apex at z = h. Only valid for points near the visible surface."""
    cone = TRAFFIC_CONE
    a, t = cone.base_width_m / 2.0, cone.base_thickness_m
    h, R = cone.height_m, cone.body_radius_m
    x, y, z = p_k.T
    r = np.hypot(x, y)
    # Plate: distance to the box surface (outside or on it).
    q = np.column_stack([np.abs(x) - a, np.abs(y) - a, np.abs(z - t / 2.0) - t / 2.0])
    d_plate = np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)
    # Cone: distance to the slanted side line in the (r, z) half plane.
    half_angle = math.atan2(R, h - t)
    d_side = (r - R * (h - z) / (h - t)) * math.cos(half_angle)
    d_cone = np.where((z >= t) & (z <= h), np.abs(d_side), np.inf)
    return np.minimum(np.abs(d_plate), d_cone)


def test_depth_back_projects_onto_ground_and_cone_surfaces() -> None:
    R_w_b = Rotation.from_euler(
        "zyx", [35.0, -8.0, 12.0], degrees=True
    ).as_matrix()  # yaw, pitch, roll
    p_w_b = np.array([1.0, -2.0, 4.0])
    cam_cfg = CameraConfig(pitch_down_deg=35.0, fovy_deg=60.0)
    # Put cones where the camera looks: ground points along chosen pixels' rays.
    R_b_c = Rotation.from_euler("y", 35.0, degrees=True).as_matrix() @ np.array(
        [[0, 0, 1], [-1, 0, 0], [0, -1, 0]], dtype=float
    )
    R_w_c = R_w_b @ R_b_c
    o_w = p_w_b + R_w_b @ np.array(cam_cfg.position_b)
    f_px = 240.0 / math.tan(math.radians(30.0))
    cones = []
    for u, v in [(320.0, 240.0), (150.0, 300.0), (500.0, 330.0), (420.0, 250.0)]:
        d_w = R_w_c @ np.array([(u - 319.5) / f_px, (v - 239.5) / f_px, 1.0])
        s = -o_w[2] / d_w[2]
        assert s > 0
        cones.append((float(o_w[0] + s * d_w[0]), float(o_w[1] + s * d_w[1]), 0.0))
    world = World.from_config(SceneConfig(camera=cam_cfg, cones_w=tuple(cones)))
    T_w_b = np.eye(4)
    T_w_b[:3, :3], T_w_b[:3, 3] = R_w_b, p_w_b
    world.set_pose(T_w_b)
    with Renderer(world) as renderer:
        frame = renderer.render(depth=True, segmentation=True)
    assert frame.depth.dtype == np.float32 and frame.rgb.dtype == np.uint8
    assert frame.rgb.shape == (480, 640, 3) and frame.depth.shape == (480, 640)

    ground = frame.segmentation == world.model.geom(names.GROUND_GEOM).id
    assert ground.sum() > 100_000
    z_w = _back_project_w(world, frame.depth, ground)[:, 2]
    assert np.max(np.abs(z_w)) < 0.01, f"ground z off by up to {np.max(np.abs(z_w)):.4f} m"

    for i, p_cone_w in enumerate(cones):
        mask = np.isin(frame.segmentation, world.cone_geom_ids[i])
        assert mask.sum() > 100, f"cone {i} covers only {mask.sum()} px"
        p_k = _back_project_w(world, frame.depth, mask) - np.array(p_cone_w)
        dist = _cone_surface_distance_m(p_k)
        # The rendered body is a 64-sided pyramid: at most R (1 - cos(pi/64)) = 0.2 mm inside.
        assert np.median(dist) < 0.002 and np.max(dist) < 0.01, (np.median(dist), dist.max())


def test_the_widest_field_of_view_still_renders_the_ground_where_it_is() -> None:
    """At ``MAX_FOVY_DEG``, looking down from 3 m: every pixel sees the ground, and its depth
    back-projects through the pinhole intrinsics onto z = 0."""
    cfg = SceneConfig(
        camera=CameraConfig(pitch_down_deg=89.0, fovy_deg=MAX_FOVY_DEG),
        cones_w=(),
        start_position_w=(0.0, 0.0, 3.0),
    )
    world = World.from_config(cfg)
    with Renderer(world) as renderer:
        frame = renderer.render(segmentation=True)
    ground = frame.segmentation == world.model.geom(names.GROUND_GEOM).id
    assert ground.all()
    z_w = _back_project_w(world, frame.depth, ground)[:, 2]
    assert np.max(np.abs(z_w)) < 1e-4, f"ground z off by up to {np.max(np.abs(z_w)):.2e} m"


@pytest.mark.parametrize("decoration_geoms", [sim.render.DECORATION_GEOMS, -30])
def test_a_thousand_and_one_cones_are_all_drawn(monkeypatch, decoration_geoms: int) -> None:
    """1,001 cones (2,002 geoms) on a grid under a camera looking straight down from 50 m:
    each one's shell is in the segmentation. A fixed buffer of 2,000 geoms left the last
    out; a buffer sized too small (a negative margin) grows until the scene fits."""
    monkeypatch.setattr(sim.render, "DECORATION_GEOMS", decoration_geoms)
    x_w, y_w = np.meshgrid((np.arange(33) - 16) * 1.6, (np.arange(31) - 15) * 1.6)
    cones_w = tuple(
        (float(x), float(y), 0.0) for x, y in zip(x_w.ravel(), y_w.ravel(), strict=True)
    )[:1001]
    cfg = SceneConfig(
        camera=CameraConfig(pitch_down_deg=90.0, position_b=(0.0, 0.0, 0.0)),
        cones_w=cones_w,
        start_position_w=(0.0, 0.0, 50.0),
    )
    world = World.from_config(cfg)
    # Every cone is in the image by the projection of its base centre (independent of MuJoCo).
    T_c_w = np.linalg.inv(world.T_w_b @ world.T_b_c)
    p_c = np.asarray(cones_w) @ T_c_w[:3, :3].T + T_c_w[:3, 3]
    uv = p_c[:, :2] / p_c[:, 2:] * world.camera.fx + [world.camera.cx, world.camera.cy]
    assert np.all((uv > 5.0) & (uv < [634.0, 474.0]))
    with Renderer(world) as renderer:
        seg = renderer.render(depth=False, segmentation=True).segmentation
    drawn = np.isin(world.cone_geom_ids[:, 1], seg)
    assert drawn.all(), f"cones not drawn: {np.flatnonzero(~drawn).tolist()}"


def test_sky_depth_reads_the_far_plane() -> None:
    cfg = SceneConfig(camera=CameraConfig(pitch_down_deg=-20.0, width=160, height=120), cones_w=())
    world = World.from_config(cfg)
    with Renderer(world) as renderer:
        frame = renderer.render(segmentation=True)
    sky = frame.segmentation == -1
    assert sky.mean() > 0.3
    np.testing.assert_array_equal(frame.depth[sky], np.float32(cfg.zfar_m))
    assert np.all(frame.depth[~sky] < 0.5 * cfg.zfar_m)


def test_onboard_camera_never_sees_its_drone_but_chase_view_does() -> None:
    # Camera at the body origin, inside the hull: a housing-blind camera still sees the world.
    cfg = SceneConfig(
        camera=CameraConfig(
            position_b=(0.0, 0.0, 0.0), pitch_down_deg=60.0, fovy_deg=120.0, width=320, height=240
        )
    )
    world = World.from_config(cfg)
    drone_id = world.model.body(names.DRONE_BODY).id
    drone_geoms = np.nonzero(world.model.geom_bodyid == drone_id)[0]
    assert drone_geoms.size >= 5
    assert np.all(world.model.geom_group[drone_geoms] == names.DRONE_GEOM_GROUP)
    with Renderer(world) as renderer:
        onboard = renderer.render(segmentation=True)
        chase = renderer.render(segmentation=True, camera=names.CHASE_CAMERA)
        free = renderer.render(
            segmentation=True,
            camera=renderer.free_camera(world.T_w_b[:3, 3], 3.0, 120.0, -30.0),
        )
    assert not np.isin(onboard.segmentation, drone_geoms).any()
    assert (onboard.segmentation == world.model.geom(names.GROUND_GEOM).id).mean() > 0.5
    assert np.isin(chase.segmentation, drone_geoms).sum() > 50
    assert np.isin(free.segmentation, drone_geoms).sum() > 50


def test_one_pass_rgb_matches_rgb_only_and_high_quality_works() -> None:
    world = World.from_config(SceneConfig(camera=CameraConfig(width=320, height=240)))
    with Renderer(world) as renderer:
        both = renderer.render(depth=True)
        rgb_only = renderer.render(depth=False)
    np.testing.assert_array_equal(both.rgb, rgb_only.rgb)
    assert rgb_only.depth is None and rgb_only.segmentation is None
    with Renderer(world, quality="high") as renderer:
        high = renderer.render()
    assert high.rgb.shape == (240, 320, 3)
    # Multisampled depth is resolved from sub-samples: close to, not exactly, pixel centres.
    near = both.depth < 30.0
    assert near.mean() > 0.5
    rel = np.abs(high.depth[near] / both.depth[near] - 1.0)
    assert np.median(rel) < 0.01


def test_cones_render_orange() -> None:
    cfg = SceneConfig(
        camera=CameraConfig(pitch_down_deg=20.0, width=320, height=240),
        cones_w=((3.0, 0.0, 0.0),),
        start_position_w=(0.0, 0.0, 1.5),
    )
    world = World.from_config(cfg)
    with Renderer(world) as renderer:
        frame = renderer.render(segmentation=True)
    mask = np.isin(frame.segmentation, world.cone_geom_ids[0])
    r, g, b = frame.rgb[mask].astype(float).mean(axis=0) / 255.0
    assert r > 0.6 and b < 0.15 and 0.15 < g / r < 0.6, (r, g, b)


def test_renderer_rejects_nonsense() -> None:
    world = World.from_config(SceneConfig(camera=CameraConfig(width=160, height=120)))
    with pytest.raises(ValueError, match="quality"):
        Renderer(world, quality="ultra")
    with pytest.raises(ValueError, match="width"):
        Renderer(world, width=100_000)
    with Renderer(world) as renderer:
        with pytest.raises(ValueError, match="unknown camera 'nose'"):
            renderer.render(camera="nose")
    with pytest.raises(RuntimeError, match="after close"):
        renderer.render()
