"""The PyBullet peer of ``python -m benchmarks peers`` renders the scene vnav-sim renders.

The benchmark's ratio means something only if PyBullet draws a comparable image: the same four
cones, of the same size, where vnav-sim's camera sees them. Each cone's pixels in PyBullet's
segmentation mask are compared with the pinhole projection (``vnav.camera``) of the cone's
solid (the base plate and the body, each convex), and with MuJoCo's segmentation of the same
view.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

pytest.importorskip(
    "pybullet",
    reason="PyBullet is not installed: it is in the bench extra (pip install -e '.[bench]'), "
    "which setup.sh, and so CI, does not install",
)

from benchmarks import peers
from sim import names
from sim.render import Renderer
from sim.world import World, cone_mesh_vertices
from vnav import se3
from vnav.camera import PinholeCamera
from vnav.cone import TRAFFIC_CONE

TIMES_S = (0.0, 2.5, 5.0)
"""The path's start, middle and end."""


@pytest.fixture(scope="module")
def spec():
    return peers.peer_spec()


@pytest.fixture(scope="module")
def scene(spec):
    with peers.PyBulletScene(spec) as s:
        yield s


def _inside(uv: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: the pixels whose centres lie inside the convex hull of ``uv`` (N, 2) (the
    rule OpenGL rasterises by; OpenCV's pixel (u, v) is centred on (u, v))."""
    hull = cv2.convexHull(uv.astype(np.float32)).reshape(-1, 2).astype(np.float64)
    v, u = np.mgrid[0 : shape[0], 0 : shape[1]]
    inside = np.ones(shape, bool)
    for a, b in zip(hull, np.roll(hull, -1, axis=0), strict=True):
        cross = (b[0] - a[0]) * (v - a[1]) - (b[1] - a[1]) * (u - a[0])
        inside &= cross >= 0.0 if _orientation(hull) > 0 else cross <= 0.0
    return inside


def _orientation(polygon: np.ndarray) -> float:
    """The sign of the polygon's signed area (shoelace)."""
    x, y = polygon[:, 0], polygon[:, 1]
    return float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _cone_masks(spec, T_w_c: np.ndarray) -> list[np.ndarray]:
    """Each cone's pixels as the pinhole model projects its solid, nearer cones on top: the
    base plate (its 8 corners) and the body (its ring and apex), each convex."""
    cam = spec.scene.camera
    camera = PinholeCamera.from_fovy(cam.fovy_deg, cam.width, cam.height)
    T_c_w = se3.invert(T_w_c)
    cones_w = np.array(spec.scene.cones_w)
    label = np.full((cam.height, cam.width), -1)
    far_first = np.argsort(-np.linalg.norm(se3.apply(T_c_w, cones_w), axis=1))
    for i in far_first:
        corners_w = TRAFFIC_CONE.extreme_points(cones_w[i])[1:]
        body_w = cone_mesh_vertices(TRAFFIC_CONE) + cones_w[i]
        for part_w in (corners_w, body_w):
            uv = camera.project(se3.apply(T_c_w, part_w))
            assert np.all(np.isfinite(uv))
            label[_inside(uv, label.shape)] = i
    return [label == i for i in range(len(cones_w))]


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


@pytest.mark.parametrize("t_s", TIMES_S)
def test_pybullet_draws_each_cone_where_the_pinhole_model_projects_it(spec, scene, t_s):
    T_w_c = peers.reference_pose(spec)(t_s) @ spec.scene.camera.T_b_c
    rgba, _, seg = scene.render(T_w_c)
    object_id = np.where(seg >= 0, seg & 0xFFFFFF, -1)
    assert not (object_id == scene.drone).any(), "the camera sees its own drone"
    for i, expected in enumerate(_cone_masks(spec, T_w_c)):
        drawn = object_id == scene.cone_ids[i]
        assert expected.sum() > 100, f"cone {i} should be in view at {t_s} s"
        # Pixel for pixel but for a centre within rounding of an outline (a face seen edge-on
        # puts a whole row there: 9 of 638 pixels at 5 s).
        assert _iou(drawn, expected) > 0.95, f"cone {i} at {t_s} s"
        v, u = np.nonzero(drawn)
        ve, ue = np.nonzero(expected)
        assert abs(u.mean() - ue.mean()) < 0.5 and abs(v.mean() - ve.mean()) < 0.5
        # The cone's colour (orange, lit): red well above green, green above blue.
        r, g, b = rgba[drawn][:, :3].mean(axis=0)
        assert r > 2 * g > 2 * b


def test_pybullet_and_mujoco_see_the_same_cone_pixels(spec, scene):
    T_w_b = peers.reference_pose(spec)(2.5)
    _, _, seg = scene.render(T_w_b @ spec.scene.camera.T_b_c)
    object_id = np.where(seg >= 0, seg & 0xFFFFFF, -1)
    world = World.from_config(spec.scene)
    world.set_pose(T_w_b)
    with Renderer(world) as renderer:
        geoms = renderer.render(depth=False, segmentation=True).segmentation
    for i, cone_id in enumerate(scene.cone_ids):
        ids = [
            world.model.geom(names.cone_base_geom(i)).id,
            world.model.geom(names.cone_shell_geom(i)).id,
        ]
        assert _iou(object_id == cone_id, np.isin(geoms, ids)) > 0.95, f"cone {i}"


@pytest.mark.parametrize("variant", peers.VARIANTS)
def test_each_variant_stamps_every_camera_tick(variant):
    out = peers.measure(variant, duration_s=0.3)
    assert out["frames"] == peers.peer_spec(duration_s=0.3).n_ticks == 4
    assert 0.0 < out["loop_s"] < out["run_s"]
    assert 0.0 < out["loop_cpu_s"] < out["cpu_s"]


def test_a_variant_is_one_of_the_four():
    with pytest.raises(ValueError, match="unknown variant 'gym'"):
        peers.measure("gym")
