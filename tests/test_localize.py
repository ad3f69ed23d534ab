"""Cone localisation against the simulator's ground truth (issue 4's accuracy contract).

Poses are drawn from a seeded generator and kept by the TRUE geometry only (the whole cone in
view with a 2 px margin, at least 12 px tall, range 2-25 m, drone height 2-15 m); every kept
pose must then give exactly one detection. A second, shallow set (drone height 2-4 m, range
8-25 m, camera pitch 0-20 deg: lines of sight 5-30 deg below the horizontal, where a 1 px
error in the apex is 4-7% of range) is drawn the same way. The per-method error statistics
of both sets are printed and attached to the test report (`record_property`).
"""

from __future__ import annotations

import itertools
import logging

import numpy as np
import pytest

from sim.config import CameraConfig, SceneConfig
from sim.render import Renderer
from sim.world import World
from vnav import se3, so3
from vnav.camera import PinholeCamera, depth_to_world_points
from vnav.cone import TRAFFIC_CONE
from vnav.detect import ConeDetection, detect_cones
from vnav.estimators import (
    MAX_RANGE_ERROR_PER_PX,
    MIN_TRIANGLE_FRACTION,
    estimate_from_depth,
    estimate_from_ground_plane,
    estimate_from_known_height,
)
from vnav.localize import localize
from vnav.methods import METHOD_NAMES
from vnav.metrics import error_stats, horizontal_error
from vnav.silhouette import apex_pixel, triangle_fraction

logger = logging.getLogger(__name__)

CAMERA_PITCHES_DEG = (0.0, 20.0, 40.0, 60.0, 80.0)
POSES_PER_PITCH = 60
SEED = 4
SHALLOW_CAMERA_PITCHES_DEG = (0.0, 10.0, 20.0)
SHALLOW_POSES_PER_PITCH = 40
SHALLOW_HEIGHTS_M = (2.0, 4.0)
SHALLOW_RANGES_M = (8.0, 25.0)


def cone_corners_w(p0_w: np.ndarray) -> np.ndarray:
    """The cone's extreme points: the base plate's 8 corners and the apex, (9, 3), metres."""
    a, t = TRAFFIC_CONE.base_width_m / 2, TRAFFIC_CONE.base_thickness_m
    pts = [(sx * a, sy * a, z) for sx in (-1, 1) for sy in (-1, 1) for z in (0.0, t)]
    pts.append((0.0, 0.0, TRAFFIC_CONE.height_m))
    return np.array(pts) + p0_w


def sample_poses(
    world: World,
    rng: np.random.Generator,
    n: int,
    heights_m: tuple[float, float] = (2.0, 15.0),
    ranges_m: tuple[float, float] = (2.0, 25.0),
) -> list[tuple[np.ndarray, float]]:
    """`n` drone poses `(T_w_b, range_m)` that see the whole cone, chosen by true geometry.

    Roll and pitch uniform in +-30 deg, yaw all around; the base centre's pixel uniform over the
    image and its range uniform in `ranges_m` place the drone; kept if the camera's height is
    within `heights_m`, every corner of the cone projects inside the image with a 2 px margin
    and the cone's projection is at least 12 px tall.
    """
    camera, T_b_c = world.camera, world.T_b_c
    p0_w = world.cones_w[0]
    poses: list[tuple[np.ndarray, float]] = []
    while len(poses) < n:
        rpy = np.radians([rng.uniform(-30, 30), rng.uniform(-30, 30), rng.uniform(-180, 180)])
        R_w_b = so3.from_rpy(*rpy)
        uv = rng.uniform([0.0, 0.0], [camera.width - 1.0, camera.height - 1.0])
        d_w = R_w_b @ T_b_c[:3, :3] @ camera.rays(uv)[0]
        range_m = rng.uniform(*ranges_m)
        t_w_c = p0_w - range_m * d_w
        if not heights_m[0] <= t_w_c[2] <= heights_m[1]:
            continue
        T_w_b = se3.make(R_w_b, t_w_c - R_w_b @ T_b_c[:3, 3])
        uv_corners = camera.project(se3.apply(se3.invert(T_w_b @ T_b_c), cone_corners_w(p0_w)))
        if not camera.in_image(uv_corners, 2.0).all() or np.ptp(uv_corners[:, 1]) < 12.0:
            continue
        poses.append((T_w_b, range_m))
    return poses


