"""Each method's covariance (``vnav.covariance``) against central differences and Monte Carlo.

The Monte Carlo draws what the covariance claims to describe and pushes every draw through the
whole estimator (``vnav.localize.localize``, on images rendered by the simulator): pose errors
``exp(xi^) T_w_b`` with ``xi ~ N(0, cov_T_w_b)``, and depth images with the simulator's depth
noise. The part of a covariance due to one source is the covariance with that source minus the
covariance without it (every other term is additive and independent).
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers import render_one

from sim.noise import noisy_depth
from vnav import se3
from vnav.cone import TRAFFIC_CONE
from vnav.covariance import (
    DEPTH_FIT_FLOOR,
    GROUND_PLANE_MODEL_STD,
    _known_height_jacobian,
    ground_plane_cov,
    naive_cov,
)
from vnav.estimators import known_height_from_view, solve_known_height
from vnav.localize import localize
from vnav.noise_model import NOISELESS, NoiseModel
from vnav.sensor_noise import body_pose_covariance, keypoint_cov
from vnav.silhouette import SilhouetteView, triangle_fraction
from vnav.uncertainty import point_from_ground, transform_point

VIEWS = [
    # (cone x, y) m, drone height m, camera pitch down deg: near and steep, mid-range, far
    ((5.0, -1.5), 4.0, 30.0),
    ((8.0, 1.0), 3.0, 10.0),
    ((14.0, 2.0), 2.5, 5.0),
]

N_DRAWS = 2000
"""Monte Carlo draws per view: a sample variance's relative standard error is sqrt(2 / N) =
3.2%, a mean NEES's sqrt(2 k / N) / k = 3.2% (k = 2) or 2.6% (k = 3)."""

_POSE_NOISE = NoiseModel(position_std_m=0.05, attitude_std_deg=1.0)
"""The built-in ``uncertainty``'s pose stream: 5 cm and 1 deg per sample."""


@pytest.fixture(scope="module", params=VIEWS, ids=lambda v: f"cone{v[0]}-h{v[1]}-pitch{v[2]}")
def view(request) -> dict:
    cone_xy, height_m, pitch_deg = request.param
    world, frame, detections = render_one(cone_xy, height_m, pitch_deg)
    (detection,) = detections
    return {
        "world": world,
        "frame": frame,
        "detection": detection,
        "far_m": 0.99 * world.model.vis.map.zfar * world.model.stat.extent,
    }


def test_known_height_jacobian_matches_central_differences(view) -> None:
    """The closed-form Jacobian of the triangle solve (normal equations) against central
    differences of the same solve, in the four keypoint coordinates and the six components of a
    left perturbation of ``T_w_c`` (which moves the camera centre and turns both rays)."""
    world, det = view["world"], view["detection"]
    cam, T_w_c = world.camera, world.T_w_c
    sv = SilhouetteView(det, cam, T_w_c)
    assert not isinstance(known_height_from_view(sv, TRAFFIC_CONE), type(None))
    d, elevation = sv.vertical_at_blob()
    apex = sv.apex(d, triangle_fraction(elevation, TRAFFIC_CONE))
    bottom = sv.axis_exit(d, apex)
    J = _known_height_jacobian(sv, cam, T_w_c, apex, bottom, TRAFFIC_CONE)

    def p_at(x: np.ndarray) -> np.ndarray:
        moved = SilhouetteView(det, cam, se3.exp(x[4:]) @ T_w_c)
        a = moved.ray(apex[0] + x[0], apex[1] + x[1])
        g = moved.ray(bottom[0] + x[2], bottom[1] + x[3])
        solution = solve_known_height(
            moved.t, a, g, TRAFFIC_CONE.height_m, TRAFFIC_CONE.base_axis_distance_m
        )
        assert solution is not None
        return np.array(solution[0])

    J_cd = np.empty((3, 10))
    for i in range(10):
        step = 1e-4 if i < 4 else 1e-6  # px, then m and rad
        dx = np.zeros(10)
        dx[i] = step
        J_cd[:, i] = (p_at(dx) - p_at(-dx)) / (2.0 * step)
    np.testing.assert_allclose(J, J_cd, rtol=0.0, atol=1e-6 * np.abs(J_cd).max())


