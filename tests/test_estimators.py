"""vnav.estimators: when each estimator gives no estimate, and its fast kernels against the
lecture forms that sit next to them in the library.

The kernels run in plain floats or with hand-written statistics for speed; each is compared
with its lecture form on random inputs: ``_world_points`` with ``_world_points_reference``,
``solve_known_height`` with ``_solve_known_height_reference``, ``_median`` and
``_percentile`` with ``np.median`` and ``np.percentile``, and ``_fit_axis`` (Gauss-Newton
with one outlier trim) with ``scipy.optimize.least_squares`` on the same circle-fit residuals
(SciPy is a test-only oracle). The accuracy of every method over rendered poses is in
test_localize.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers import blank, random_poses, relative_error, render_one, synthetic_cone
from scipy.optimize import least_squares

from vnav import se3, so3
from vnav.camera import PinholeCamera
from vnav.cone import TRAFFIC_CONE
from vnav.detect import detect_cones
from vnav.estimators import (
    MAX_RANGE_ERROR_PER_PX,
    MIN_TRIANGLE_FRACTION,
    NoEstimate,
    _fit_axis,
    _median,
    _percentile,
    _solve_known_height_reference,
    _world_points,
    _world_points_reference,
    estimate_from_depth,
    estimate_from_ground_plane,
    estimate_from_known_height,
    known_height_max_elevation_rad,
    naive_estimate,
    solve_known_height,
)
from vnav.localize import localize
from vnav.silhouette import SilhouetteView, triangle_fraction

CAM = PinholeCamera.from_fovy(60.0, 640, 480)


# --------------------------------------------------------------- when a method gives none


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
    """Both sides of the steep-view criterion ``triangle_fraction(e) >= MIN_TRIANGLE_FRACTION``,
    seen from 10 m above; the other methods keep working."""
    world, frame, (detection,) = render_one((cone_x_m, 0.0), 10.0, pitch_deg)
    T_w_c = world.T_w_c
    elevation = np.arcsin(T_w_c[2, 3] / np.linalg.norm(world.cones_w[0] - T_w_c[:3, 3]))
    assert (triangle_fraction(elevation) >= MIN_TRIANGLE_FRACTION) == expect_estimate
    estimates = localize(detection, world.camera, world.T_w_b, world.T_b_c, frame.depth)
    if expect_estimate:
        assert estimates.known_height is not None
        assert relative_error(world, estimates.known_height) <= 0.05
        assert "known_height" not in estimates.no_estimate
    else:
        assert estimates.known_height is None
        assert estimates.no_estimate == {
            "known_height": NoEstimate.STEEP,
            "triangulated": NoEstimate.ONE_IMAGE,
        }
    assert relative_error(world, estimates.depth_image) <= 0.01
    assert relative_error(world, estimates.ground_plane) <= 0.02


@pytest.mark.parametrize(("cone_x_m", "expect_estimate"), [(24.0, True), (36.0, False)])
def test_known_height_refuses_tiny_cones(cone_x_m: float, expect_estimate: bool) -> None:
    """Both sides of the sensitivity criterion: at 24 m (12 px tall) one pixel moves the
    estimate by under 10% of range (kept); at 36 m (7 px) by about 16% (> MAX_RANGE_ERROR_PER_PX
    = 10%: no estimate rather than a wrong one)."""
    world, frame, (detection,) = render_one((cone_x_m, 0.0), 3.0, 5.0, yaw=0.02)
    p_w = estimate_from_known_height(detection, world.camera, world.T_w_c)
    assert (p_w is not None) == expect_estimate
    estimates = localize(detection, world.camera, world.T_w_b, world.T_b_c, frame.depth)
    reason = estimates.no_estimate.get("known_height")
    assert reason is (None if expect_estimate else NoEstimate.SMALL)
    if p_w is not None:
        assert relative_error(world, p_w) <= 2.0 * MAX_RANGE_ERROR_PER_PX


def test_cone_cut_off_by_border_gives_no_estimate() -> None:
    """Half the cone outside the image: every method (and the naive one) gives None."""
    world, frame, (detection,) = render_one((6.0, 0.0), 3.0, 30.0, yaw=-0.73)
    assert detection.touches_border
    estimates = localize(detection, world.camera, world.T_w_b, world.T_b_c, frame.depth)
    assert all(p is None for p in estimates.as_dict().values()), estimates
    assert set(estimates.no_estimate.values()) == {NoEstimate.BORDER}
    assert len(estimates.no_estimate) == len(estimates)
    T_w_c = world.T_w_c
    assert estimate_from_depth(detection, frame.depth, world.camera, T_w_c) is None
    assert estimate_from_ground_plane(detection, world.camera, T_w_c) is None
    assert estimate_from_known_height(detection, world.camera, T_w_c) is None


def test_no_valid_depth_gives_no_depth_estimate(one_view: dict) -> None:
    world, detection = one_view["world"], one_view["detection"]
    far = np.full_like(one_view["frame"].depth, 1e3)
    assert estimate_from_depth(detection, far, world.camera, world.T_w_c, far_m=500.0) is None
    estimates = localize(detection, world.camera, world.T_w_b, world.T_b_c, far, far_m=500.0)
    assert estimates.depth_image is None
    assert estimates.no_estimate["depth_image"] is NoEstimate.NO_DEPTH
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


def test_known_height_steepest_view_inverts_triangle_fraction() -> None:
    """The closed form meets ``triangle_fraction`` (the forward formula) at the criterion, and
    the views on either side fall on either side of it."""
    e_max = known_height_max_elevation_rad()
    assert triangle_fraction(e_max) == pytest.approx(MIN_TRIANGLE_FRACTION, abs=1e-12)
    assert triangle_fraction(e_max - 1e-6) > MIN_TRIANGLE_FRACTION
    assert triangle_fraction(e_max + 1e-6) < MIN_TRIANGLE_FRACTION
    assert f"{np.degrees(e_max):.0f} deg" in NoEstimate.STEEP.text


def test_no_estimate_reasons_say_which_are_the_geometry() -> None:
    geometric = {r for r in NoEstimate if r.geometric}
    assert geometric == {
        NoEstimate.BORDER,
        NoEstimate.GROUND_NOT_HIT,
        NoEstimate.NADIR,
        NoEstimate.STEEP,
        NoEstimate.SMALL,
        NoEstimate.PARALLAX,
    }
    assert all(r.text for r in NoEstimate)


def test_naive_estimate_adds_camera_coordinates_to_the_drone_position() -> None:
    """The lecture's mistake (chapter 0), by hand: only the drone's translation is used."""
    T_w_b = se3.make(so3.rot_z(np.pi / 2), [1.0, 2.0, 10.0])
    np.testing.assert_array_equal(naive_estimate([0.5, -1.0, 4.0], T_w_b), [1.5, 1.0, 14.0])
    with pytest.raises(ValueError, match=r"p_c must have shape \(3,\)"):
        naive_estimate(np.zeros(2), T_w_b)


# ------------------------------------------------------- fast kernels against lecture forms


def _synthetic_detection():
    image = blank()
    synthetic_cone(image, (320.0, 200.0), 60.0)
    (detection,) = detect_cones(image)
    return detection


@pytest.mark.parametrize("seed", range(5))
def test_world_points_match_reference(seed: int) -> None:
    """``_world_points`` (scalar rows of R_w_c) equals ``se3.apply(T_w_c, backproject)``."""
    rng = np.random.default_rng(seed)
    detection = _synthetic_detection()
    for T_w_c in random_poses(rng, 20, max_t_m=20.0):
        view = SilhouetteView(detection, CAM, T_w_c)
        uv = rng.uniform([-50.0, -50.0], [700.0, 530.0], size=(200, 2))
        z_c = rng.uniform(0.1, 60.0, 200)
        fast = np.column_stack(_world_points(view, uv[:, 0], uv[:, 1], z_c))
        reference = _world_points_reference(CAM, T_w_c, uv, z_c)
        np.testing.assert_allclose(fast, reference, rtol=0, atol=1e-12)
    # The detection's own pixels, as the estimator passes them.
    uv = view.uv()
    z_c = rng.uniform(1.0, 30.0, len(uv))
    fast = np.column_stack(_world_points(view, uv[:, 0], uv[:, 1], z_c))
    np.testing.assert_allclose(fast, _world_points_reference(CAM, T_w_c, uv, z_c), atol=1e-12)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


@pytest.mark.parametrize("seed", range(5))
def test_solve_known_height_matches_lstsq_reference(seed: int) -> None:
    """QR by Gram-Schmidt in floats against ``np.linalg.lstsq`` on random well-conditioned
    rays: consistent ones (apex and plate edge of a cone on the ground, residual 0) and
    perturbed ones (the rays off by up to 3 deg, a non-zero residual)."""
    rng = np.random.default_rng(seed)
    H, s = TRAFFIC_CONE.height_m, TRAFFIC_CONE.base_axis_distance_m
    checked = 0
    while checked < 200:
        c_w = rng.uniform([-20.0, -20.0, 1.0], [20.0, 20.0, 15.0])
        p_w = np.array([*rng.uniform(-30.0, 30.0, 2), 0.0])
        horizontal = p_w[:2] - c_w[:2]
        if np.linalg.norm(horizontal) < 2.0:
            continue
        b = np.array([*_unit(horizontal), 0.0])
        a_w = _unit(p_w + np.array([0.0, 0.0, H]) - c_w)
        g_w = _unit(p_w - s * b - c_w)
        if checked % 2:  # perturbed: the equations no longer hold exactly
            a_w = _unit(a_w + rng.uniform(-0.05, 0.05, 3))
            g_w = _unit(g_w + rng.uniform(-0.05, 0.05, 3))
        if np.arccos(np.clip(a_w @ g_w, -1.0, 1.0)) < 1e-2:
            continue  # well-conditioned rays only
        fast = solve_known_height(tuple(c_w), tuple(a_w), tuple(g_w), H, s)
        reference = _solve_known_height_reference(c_w, a_w, g_w, H, s)
        assert fast is not None
        p_fast, alpha, gamma, residual = fast
        p_ref, alpha_ref, gamma_ref, residual_ref = reference
        scale = max(1.0, abs(alpha_ref), abs(gamma_ref))
        np.testing.assert_allclose(p_fast, p_ref, rtol=0, atol=1e-9 * scale)
        assert alpha == pytest.approx(alpha_ref, rel=1e-9, abs=1e-9)
        assert gamma == pytest.approx(gamma_ref, rel=1e-9, abs=1e-9)
        assert residual == pytest.approx(residual_ref, rel=1e-6, abs=1e-9)
        if checked % 2 == 0:  # consistent: the truth comes back, exactly up to rounding
            np.testing.assert_allclose(p_fast, p_w, atol=1e-9)
            assert residual < 1e-9
        checked += 1


def test_solve_known_height_refuses_degenerate_rays() -> None:
    c_w = (0.0, 0.0, 3.0)
    g_w = tuple(_unit(np.array([5.0, 0.0, -3.0])))
    # Parallel rays (the apex and the edge on one line of sight).
    assert solve_known_height(c_w, g_w, g_w, 0.7, 0.2) is None
    # A vertical bottom ray has no horizontal bearing.
    assert solve_known_height(c_w, g_w, (0.0, 0.0, -1.0), 0.7, 0.2) is None


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 10, 11, 100, 101, 1000, 1001])
def test_median_equals_np_median(n: int) -> None:
    rng = np.random.default_rng(n)
    samples = [
        rng.normal(size=n),
        rng.integers(0, 3, n).astype(np.float64),  # ties
        np.full(n, 0.25),  # all equal
        np.sort(rng.uniform(-1e3, 1e3, n)),  # sorted
        np.sort(rng.uniform(-1e3, 1e3, n))[::-1].copy(),  # reversed
    ]
    for a in samples:
        before = a.copy()
        assert _median(a) == np.median(a)
        np.testing.assert_array_equal(a, before)  # the input is left alone


@pytest.mark.parametrize("n", [1, 2, 3, 4, 7, 50, 51, 1000])
@pytest.mark.parametrize("q", [0.0, 2.0, 25.0, 50.0, 97.5, 99.9, 100.0])
def test_percentile_equals_np_percentile(n: int, q: float) -> None:
    rng = np.random.default_rng(n)
    samples = [
        rng.normal(size=n),
        rng.integers(0, 3, n).astype(np.float64),  # ties
        rng.uniform(0.0, 0.7, n),  # heights of a cone's points
    ]
    for a in samples:
        assert _percentile(a, q) == np.percentile(a, q)
    for q_random in rng.uniform(0.0, 100.0, 20):
        assert _percentile(samples[0], q_random) == np.percentile(samples[0], q_random)


def _cone_body_points(rng: np.random.Generator, n: int, centre: np.ndarray, noise_m: float):
    """Points on horizontal circles of the cone's body (radius r(h) at height h) around
    ``centre``, on the half facing a camera at a random bearing, with uniform noise."""
    c = TRAFFIC_CONE
    t, H, r0 = c.base_thickness_m, c.height_m, c.body_radius_m
    height = rng.uniform(t + 0.02, H - 0.03, n)
    r = r0 * (H - height) / (H - t)
    bearing = rng.uniform(-np.pi, np.pi)
    phi = bearing + rng.uniform(-0.45 * np.pi, 0.45 * np.pi, n)  # the visible side
    radial = r + rng.uniform(-noise_m, noise_m, n)
    return centre[0] + radial * np.cos(phi), centre[1] + radial * np.sin(phi), r


def _least_squares_axis(qx, qy, r, c0) -> np.ndarray:
    def residuals(c):
        return np.hypot(qx - c[0], qy - c[1]) - r

    def jacobian(c):
        dist = np.hypot(qx - c[0], qy - c[1])
        return np.column_stack([-(qx - c[0]) / dist, -(qy - c[1]) / dist])

    fit = least_squares(residuals, c0, jac=jacobian, method="lm", xtol=1e-15, ftol=1e-15)
    assert fit.success
    return fit.x


@pytest.mark.parametrize("seed", range(20))
def test_fit_axis_matches_scipy_least_squares(seed: int) -> None:
    """Gauss-Newton on ``|q_i - c| - r_i`` reaches SciPy's least-squares minimum. The noise
    (+-2 mm) stays inside the trim's 5 mm floor, so the trim keeps every point."""
    rng = np.random.default_rng(seed)
    centre = rng.uniform(-20.0, 20.0, 2)
    qx, qy, r = _cone_body_points(rng, int(rng.integers(30, 400)), centre, noise_m=0.002)
    c0 = tuple(centre + rng.uniform(-0.08, 0.08, 2))  # the estimator's median start
    fast = _fit_axis(qx, qy, r, c0)
    assert fast is not None
    expected = _least_squares_axis(qx, qy, r, np.array(c0))
    np.testing.assert_allclose(fast, expected, rtol=0, atol=1e-6)
    assert np.linalg.norm(np.array(fast) - centre) < 0.01


