"""Cone localisation against the simulator's ground truth (the accuracy contract,
docs/ACCURACY.md), and ``vnav.localize.localize`` itself.

Poses are drawn from a seeded generator and kept by the TRUE geometry only (the whole cone in
view with a 2 px margin, at least 12 px tall, range 2-25 m, drone height 2-15 m); every kept
pose must then give exactly one detection. A second, shallow set (drone height 2-4 m, range
8-25 m, camera pitch 0-20 deg: lines of sight 5-30 deg below the horizontal, where a 1 px
error in the apex is 4-7% of range) is drawn the same way. The per-method error statistics
of both sets are printed and attached to the test report (``record_property``).

Each estimator's own rules (when it refuses, its fast kernels against their lecture forms) are
tested in test_estimators.py, the silhouette geometry in test_silhouette.py.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
from helpers import cone_corners_w, relative_error, render_one

from sim.config import CameraConfig, SceneConfig
from sim.render import Renderer
from sim.world import World
from vnav import se3, so3
from vnav.camera import PinholeCamera
from vnav.detect import ConeDetection, detect_cones
from vnav.estimators import (
    NoEstimate,
    estimate_from_depth,
    estimate_from_ground_plane,
    estimate_from_known_height,
    naive_estimate,
)
from vnav.localize import ConeEstimates, localize
from vnav.methods import METHOD_NAMES, PREFERENCE
from vnav.metrics import error_stats, horizontal_error

logger = logging.getLogger(__name__)

CAMERA_PITCHES_DEG = (0.0, 20.0, 40.0, 60.0, 80.0)
POSES_PER_PITCH = 60
SEED = 4
SHALLOW_CAMERA_PITCHES_DEG = (0.0, 10.0, 20.0)
SHALLOW_POSES_PER_PITCH = 40
SHALLOW_HEIGHTS_M = (2.0, 4.0)
SHALLOW_RANGES_M = (8.0, 25.0)


def sample_poses(
    world: World,
    rng: np.random.Generator,
    n: int,
    heights_m: tuple[float, float] = (2.0, 15.0),
    ranges_m: tuple[float, float] = (2.0, 25.0),
) -> list[tuple[np.ndarray, float]]:
    """``n`` drone poses ``(T_w_b, range_m)`` that see the whole cone, chosen by true geometry.

    Roll and pitch uniform in +-30 deg, yaw all around; the base centre's pixel uniform over the
    image and its range uniform in ``ranges_m`` place the drone; kept if the camera's height is
    within ``heights_m``, every corner of the cone projects inside the image with a 2 px margin
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


def test_known_height_straight_ahead_low_camera() -> None:
    """The cone dead ahead of a level drone 3 m up, camera pitched 12 deg (the ``approach``
    scenario): its axis falls on a pixel boundary, the worst case for a thin tip (the top-most
    pixel lies 2-3 px below the apex at 20 m, and the known height erred by 26% there). The
    median within 5% of range (the contract) and each within 10% (about one pixel at 24 m)."""
    errors = []
    for x in (8.0, 12.0, 16.0, 20.0, 24.0):
        world, _, (detection,) = render_one((x, 0.0), 3.0, 12.0)
        p_w = localize(detection, world.camera, world.T_w_b, world.T_b_c).known_height
        assert p_w is not None, f"no estimate at {x} m"
        errors.append(relative_error(world, p_w))
    assert np.median(errors) <= 0.05, f"relative errors {np.round(errors, 3)}"
    assert max(errors) <= 0.10, f"relative errors {np.round(errors, 3)}"


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
    with pytest.raises(ValueError, match=r"T_w_b must have shape \(\.\.\., 4, 4\)"):
        localize(detection, cam, T_w_b[:3], T_b_c)
    with pytest.raises(ValueError, match="T_w_b must be a single 4x4 transform"):
        localize(detection, cam, np.stack([T_w_b, T_w_b]), T_b_c)
    bad = T_b_c.copy()
    bad[0, 0] = 2.0
    with pytest.raises(ValueError, match=r"T_b_c\[:3, :3\] is not a rotation matrix"):
        localize(detection, cam, T_w_b, bad)
    small = PinholeCamera.from_fovy(60.0, 320, 240)
    with pytest.raises(ValueError, match="does not fit the camera's image"):
        localize(detection, small, T_w_b, T_b_c)
    with pytest.raises(ValueError, match="detection must be a ConeDetection"):
        localize("cone", cam, T_w_b, T_b_c)  # type: ignore[arg-type]
    assert isinstance(detection, ConeDetection)