def _pose_monte_carlo(view: dict) -> tuple[dict, dict, dict]:
    world, frame, det = view["world"], view["frame"], view["detection"]
    cam, T_w_b, T_b_c = world.camera, world.T_w_b, world.T_b_c
    cov_T_w_b = body_pose_covariance(T_w_b, _POSE_NOISE)
    args = (det, cam, T_w_b, T_b_c, frame.depth)
    with_pose = localize(*args, far_m=view["far_m"], cov_T_w_b=cov_T_w_b)
    without = localize(*args, far_m=view["far_m"])
    L = np.linalg.cholesky(cov_T_w_b)
    rng = np.random.default_rng(20261124)
    samples: dict[str, list] = {m: [] for m in ("depth_image", "ground_plane", "known_height")}
    for _ in range(N_DRAWS):
        T_drawn = se3.exp(L @ rng.standard_normal(6)) @ T_w_b
        e = localize(
            det, cam, T_drawn, T_b_c, frame.depth, far_m=view["far_m"], with_covariance=False
        )
        for m, out in samples.items():
            if e[m] is not None:
                out.append(e[m])
    return with_pose, without, {m: np.array(s) for m, s in samples.items()}


_POSE_MONTE_CARLO: dict[int, tuple] = {}


def pose_monte_carlo(index: int) -> tuple:
    """``_pose_monte_carlo`` of ``VIEWS[index]``, computed once per session."""
    if index not in _POSE_MONTE_CARLO:
        cone_xy, height_m, pitch_deg = VIEWS[index]
        world, frame, (detection,) = render_one(cone_xy, height_m, pitch_deg)
        far_m = 0.99 * world.model.vis.map.zfar * world.model.stat.extent
        v = {"world": world, "frame": frame, "detection": detection, "far_m": far_m}
        _POSE_MONTE_CARLO[index] = _pose_monte_carlo(v)
    return _POSE_MONTE_CARLO[index]


# ground_plane is left out at the far view: its line of sight is 10 deg below the horizontal,
# and 1 deg of attitude noise there is not small (the ground hit's range goes as 1 / tan e);
# first order under-predicts its spread by about 8% (measured 7-10% over seeds), beyond the
# 10% criterion once sampling error is added. A gap, documented in docs/ACCURACY.md.
POSE_CASES = [(i, m) for i in range(len(VIEWS)) for m in ("depth_image", "known_height")] + [
    (0, "ground_plane"),
    (1, "ground_plane"),
]


@pytest.mark.parametrize(("index", "method"), POSE_CASES)
def test_pose_covariance_matches_monte_carlo(index: int, method: str) -> None:
    """1 deg and 5 cm of pose noise through the whole estimator, the image and depth fixed: the
    sample covariance of the estimates against the pose's part of the method's covariance.

    The criterion, in the regime where first order holds: the traces within 10%, and
    the mean NEES of the draws (about their mean) within 10% of its degrees of freedom; each
    eigenvalue within 10% (``known_height``: 15%, its Jacobian holds the keypoints where the
    image puts them, while the estimator moves them a little with the believed vertical).
    ``ground_plane`` is compared in x, y (its z is exact)."""
    with_pose, without, samples = pose_monte_carlo(index)
    drawn = samples[method]
    assert len(drawn) >= 0.99 * N_DRAWS, "the method must estimate in (almost) every draw"
    k = 2 if method == "ground_plane" else 3
    predicted = (with_pose.covariance(method) - without.covariance(method))[:k, :k]
    sample = np.cov(drawn[:, :k].T)
    assert np.trace(sample) / np.trace(predicted) == pytest.approx(1.0, abs=0.10)
    eig_tol = 0.15 if method == "known_height" else 0.10
    np.testing.assert_allclose(
        np.linalg.eigvalsh(sample) / np.linalg.eigvalsh(predicted), 1.0, atol=eig_tol
    )
    err = drawn[:, :k] - drawn[:, :k].mean(axis=0)
    nees = np.einsum("ni,ij,nj->n", err, np.linalg.inv(predicted), err)
    assert nees.mean() / k == pytest.approx(1.0, abs=0.10)


