"""``vnav.sensor_noise``: the keypoint figures re-measured on fresh renders, the keypoint
covariance's shape, and the pose covariances against Monte Carlo."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.config import SceneConfig
from sim.noise import noisy_rgb
from sim.render import Renderer
from sim.world import World
from vnav import se3, so3
from vnav.cone import TRAFFIC_CONE
from vnav.detect import detect_cones
from vnav.estimators import MIN_TRIANGLE_FRACTION
from vnav.sensor_noise import (
    KEYPOINT_STD_PX,
    SensorNoise,
    body_pose_covariance,
    keypoint_cov,
    keypoint_std_px,
    mount_covariance,
)
from vnav.silhouette import SilhouetteView, triangle_fraction
from vnav.uncertainty import se3_exp, se3_log

N_VIEWS = 150


def _keypoint_errors(pixel_std: float, seed: int) -> dict[str, np.ndarray]:
    """Each keypoint's error from the true projection, (n, 2) px, along and across the image of
    the vertical, over ``N_VIEWS`` random views drawn as ``KEYPOINT_STD_PX`` says: the default
    camera on a level drone, range 3-20 m, 1.5-8 m high, any bearing, the cone within 17 deg of
    the heading; image noise from ``sim.noise.noisy_rgb``."""
    rng = np.random.default_rng(seed)
    world = World.from_config(SceneConfig(cones_w=((0.0, 0.0, 0.0),)))
    cam, cone = world.camera, TRAFFIC_CONE
    errors: dict[str, list] = {"apex": [], "bottom": []}
    with Renderer(world) as renderer:
        for _ in range(N_VIEWS):
            range_m, height_m = rng.uniform(3.0, 20.0), rng.uniform(1.5, 8.0)
            bearing = rng.uniform(-math.pi, math.pi)
            t_w_b = [-range_m * math.cos(bearing), -range_m * math.sin(bearing), height_m]
            yaw = bearing + rng.uniform(-0.3, 0.3)
            world.set_pose(se3.make(so3.rot_z(yaw), t_w_b))
            rgb = noisy_rgb(renderer.render(depth=False).rgb, pixel_std, rng)
            detections = detect_cones(rgb)
            if len(detections) != 1 or detections[0].touches_border:
                continue
            T_w_c = world.T_w_c
            view = SilhouetteView(detections[0], cam, T_w_c)
            vertical = view.vertical_at_blob()
            if vertical is None:
                continue
            d, elevation = vertical
            fraction = triangle_fraction(elevation, cone)
            apex = view.apex(d, fraction) if fraction >= MIN_TRIANGLE_FRACTION else None
            if apex is None:
                continue
            # The truth: the apex, and the plate's bottom edge on the bearing (the plate is a
            # square aligned with the world axes, half-width a).
            b = -np.array(t_w_b[:2]) / np.linalg.norm(t_w_b[:2])
            a = cone.base_width_m / 2
            edge_w = np.array([*(-b * a / max(abs(b[0]), abs(b[1]))), 0.0])
            truth_w = {"apex": np.array([0.0, 0.0, cone.height_m]), "bottom": edge_w}
            T_c_w = se3.invert(T_w_c)
            down = np.asarray(d) / np.linalg.norm(d)
            across = np.array([-down[1], down[0]])
            for kind, uv in (("apex", apex), ("bottom", view.bottom(cone))):
                p_c = T_c_w[:3, :3] @ truth_w[kind] + T_c_w[:3, 3]
                err = np.asarray(uv) - cam.project(p_c[None])[0]
                errors[kind].append((err @ down, err @ across))
    return {k: np.array(v) for k, v in errors.items()}


@pytest.mark.parametrize("pixel_std", [0.0, 10.0])
def test_keypoint_figures_hold_on_fresh_renders(pixel_std: float) -> None:
    """The table's root-mean-square errors against a fresh sample (another seed than the one
    measured): the mean squared error over the sample, divided by the table's square, is 1
    within 4 standard errors of that mean (the standard error from the sample's own spread of
    squared errors, which are heavy-tailed: a few views miss by 2 px)."""
    errors = _keypoint_errors(pixel_std, seed=20261124)
    for kind, e in errors.items():
        assert len(e) >= 0.8 * N_VIEWS, "most views must give both keypoints"
        for axis, std in enumerate(keypoint_std_px(kind, pixel_std)):
            sq = e[:, axis] ** 2
            ratio = sq.mean() / std**2
            standard_error = sq.std(ddof=1) / math.sqrt(len(sq)) / std**2
            assert abs(ratio - 1.0) <= 4.0 * standard_error, (kind, axis, ratio, standard_error)


def test_keypoint_std_interpolates_the_table_like_numpy() -> None:
    """Between rows, ``np.interp`` of the table; beyond the last row, the last row scaled."""
    for kind, rows in KEYPOINT_STD_PX.items():
        levels = [r[0] for r in rows]
        for level in np.linspace(0.0, levels[-1], 25):
            expected = (
                np.interp(level, levels, [r[1] for r in rows]),
                np.interp(level, levels, [r[2] for r in rows]),
            )
            np.testing.assert_allclose(keypoint_std_px(kind, float(level)), expected)
        along, across = keypoint_std_px(kind, 2.0 * levels[-1])
        assert (along, across) == pytest.approx((2.0 * rows[-1][1], 2.0 * rows[-1][2]))


def test_keypoint_cov_has_the_figures_along_and_across_the_vertical() -> None:
    """Eigenvalues along^2 and across^2, the first with the image vertical as eigenvector,
    whatever the vertical's length."""
    for angle in np.linspace(0.0, math.pi, 7):
        down = 3.0 * np.array([math.cos(angle), math.sin(angle)])
        cov = keypoint_cov("apex", 0.0, down)
        along, across = keypoint_std_px("apex", 0.0)
        unit = down / np.linalg.norm(down)
        assert unit @ cov @ unit == pytest.approx(along**2)
        normal = np.array([-unit[1], unit[0]])
        assert normal @ cov @ normal == pytest.approx(across**2)
        assert unit @ cov @ normal == pytest.approx(0.0, abs=1e-15)