# ------------------------------------------------------------------------- localize itself


def test_localize_runs_every_estimator_on_one_view(one_view: dict) -> None:
    """localize's estimates are the estimators' own, each called alone; the naive one is the
    best estimate's camera coordinates added to the drone's position (lecture chapter 0)."""
    world, frame, detection = one_view["world"], one_view["frame"], one_view["detection"]
    far_m = one_view["far_m"]
    cam, T_w_b, T_b_c, T_w_c = world.camera, world.T_w_b, world.T_b_c, world.T_w_c
    estimates = localize(detection, cam, T_w_b, T_b_c, frame.depth, far_m=far_m)
    assert list(estimates) == list(METHOD_NAMES)
    expected = {
        "depth_image": estimate_from_depth(detection, frame.depth, cam, T_w_c, far_m=far_m),
        "ground_plane": estimate_from_ground_plane(detection, cam, T_w_c),
        "known_height": estimate_from_known_height(detection, cam, T_w_c),
    }
    for name, p_w in expected.items():
        assert p_w is not None, name
        np.testing.assert_array_equal(estimates[name], p_w)
    best = expected[PREFERENCE[0]]
    p_c = se3.apply(se3.invert(T_w_c), best)
    np.testing.assert_allclose(estimates.naive, naive_estimate(p_c, T_w_b), atol=1e-12)
    np.testing.assert_allclose(estimates.naive, T_w_b[:3, 3] + p_c, atol=1e-12)
    # Without a depth image there is no depth estimate; the next preferred one feeds naive.
    no_depth = localize(detection, cam, T_w_b, T_b_c)
    assert no_depth.depth_image is None
    np.testing.assert_array_equal(no_depth.best, expected[PREFERENCE[1]])


def test_cone_estimates_is_a_read_only_mapping_in_method_order() -> None:
    p, q = np.array([1.0, 2.0, 0.0]), np.array([1.1, 2.1, 0.0])
    estimates = ConeEstimates({"ground_plane": p})
    assert list(estimates) == list(METHOD_NAMES) and len(estimates) == len(METHOD_NAMES)
    assert estimates["ground_plane"] is p and estimates.ground_plane is p
    assert estimates.depth_image is None and estimates["naive"] is None
    assert estimates.as_dict() == {m: (p if m == "ground_plane" else None) for m in METHOD_NAMES}
    # best: the first available in PREFERENCE order; naive is never the best.
    assert estimates.best is p
    assert ConeEstimates({"ground_plane": p, "depth_image": q}).best is q
    assert ConeEstimates({"naive": p}).best is None
    assert ConeEstimates({}).best is None
    with pytest.raises(ValueError, match=r"unknown methods \['lidar'\]; valid: "):
        ConeEstimates({"lidar": p})
    with pytest.raises(AttributeError, match="lidar"):
        estimates.lidar  # noqa: B018
    # Why a method gave none: only beside a missing estimate, only for a method.
    why = ConeEstimates({"ground_plane": p}, {"known_height": NoEstimate.STEEP})
    assert why.no_estimate == {"known_height": NoEstimate.STEEP}
    with pytest.raises(
        ValueError, match=r"reason for methods with an estimate: \['ground_plane'\]"
    ):
        ConeEstimates({"ground_plane": p}, {"ground_plane": NoEstimate.STEEP})
    with pytest.raises(ValueError, match=r"unknown methods \['lidar'\]"):
        ConeEstimates({}, {"lidar": NoEstimate.STEEP})