def surface_residual_m(p_k: np.ndarray) -> np.ndarray:
    """Distance-like residual of points (cone frame, base centre origin) to the cone's surface.

    Points at the base plate's height inside its square count 0 distance from the plate; other
    points get their radial distance to the body, `|r - r(z)|`, metres.
    """
    c = TRAFFIC_CONE
    a, t, H, r0 = c.base_width_m / 2, c.base_thickness_m, c.height_m, c.body_radius_m
    on_plate = (p_k[:, 2] <= t + 2e-3) & (np.abs(p_k[:, :2]) <= a + 2e-3).all(axis=1)
    r_model = r0 * np.clip(H - p_k[:, 2], 0.0, H - t) / (H - t)
    body = np.abs(np.hypot(p_k[:, 0], p_k[:, 1]) - r_model)
    return np.where(on_plate, 0.0, body)


def _render_set(
    rng: np.random.Generator,
    pitches_deg: tuple[float, ...],
    per_pitch: int,
    heights_m: tuple[float, float],
    ranges_m: tuple[float, float],
) -> list[dict]:
    rows = []
    for pitch_deg in pitches_deg:
        world = World.from_config(SceneConfig(camera=CameraConfig(pitch_down_deg=pitch_deg)))
        far_m = 0.99 * world.model.vis.map.zfar * world.model.stat.extent
        p0_w = world.cones_w[0]
        with Renderer(world) as renderer:
            for T_w_b, range_m in sample_poses(world, rng, per_pitch, heights_m, ranges_m):
                world.set_pose(T_w_b)
                frame = renderer.render(depth=True)
                detections = detect_cones(frame.rgb)
                estimates = None
                if len(detections) == 1:
                    estimates = localize(
                        detections[0],
                        world.camera,
                        world.T_w_b,
                        world.T_b_c,
                        frame.depth,
                        far_m=far_m,
                    )
                rows.append(
                    {
                        "pitch_deg": pitch_deg,
                        "range_m": range_m,
                        "p0_w": p0_w,
                        "t_w_c": (world.T_w_b @ world.T_b_c)[:3, 3],
                        "n_detections": len(detections),
                        "estimates": estimates,
                    }
                )
    return rows


@pytest.fixture(scope="module")
def grid() -> dict:
    """Render every pose of the grid and of the shallow set once; localise its detection."""
    rng = np.random.default_rng(SEED)
    rows = _render_set(rng, CAMERA_PITCHES_DEG, POSES_PER_PITCH, (2.0, 15.0), (2.0, 25.0))
    shallow = _render_set(
        rng,
        SHALLOW_CAMERA_PITCHES_DEG,
        SHALLOW_POSES_PER_PITCH,
        SHALLOW_HEIGHTS_M,
        SHALLOW_RANGES_M,
    )
    return {"rows": rows, "shallow": shallow}