def test_body_pose_covariance_matches_monte_carlo() -> None:
    """The pose stream's noise, drawn as the simulator draws it (position in world axes,
    attitude ``R_w_b exp(dtheta_b)``), expressed as a left perturbation ``se3_log(T_noisy
    T^-1)``: its sample covariance over 20,000 draws against ``body_pose_covariance``, each
    entry within 5 standard errors (a sample covariance's entry has standard error
    ``sqrt((S_ii S_jj + S_ij^2) / n)``)."""
    from helpers import se3_log_stack  # the draws a stack at a time

    rng = np.random.default_rng(5)
    T = se3.make(so3.from_rpy(0.3, -0.2, 2.0), [4.0, -3.0, 6.0])
    std_p, std_a = 0.05, math.radians(2.0)
    n = 20_000
    # Per draw 3 normals for the attitude, then 3 for the position: a draw-by-draw loop's
    # numbers, drawn at once.
    z = rng.standard_normal((n, 6))
    noisy = se3.make(T[:3, :3] @ so3.exp(std_a * z[:, :3]), T[:3, 3] + std_p * z[:, 3:])
    xis = se3_log_stack(noisy @ se3.invert(T))
    sample = np.cov(xis.T)
    predicted = body_pose_covariance(T, std_p, std_a)
    d = np.diag(predicted)
    standard_error = np.sqrt((np.outer(d, d) + predicted**2) / n)
    assert np.all(np.abs(sample - predicted) <= 5.0 * standard_error)


def test_mount_covariance_is_what_the_simulator_draws() -> None:
    """``mount_covariance`` against the sample covariance of ``se3_log`` of
    ``sim.noise.mount_error`` draws (5 standard errors per entry)."""
    from sim.noise import mount_error

    rng = np.random.default_rng(9)
    n = 20_000
    xis = np.array([se3_log(mount_error(0.01, 2.0, rng)) for _ in range(n)])
    predicted = mount_covariance(0.01, math.radians(2.0))
    d = np.diag(predicted)
    standard_error = np.sqrt((np.outer(d, d) + predicted**2) / n)
    assert np.all(np.abs(np.cov(xis.T) - predicted) <= 5.0 * standard_error)
    np.testing.assert_array_equal(se3_exp(np.zeros(6)), mount_error(0.0, 0.0, rng))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"pixel_std": -1.0}, "pixel_std"),
        ({"depth_std_m": float("nan")}, "depth_std_m"),
        ({"depth_std_per_m2": "0.1"}, "depth_std_per_m2"),
    ],
)
def test_sensor_noise_refuses_bad_figures(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        SensorNoise(**kwargs)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("tip", 0.0), "keypoint kind"),
        (("apex", -2.0), "pixel_std"),
        (("apex", [1.0]), "pixel_std"),
    ],
)
def test_keypoint_std_refuses_bad_input(args: tuple, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        keypoint_std_px(*args)


def test_depth_std_grows_with_the_square_of_depth() -> None:
    noise = SensorNoise(0.0, 0.005, 0.0002)
    np.testing.assert_allclose(noise.depth_std_at(np.array([0.0, 10.0])), [0.005, 0.025])