def test_depth_noise_covariance_covers_monte_carlo(view) -> None:
    """The built-in ``uncertainty`` scenario's depth noise (0.005 m + 0.0002 z^2 per pixel),
    drawn by the simulator's own ``noisy_depth`` 300 times, the pose exact: the horizontal
    spread of ``depth_image`` matches its depth-noise term within the sampling error and the
    model's reach (a factor of 1.5 on the standard deviation: the fit is not a plain mean), and
    the whole covariance (floor included) covers the error against the truth: mean NEES at most
    the upper 99% chi-square bound for 3 dof."""
    world, frame, det = view["world"], view["frame"], view["detection"]
    cam, T_w_b, T_b_c, far_m = world.camera, world.T_w_b, world.T_b_c, view["far_m"]
    noise = NoiseModel(depth_std_m=0.005, depth_std_per_m2=0.0002)
    base = localize(det, cam, T_w_b, T_b_c, frame.depth, far_m=far_m)
    noisy = localize(det, cam, T_w_b, T_b_c, frame.depth, far_m=far_m, noise=noise)
    term = noisy.covariance("depth_image") - base.covariance("depth_image")
    rng = np.random.default_rng(7)
    drawn = np.array(
        [
            localize(
                det,
                cam,
                T_w_b,
                T_b_c,
                noisy_depth(frame.depth, noise, far_m, rng),
                far_m=far_m,
                with_covariance=False,
            ).depth_image
            for _ in range(300)
        ]
    )
    std_h = np.sqrt(np.diag(np.cov(drawn.T))[:2])
    np.testing.assert_array_less(std_h, 1.5 * np.sqrt(np.diag(term)[:2]))
    np.testing.assert_array_less(np.sqrt(np.diag(term)[:2]), 1.5 * std_h)
    err = drawn - world.cones_w[0]
    cov = noisy.covariance("depth_image")
    nees = np.einsum("ni,ij,nj->n", err, np.linalg.inv(cov), err)
    # chi2(3 * 300) / 300 upper 99% point: 3 + 2.33 sqrt(6 / 300).
    assert nees.mean() <= 3.0 + 2.33 * np.sqrt(6.0 / 300)


def test_ground_plane_cov_is_point_from_ground_plus_the_plate(view) -> None:
    """``ground_plane_cov`` is the public ``vnav.uncertainty.point_from_ground`` (tested
    against central differences and Monte Carlo) at the bottom pixel, plus the plate's yaw
    term ``ConeModel.base_axis_distance_std_m`` along the horizontal bearing and the method's
    own ``GROUND_PLANE_MODEL_STD`` of range in x and y."""
    world, det = view["world"], view["detection"]
    cam, T_w_c = world.camera, world.T_w_c
    cov_T = body_pose_covariance(world.T_w_b, _POSE_NOISE)
    sv = SilhouetteView(det, cam, T_w_c)
    noise = NoiseModel(intensity_std_grey=4.0)
    p_w = localize(det, cam, world.T_w_b, world.T_b_c).ground_plane
    d, _ = sv.vertical_at_blob()
    _, expected = point_from_ground(
        cam,
        T_w_c,
        sv.bottom(TRAFFIC_CONE),
        cov_uv=keypoint_cov("bottom", 4.0, d),
        cov_T_w_c=cov_T,
    )
    b = (p_w - T_w_c[:3, 3])[:2]
    b /= np.linalg.norm(b)
    expected[:2, :2] += TRAFFIC_CONE.base_axis_distance_std_m**2 * np.outer(b, b)
    range_m = np.linalg.norm(p_w - T_w_c[:3, 3])
    expected[:2, :2] += (GROUND_PLANE_MODEL_STD * range_m) ** 2 * np.eye(2)
    got = ground_plane_cov(sv, cam, T_w_c, cov_T, p_w, noise, TRAFFIC_CONE)
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-15)