@pytest.mark.parametrize("seed", range(10))
def test_fit_axis_trims_outliers_like_least_squares_on_the_inliers(seed: int) -> None:
    """Two gross outliers (5-10 cm off the surface, 300 points) are trimmed: the fit is SciPy's
    least-squares fit of the remaining points."""
    rng = np.random.default_rng(100 + seed)
    centre = rng.uniform(-20.0, 20.0, 2)
    qx, qy, r = _cone_body_points(rng, 300, centre, noise_m=0.002)
    outliers = rng.choice(300, 2, replace=False)
    away = rng.uniform(0.05, 0.1, 2)
    d = np.column_stack([qx[outliers] - centre[0], qy[outliers] - centre[1]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    qx[outliers] += away * d[:, 0]
    qy[outliers] += away * d[:, 1]
    inliers = np.setdiff1d(np.arange(300), outliers)
    c0 = tuple(centre + rng.uniform(-0.05, 0.05, 2))
    fast = _fit_axis(qx, qy, r, c0)
    assert fast is not None
    expected = _least_squares_axis(qx[inliers], qy[inliers], r[inliers], np.array(c0))
    np.testing.assert_allclose(fast, expected, rtol=0, atol=1e-6)


def test_fit_axis_trims_outliers_even_when_it_converges_at_once() -> None:
    rng = np.random.default_rng(7)
    centre = rng.uniform(-20.0, 20.0, 2)
    qx, qy, r = _cone_body_points(rng, 300, centre, noise_m=0.002)
    qx[:2] += 0.08 * (qx[:2] - centre[0]) / r[:2]  # two points 8 cm outside the surface
    qy[:2] += 0.08 * (qy[:2] - centre[1]) / r[:2]
    start = _least_squares_axis(qx, qy, r, centre)  # the minimum with the outliers
    fast = _fit_axis(qx, qy, r, (float(start[0]), float(start[1])))
    assert fast is not None
    expected = _least_squares_axis(qx[2:], qy[2:], r[2:], centre)
    np.testing.assert_allclose(fast, expected, rtol=0, atol=1e-6)


def test_fit_axis_gives_none_when_ill_posed() -> None:
    # Fewer than three points, or a point on the centre.
    assert _fit_axis(np.array([1.0, 2.0]), np.array([0.0, 0.0]), np.ones(2), (0.0, 0.0)) is None
    qx, qy = np.array([0.0, 1.0, -1.0]), np.array([0.0, 0.0, 0.0])
    assert _fit_axis(qx, qy, np.ones(3), (0.0, 0.0)) is None
    # All points in one direction from the centre: J^T J is singular.
    qx, qy = np.array([1.0, 2.0, 3.0]), np.zeros(3)
    assert _fit_axis(qx, qy, np.ones(3), (0.0, 0.0)) is None