def _errors(rows: list[dict], method: str) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal errors (inf where the method gave none) and ranges, metres."""
    e, r = [], []
    for row in rows:
        p_w = getattr(row["estimates"], method)
        e.append(np.inf if p_w is None else horizontal_error(row["p0_w"], p_w)[0])
        r.append(row["range_m"])
    return np.array(e), np.array(r)


def _signed_range_errors(rows: list[dict], method: str) -> np.ndarray:
    """(estimated - true) horizontal distance from the camera over range; NaN where none."""
    out = []
    for row in rows:
        p_w = getattr(row["estimates"], method)
        if p_w is None:
            out.append(np.nan)
            continue
        c = row["t_w_c"][:2]
        true_m = np.linalg.norm(row["p0_w"][:2] - c)
        out.append((np.linalg.norm(p_w[:2] - c) - true_m) / row["range_m"])
    return np.array(out)


def test_every_selected_pose_detects_one_cone(grid: dict) -> None:
    counts = [row["n_detections"] for row in grid["rows"] + grid["shallow"]]
    n_grid = len(CAMERA_PITCHES_DEG) * POSES_PER_PITCH
    assert len(counts) == n_grid + len(SHALLOW_CAMERA_PITCHES_DEG) * SHALLOW_POSES_PER_PITCH
    assert all(c == 1 for c in counts), f"detections per frame: {counts}"


def test_error_statistics_per_method(grid: dict, record_property) -> None:
    """Print (pytest -s) and record the statistics; the contract is checked below."""
    lines = []
    for name in ("rows", "shallow"):
        lines.append(
            f"{'grid' if name == 'rows' else 'shallow'} ({len(grid[name])} poses)\n"
            f"{'method':13s} {'n':>4s} {'none':>4s} {'mean':>7s} {'median':>7s} "
            f"{'rmse':>7s} {'max':>7s}  horizontal error, m; median / range"
        )
        for method in METHOD_NAMES:
            e, r = _errors(grid[name], method)
            stats = error_stats(e[np.isfinite(e)])
            record_property(f"{name}_{method}_horizontal_error_m", stats)
            lines.append(
                f"{method:13s} {stats['count']:4d} {int(np.isinf(e).sum()):4d} "
                f"{stats['mean']:7.3f} {stats['median']:7.3f} {stats['rmse']:7.3f} "
                f"{stats['max']:7.3f}  {100 * np.median(e / r):6.2f}%"
            )
    print("\n" + "\n".join(lines))
    logger.info("localisation error statistics:\n%s", "\n".join(lines))


def test_depth_image_every_detection_within_contract(grid: dict) -> None:
    e, r = _errors(grid["rows"], "depth_image")
    bound = np.maximum(0.05, 0.01 * r)
    assert (e <= bound).all(), (
        f"worst ratio {np.max(e / bound):.2f} at range {r[np.argmax(e / bound)]:.1f} m"
    )


def test_ground_plane_median_within_contract(grid: dict) -> None:
    e, r = _errors(grid["rows"], "ground_plane")
    assert np.median(e / np.maximum(0.10, 0.02 * r)) <= 1.0


def test_known_height_median_within_contract(grid: dict) -> None:
    e, r = _errors(grid["rows"], "known_height")  # a missing estimate counts as infinite error
    assert np.median(e / r) <= 0.05


def test_known_height_shallow_views_unbiased(grid: dict) -> None:
    """Low camera, long range: the contract's 5% median, and no systematic range bias.

    Bounds: median error <= 5% of range (the contract) and, tighter, <= 3%; the mean signed
    range error within 1.5% of range (before the area-based apex the top-most pixel of the
    thin tip, several pixels below the apex, biased such views by 10-30%).
    """
    e, r = _errors(grid["shallow"], "known_height")
    assert np.median(e / r) <= 0.05
    assert np.median(e / r) <= 0.03, f"median {100 * np.median(e / r):.2f}% of range"
    bias = np.nanmean(_signed_range_errors(grid["shallow"], "known_height"))
    assert abs(bias) <= 0.015, f"mean signed range error {100 * bias:+.2f}% of range"


def _render_one(cone_xy: tuple[float, float], height_m: float, pitch_deg: float, yaw: float = 0.0):
    """Render one cone from a level drone at (0, 0, height_m); return (world, frame, detections)."""
    world = World.from_config(
        SceneConfig(cones_w=((*cone_xy, 0.0),), camera=CameraConfig(pitch_down_deg=pitch_deg))
    )
    world.set_pose(se3.make(so3.rot_z(yaw), [0.0, 0.0, height_m]))
    with Renderer(world) as renderer:
        frame = renderer.render(depth=True)
    return world, frame, detect_cones(frame.rgb)


def _relative_error(world: World, p_w: np.ndarray) -> float:
    p0_w = world.cones_w[0]
    return float(horizontal_error(p0_w, p_w)[0] / np.linalg.norm(p0_w - world.T_w_c[:3, 3]))


def test_known_height_straight_ahead_low_camera() -> None:
    """The cone dead ahead of a level drone 3 m up, camera pitched 12 deg (the `approach`
    scenario): its axis falls on a pixel boundary, the worst case for a thin tip (the top-most
    pixel lies 2-3 px below the apex at 20 m, and the known height erred by 26% there). The
    median within 5% of range (the contract) and each within 10% (about one pixel at 24 m)."""
    errors = []
    for x in (8.0, 12.0, 16.0, 20.0, 24.0):
        world, _, (detection,) = _render_one((x, 0.0), 3.0, 12.0)
        p_w = localize(detection, world.camera, world.T_w_b, world.T_b_c).known_height
        assert p_w is not None, f"no estimate at {x} m"
        errors.append(_relative_error(world, p_w))
    assert np.median(errors) <= 0.05, f"relative errors {np.round(errors, 3)}"
    assert max(errors) <= 0.10, f"relative errors {np.round(errors, 3)}"


@pytest.mark.parametrize(
    ("cone_x_m", "pitch_deg", "expect_estimate"),
    [
        (6.0, 55.0, True),  # line of sight 59 deg below the horizontal: apex clear of the plate
        (5.0, 60.0, True),  # 64 deg
        (3.0, 70.0, False),  # 74 deg: the apex projects onto the base plate
        (2.2, 80.0, False),  # 78 deg, near nadir
    ],
)
def test_known_height_refuses_steep_views(
    cone_x_m: float, pitch_deg: float, expect_estimate: bool
) -> None:
    """Both sides of the steep-view criterion `triangle_fraction(e) >= MIN_TRIANGLE_FRACTION`,
    seen from 10 m above; the other methods keep working."""
    world, frame, (detection,) = _render_one((cone_x_m, 0.0), 10.0, pitch_deg)
    T_w_c = world.T_w_c
    elevation = np.arcsin(T_w_c[2, 3] / np.linalg.norm(world.cones_w[0] - T_w_c[:3, 3]))
    assert (triangle_fraction(elevation) >= MIN_TRIANGLE_FRACTION) == expect_estimate
    estimates = localize(detection, world.camera, world.T_w_b, world.T_b_c, frame.depth)
    if expect_estimate:
        assert estimates.known_height is not None
        assert _relative_error(world, estimates.known_height) <= 0.05
    else:
        assert estimates.known_height is None
    assert _relative_error(world, estimates.depth_image) <= 0.01
    assert _relative_error(world, estimates.ground_plane) <= 0.02


def test_triangle_fraction() -> None:
    assert triangle_fraction(0.0) == pytest.approx(1.0 - 0.0 / 0.70, abs=0.05)
    fractions = [triangle_fraction(np.radians(e)) for e in range(0, 91, 5)]
    assert all(a >= b for a, b in itertools.pairwise(fractions))
    assert triangle_fraction(np.radians(75.0)) == 0.0
    assert triangle_fraction(np.radians(90.0)) == 0.0


@pytest.mark.parametrize(("cone_x_m", "expect_estimate"), [(24.0, True), (36.0, False)])
def test_known_height_refuses_tiny_cones(cone_x_m: float, expect_estimate: bool) -> None:
    """Both sides of the sensitivity criterion: at 24 m (12 px tall) one pixel moves the
    estimate by under 10% of range (kept); at 36 m (7 px) by about 16% (> MAX_RANGE_ERROR_PER_PX
    = 10%: no estimate rather than a wrong one)."""
    world, _, (detection,) = _render_one((cone_x_m, 0.0), 3.0, 5.0, yaw=0.02)
    p_w = estimate_from_known_height(detection, world.camera, world.T_w_c)
    assert (p_w is not None) == expect_estimate
    if p_w is not None:
        assert _relative_error(world, p_w) <= 2.0 * MAX_RANGE_ERROR_PER_PX


def test_cone_cut_off_by_border_gives_no_estimate() -> None:
    """Half the cone outside the image: every method (and the naive one) gives None."""
    world, frame, (detection,) = _render_one((6.0, 0.0), 3.0, 30.0, yaw=-0.73)
    assert detection.touches_border
    estimates = localize(detection, world.camera, world.T_w_b, world.T_b_c, frame.depth)
    assert all(p is None for p in estimates.as_dict().values()), estimates
    T_w_c = world.T_w_c
    assert estimate_from_depth(detection, frame.depth, world.camera, T_w_c) is None
    assert estimate_from_ground_plane(detection, world.camera, T_w_c) is None
    assert estimate_from_known_height(detection, world.camera, T_w_c) is None


@pytest.mark.parametrize("seed", range(6))
def test_apex_pixel_synthetic_thin_tip(seed: int) -> None:
    """A rasterised upright triangle (pixel-centre inclusion) 14-40 px tall, its axis on a pixel
    boundary or at a random phase: the area fit finds the apex to 0.6 px, where the top-most
    covered pixel lies up to 0.5 / slope (about 2 px) below it."""
    rng = np.random.default_rng(seed)
    apex = np.array([rng.choice([320.5, rng.uniform(300.0, 340.0)]), rng.uniform(100.0, 300.0)])
    height = rng.uniform(14.0, 40.0)
    v, u = np.mgrid[0:480, 0:640]
    t = (v - apex[1]) / height
    mask = (t >= 0) & (t <= 1) & (np.abs(u - apex[0]) <= 0.22 * height * t)
    rows, cols = np.nonzero(mask)
    x0, y0 = cols.min(), rows.min()
    crop = mask[y0 : rows.max() + 1, x0 : cols.max() + 1]
    detection = ConeDetection(
        bbox=(int(x0), int(y0), crop.shape[1], crop.shape[0]),
        area_px=int(crop.sum()),
        mask=crop,
        apex_uv=apex,
        base_uv=apex + np.array([0.0, height]),
        centroid_uv=np.array([cols.mean(), rows.mean()]),
        touches_border=False,
        apex_from_edges=False,
    )
    found = apex_pixel(detection, np.array([0.0, 1.0]), fraction=1.0)
    assert found is not None
    np.testing.assert_allclose(found, apex, atol=0.6)


def test_naive_is_badly_wrong(grid: dict) -> None:
    e, r = _errors(grid["rows"], "naive")
    assert np.median(e / r) > 0.3


def test_chain_is_exact() -> None:
    """Project the true base centre and back-project with its true depth: the truth to 1e-9 m."""
    world = World.from_config(SceneConfig())
    rng = np.random.default_rng(1)
    p0_w = world.cones_w[0]
    for T_w_b, _ in sample_poses(world, rng, 50):
        world.set_pose(T_w_b)
        T_w_c = world.T_w_b @ world.T_b_c
        p_c = se3.apply(se3.invert(T_w_c), p0_w)
        uv = world.camera.project(p_c)
        p_w = se3.apply(T_w_c, world.camera.backproject(uv, p_c[2]))
        np.testing.assert_allclose(p_w[0], p0_w, atol=1e-9, rtol=0)


@pytest.fixture(scope="module")
def one_view() -> dict:
    world = World.from_config(SceneConfig())
    T_w_b = se3.make(so3.from_rpy(0.0, 0.0, np.arctan2(1.0, 6.0)), [0.0, 0.0, 4.0])
    world.set_pose(T_w_b)
    with Renderer(world) as renderer:
        frame = renderer.render(depth=True, segmentation=True)
    far_m = 0.99 * world.model.vis.map.zfar * world.model.stat.extent
    (detection,) = detect_cones(frame.rgb)
    return {"world": world, "frame": frame, "detection": detection, "far_m": far_m}


def test_depth_cloud_lies_on_true_surfaces(one_view: dict) -> None:
    world, frame, far_m = one_view["world"], one_view["frame"], one_view["far_m"]
    T_w_c = world.T_w_c
    cloud_w = depth_to_world_points(frame.depth, world.camera, T_w_c, far_m=far_m)
    sky = frame.depth >= far_m
    assert cloud_w.shape == (int((~sky).sum()), 3)
    cone = one_view["detection"].full_mask(frame.depth.shape)[~sky]
    # Ground pixels lie on z = 0 (float32 depth: relative 1e-5 of up to ~300 m).
    ground_z = cloud_w[~cone, 2]
    assert np.abs(ground_z).max() < 0.02
    # Cone pixels lie on the cone's analytic surface.
    p_k = cloud_w[cone] - world.cones_w[0]
    assert np.median(surface_residual_m(p_k)) < 0.003
    # The strided cloud is the subset of pixels.
    sub = depth_to_world_points(frame.depth, world.camera, T_w_c, stride=4, far_m=far_m)
    assert sub.shape[0] == int((frame.depth[::4, ::4] < far_m).sum())


def test_no_valid_depth_gives_no_depth_estimate(one_view: dict) -> None:
    world, detection = one_view["world"], one_view["detection"]
    far = np.full_like(one_view["frame"].depth, 1e3)
    assert estimate_from_depth(detection, far, world.camera, world.T_w_c, far_m=500.0) is None
    estimates = localize(detection, world.camera, world.T_w_b, world.T_b_c, far, far_m=500.0)
    assert estimates.depth_image is None
    assert estimates.ground_plane is not None and estimates.naive is not None


def test_ray_not_reaching_ground_gives_no_ground_estimate(one_view: dict) -> None:
    world, detection = one_view["world"], one_view["detection"]
    T_w_c = world.T_w_c
    # Turn the camera upside down about its optical axis's horizontal: rays now point up.
    T_up = T_w_c.copy()
    T_up[:3, :3] = so3.rot_x(np.pi) @ T_w_c[:3, :3]
    assert estimate_from_ground_plane(detection, world.camera, T_up) is None
    # A camera below the ground sees no ground either.
    T_below = T_w_c.copy()
    T_below[2, 3] = -1.0
    assert estimate_from_ground_plane(detection, world.camera, T_below) is None


def test_bad_input_raises(one_view: dict) -> None:
    world, frame, detection = one_view["world"], one_view["frame"], one_view["detection"]
    cam, T_w_b, T_b_c = world.camera, world.T_w_b, world.T_b_c
    with pytest.raises(ValueError, match=r"depth must have the camera's image size"):
        localize(detection, cam, T_w_b, T_b_c, frame.depth[:-1])
    with pytest.raises(ValueError, match="depth must have dtype float32 or float64"):
        localize(detection, cam, T_w_b, T_b_c, frame.depth.astype(np.uint16))
    nan_depth = frame.depth.copy()
    x, y, w, h = detection.bbox
    nan_depth[y : y + h, x : x + w] = np.nan
    with pytest.raises(ValueError, match="depth must be finite under the detection's mask"):
        localize(detection, cam, T_w_b, T_b_c, nan_depth)
    with pytest.raises(ValueError, match="depth must not contain NaN"):
        depth_to_world_points(nan_depth, cam, world.T_w_c)
    with pytest.raises(ValueError, match=r"T_w_b must have shape \(\.\.\., 4, 4\)"):
        localize(detection, cam, T_w_b[:3], T_b_c)
    with pytest.raises(ValueError, match="T_w_b must be a single 4x4 transform"):
        localize(detection, cam, np.stack([T_w_b, T_w_b]), T_b_c)
    bad = T_b_c.copy()
    bad[0, 0] = 2.0
    with pytest.raises(ValueError, match=r"T_b_c\[:3, :3\] is not a rotation matrix"):
        localize(detection, cam, T_w_b, bad)
    with pytest.raises(ValueError, match="stride must be a positive int"):
        depth_to_world_points(frame.depth, cam, world.T_w_c, stride=0)
    small = PinholeCamera.from_fovy(60.0, 320, 240)
    with pytest.raises(ValueError, match="does not fit the camera's image"):
        localize(detection, small, T_w_b, T_b_c)
    with pytest.raises(ValueError, match="detection must be a ConeDetection"):
        localize("cone", cam, T_w_b, T_b_c)  # type: ignore[arg-type]
    assert isinstance(detection, ConeDetection)