def test_naive_cov_is_the_body_origin_plus_the_best_estimate_in_camera_axes(view) -> None:
    """``naive_cov``: the body origin through the body pose (``transform_point`` of the zero
    point) plus the best estimate's covariance turned into camera axes."""
    world = view["world"]
    T_w_b = world.T_w_b
    cov_T = body_pose_covariance(T_w_b, _POSE_NOISE)
    rng = np.random.default_rng(3)
    A = rng.standard_normal((3, 3))
    cov_best = A @ A.T
    R_c_w = world.T_w_c[:3, :3].T
    _, cov_origin = transform_point(T_w_b, cov_T, np.zeros(3), np.zeros((3, 3)))
    np.testing.assert_allclose(
        naive_cov(T_w_b, cov_T, R_c_w, cov_best),
        cov_origin + R_c_w @ cov_best @ R_c_w.T,
        rtol=1e-12,
        atol=1e-15,
    )


def test_localize_without_noise_or_pose_covariance_keeps_the_model_terms(view) -> None:
    """With no noise and exact poses the covariances are the methods' own model terms, not
    zero: ``depth_image``'s floor, the plate's yaw for the others; and ``with_covariance=False``
    gives the same points with no covariances."""
    world, frame, det = view["world"], view["frame"], view["detection"]
    args = (det, world.camera, world.T_w_b, world.T_b_c, frame.depth)
    est = localize(*args, far_m=view["far_m"], noise=NOISELESS)
    points_only = localize(*args, far_m=view["far_m"], with_covariance=False)
    assert points_only.cov_w_by_method == {}
    for m in est:
        if est[m] is None:
            assert est.covariance(m) is None
            continue
        np.testing.assert_array_equal(points_only[m], est[m])
        cov = est.covariance(m)
        assert np.all(np.linalg.eigvalsh(cov) >= -1e-15)
        assert np.trace(cov) > 0.0


def test_uncertainty_builtin_covariance_grows_with_range_as_the_chain_predicts(builtin_runs):
    """In the built-in ``uncertainty`` (5 cm, 1 deg of pose noise per sample), a body-frame
    rotation error ``dtheta`` moves a point seen at range ``r`` by ``dtheta x (p_w - t_w_b)``:
    across the line of sight, horizontally, by ``r dtheta`` whatever the axis, so the chain
    ``p_w = T_w_b T_b_c p_c`` predicts a variance ``s_p^2 + (r s_a)^2`` there, times the
    interpolation factor of the pose between its two samples (``(1 - a)^2 + a^2``, between
    1/2 and 1). ``depth_image``'s covariance across the line of sight must lie between that
    prediction at its lowest factor and at its highest plus the method's floor (ranges from
    the pose the estimator was given, about which the covariance is taken)."""
    run = builtin_runs["uncertainty"]
    noise = run.spec.noise
    s_p, s_a = noise.position_std_m, np.radians(noise.attitude_std_deg)
    checked = 0
    for tick in run.result.ticks:
        t_w_b = tick.T_w_b_est[:3, 3]  # the pose the estimator was given
        for d in tick.detections:
            if "depth_image" not in d.covariances_w:
                continue
            p_w = d.estimates_w["depth_image"]
            v = p_w - t_w_b
            across = np.array([-v[1], v[0], 0.0]) / np.hypot(v[0], v[1])
            variance = across @ d.covariances_w["depth_image"] @ across
            chain = s_p**2 + (np.linalg.norm(v) * s_a) ** 2
            floor = (DEPTH_FIT_FLOOR[0] + DEPTH_FIT_FLOOR[1] * np.linalg.norm(v)) ** 2
            assert 0.5 * chain * 0.999 <= variance <= chain * 1.001 + floor + 1e-6
            checked += 1
    assert checked > 50
