"""vnav.uncertainty against independent oracles: central differences of the exact chain,
Monte Carlo samples pushed through it, and SciPy's chi-square quantiles."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from vnav import se3, so3
from vnav.camera import PinholeCamera
from vnav.uncertainty import (
    compose,
    invert,
    nees,
    nees_band,
    nees_many,
    nees_p_value,
    point_from_depth,
    point_from_ground,
    transform_point,
)

CAMERA = PinholeCamera.from_fovy(60.0, 640, 480)
N_MC = 4000


def _pose(rng, height=None):
    R = so3.exp(rng.normal(0.0, 1.0, 3))
    t = rng.normal(0.0, 3.0, 3)
    if height is not None:  # a camera above the ground looking down-ish
        R = so3.rot_x(-np.pi / 2 - 0.4) @ so3.rot_z(rng.uniform(-1, 1))
        R = so3.rot_z(rng.uniform(-np.pi, np.pi)) @ so3.rot_x(-np.pi + 0.6)
        t = np.array([*rng.normal(0.0, 3.0, 2), height])
    return se3.make(R, t)


def _cov6(rng, pos_m=0.05, rot_deg=0.5):
    rot_rad = np.radians(rot_deg)
    A = rng.normal(size=(6, 6)) * 0.3
    S = A @ A.T + np.eye(6)
    d = np.array([pos_m] * 3 + [rot_rad] * 3)
    return S * np.outer(d, d) / np.mean(np.diag(S))


def _close_covariance(sample, predicted, rtol=0.10):
    """Traces and eigenvalues within rtol: 4000 samples give a covariance within ~5% (2 sd of
    the sample variance, sqrt(2/4000) = 2.2%) where first order holds."""
    assert np.trace(sample) == pytest.approx(np.trace(predicted), rel=rtol)
    w_s, w_p = np.linalg.eigvalsh(sample), np.linalg.eigvalsh(predicted)
    keep = w_p > 1e-9 * w_p[-1]
    np.testing.assert_allclose(w_s[keep], w_p[keep], rtol=rtol)


def test_stacked_exp_and_log_are_se3_exp_and_se3_log_one_by_one(rng):
    """``helpers.se3_exp_stack`` and ``se3_log_stack``, which push the Monte Carlo draws of
    this file, test_tracking and test_sensor_noise through the chain a stack at a time, equal
    ``se3.exp`` and ``se3.log`` one by one (rotation angles uniform, tiny, on the Taylor
    branch, near and at pi; translations up to metres)."""
    from helpers import rotation_vectors, se3_exp_stack, se3_log_stack

    xi = np.concatenate([rng.normal(0.0, 3.0, (600, 3)), rotation_vectors(rng, 600)], axis=1)
    T = se3_exp_stack(xi)
    for xi_i, T_i in zip(xi, T, strict=True):
        np.testing.assert_allclose(T_i, se3.exp(xi_i), rtol=0, atol=1e-13)
    for T_i, log_i in zip(T, se3_log_stack(T), strict=True):
        np.testing.assert_allclose(log_i, se3.log(T_i), rtol=0, atol=1e-13)


def _fd_pose_jacobian(f, T, eps=1e-6):
    return np.column_stack(
        [(f(se3.exp(eps * e) @ T) - f(se3.exp(-eps * e) @ T)) / (2 * eps) for e in np.eye(6)]
    )


def test_point_jacobians_match_central_differences(rng):
    """The propagated covariance of a unit-covariance input is J J^T: each Jacobian block."""
    for _ in range(10):
        T = _pose(rng, height=rng.uniform(2.0, 10.0))
        uv, z = np.array([rng.uniform(100, 540), rng.uniform(300, 460)]), rng.uniform(2.0, 20.0)
        # pose block of point_from_depth = [I, -p^] of transform_point
        p_c = CAMERA.backproject(uv, z)[0]
        J = _fd_pose_jacobian(lambda T_, p=p_c: se3.apply(T_, p), T)
        for e in np.eye(6):
            _, cov = point_from_depth(
                CAMERA, T, uv, z, cov_uv=np.zeros((2, 2)), var_z=0.0, cov_T_w_c=np.outer(e, e)
            )
            np.testing.assert_allclose(cov, np.outer(J @ e, J @ e), atol=1e-6)

        # ground: pose and pixel blocks
        def ground(T_, uv_=uv):
            d_w = T_[:3, :3] @ np.array(
                [(uv_[0] - CAMERA.cx) / CAMERA.fx, (uv_[1] - CAMERA.cy) / CAMERA.fy, 1.0]
            )
            return T_[:3, 3] - T_[2, 3] / d_w[2] * d_w

        if (T[:3, :3] @ [(uv[0] - CAMERA.cx) / CAMERA.fx, (uv[1] - CAMERA.cy) / CAMERA.fy, 1.0])[
            2
        ] > -0.05:
            continue
        J = _fd_pose_jacobian(ground, T)
        for e in np.eye(6):
            _, cov = point_from_ground(
                CAMERA, T, uv, cov_uv=np.zeros((2, 2)), cov_T_w_c=np.outer(e, e)
            )
            np.testing.assert_allclose(
                cov, np.outer(J @ e, J @ e), atol=1e-5 * (1 + np.abs(J @ e).max() ** 2)
            )
        for k in range(2):
            step = np.eye(2)[k] * 1e-4
            col = (ground(T, uv + step) - ground(T, uv - step)) / 2e-4
            _, cov = point_from_ground(
                CAMERA,
                T,
                uv,
                cov_uv=np.outer(np.eye(2)[k], np.eye(2)[k]),
                cov_T_w_c=np.zeros((6, 6)),
            )
            np.testing.assert_allclose(
                cov, np.outer(col, col), atol=1e-6 * (1 + np.abs(col).max() ** 2)
            )


def test_monte_carlo_matches_the_propagated_covariance(rng):
    from helpers import se3_exp_stack, se3_log_stack  # the draws a stack at a time

    T = se3.make(so3.rot_x(-np.pi + 0.7), [1.0, -2.0, 6.0])
    cov_T = _cov6(rng)
    uv, z = np.array([300.0, 330.0]), 9.0
    cov_uv, var_z = np.diag([0.5**2, 0.4**2]), 0.05**2
    p_d, cov_d = point_from_depth(CAMERA, T, uv, z, cov_uv=cov_uv, var_z=var_z, cov_T_w_c=cov_T)
    _, cov_g = point_from_ground(CAMERA, T, uv, cov_uv=cov_uv, cov_T_w_c=cov_T)
    xis = rng.multivariate_normal(np.zeros(6), cov_T, N_MC)
    uvs = rng.multivariate_normal(uv, cov_uv, N_MC)
    zs = z + rng.normal(0.0, np.sqrt(var_z), N_MC)
    T_i = se3_exp_stack(xis) @ T
    R_i, t_i = T_i[:, :3, :3], T_i[:, :3, 3]
    depth_pts = np.einsum("nij,nj->ni", R_i, CAMERA.backproject(uvs, zs)) + t_i
    x_c = (uvs - [CAMERA.cx, CAMERA.cy]) / [CAMERA.fx, CAMERA.fy]
    d_w = np.einsum("nij,nj->ni", R_i, np.column_stack([x_c, np.ones(N_MC)]))
    ground_pts = t_i - (t_i[:, 2] / d_w[:, 2])[:, None] * d_w
    _close_covariance(np.cov(depth_pts.T), cov_d)
    _close_covariance(np.cov(ground_pts.T), cov_g)
    values = [nees(p - p_d, cov_d)[0] for p in depth_pts[:500]]
    low, high = nees_band(3, 500)
    assert low <= np.mean(values) <= high
    # compose and invert
    T2, cov2 = _pose(rng), _cov6(rng)
    T_ac, cov_ac = compose(T, cov_T, T2, cov2)
    xi2 = rng.multivariate_normal(np.zeros(6), cov2, N_MC)
    samples = se3_log_stack(T_i @ se3_exp_stack(xi2) @ T2 @ se3.invert(T_ac))
    _close_covariance(np.cov(samples.T), cov_ac)
    _, cov_inv = invert(T, cov_T)
    samples = se3_log_stack(se3.invert(T_i) @ T)
    _close_covariance(np.cov(samples.T), cov_inv)
    p_b, cov_p = np.array([2.0, -1.0, 4.0]), np.diag([0.01, 0.02, 0.03]) ** 2
    _, cov_a = transform_point(T, cov_T, p_b, cov_p)
    dps = rng.multivariate_normal(np.zeros(3), cov_p, N_MC)
    pts = np.einsum("nij,nj->ni", R_i, p_b + dps) + t_i
    _close_covariance(np.cov(pts.T), cov_a)


def test_fourth_order_closes_most_of_the_gap_on_a_chain(rng):
    """B&F's experiment: compound K = 30 uncertain steps with 10 deg of rotational noise each;
    order 4 stays closer to Monte Carlo than order 2."""
    from helpers import se3_exp_stack, se3_log_stack  # the draws a stack at a time

    step = se3.make(so3.rot_z(0.05), [0.5, 0.0, 0.0])
    cov_step = np.diag([0.01**2] * 3 + [np.radians(10.0) ** 2] * 3)
    K = 30
    T2, c2 = np.eye(4), np.zeros((6, 6))
    T4, c4 = np.eye(4), np.zeros((6, 6))
    for _ in range(K):
        T2, c2 = compose(T2, c2, step, cov_step, order=2)
        T4, c4 = compose(T4, c4, step, cov_step, order=4)
    # 2000 chains of K noisy steps (K draws each, in the order of a chain-by-chain loop).
    xis = rng.multivariate_normal(np.zeros(6), cov_step, (2000, K))
    noise = se3_exp_stack(xis.reshape(-1, 6)).reshape(2000, K, 4, 4)
    T = np.broadcast_to(np.eye(4), (2000, 4, 4))
    for k in range(K):
        T = T @ noise[:, k] @ step
    mc = np.cov(se3_log_stack(T @ se3.invert(T2)).T)
    gap2 = np.linalg.norm(c2 - mc) / np.linalg.norm(mc)
    gap4 = np.linalg.norm(c4 - mc) / np.linalg.norm(mc)
    # Measured (seed 3 of a scratch run): order 2 is 14% off in Frobenius norm, order 4 5%.
    assert gap2 > 0.1  # second order is measurably off here
    assert gap4 < 0.5 * gap2


def test_nees_band_and_p_value_against_scipy():
    for dof, count in ((3, 50), (2, 121), (3, 121), (3, 1000)):
        low, high = nees_band(dof, count)
        k = dof * count
        assert low == pytest.approx(chi2.ppf(0.025, k) / count, rel=5e-3)
        assert high == pytest.approx(chi2.ppf(0.975, k) / count, rel=5e-3)
        assert nees_p_value(low, dof, count) == pytest.approx(0.05, abs=1e-9)
    exact = 2.0 * (1.0 - chi2.cdf(6.0, 6))
    assert nees_p_value(3.0, 3, 2) == pytest.approx(exact, abs=0.01)


def test_nees_of_a_rank_two_covariance_has_two_dof():
    cov = np.diag([1.0, 4.0, 0.0])
    assert nees([1.0, 2.0, 0.0], cov) == (pytest.approx(2.0), 2)
    assert nees([1.0, 2.0, 0.1], cov)[0] == np.inf


def test_nees_of_a_full_rank_stack_is_nees_pair_by_pair_to_the_last_bit(rng):
    """Stacks whose covariances all have full rank (a detection's methods, the usual case,
    which ``nees_many`` scores as one product and one sum) against ``nees`` one pair at a
    time: equal to the last bit, for 1 to 9 pairs, well and badly conditioned."""
    for _ in range(300):
        m = int(rng.integers(1, 10))
        A = rng.normal(0.0, 1.0, (m, 3, 3)) * rng.uniform(1e-4, 1.0, (m, 1, 3))
        covs = A @ A.transpose(0, 2, 1) + 1e-12 * np.eye(3)
        errors = rng.normal(0.0, rng.uniform(0.01, 3.0), (m, 3))
        got = nees_many(errors, covs)
        assert got == [nees(e, c) for e, c in zip(errors, covs, strict=True)]
        assert all(dof == 3 for _, dof in got)


def test_nees_of_a_stack_is_nees_pair_by_pair_to_the_last_bit(rng):
    """``nees_many`` (one decomposition of the stacked covariances) against ``nees`` one pair
    at a time: covariances of rank 3, 2 (exact in z, with and without an error along z), 1
    and 0, and the same refusal of a bad covariance."""
    errors, covs = [], []
    for rank in (3, 3, 2, 2, 1, 0, 0) * 30:
        A = rng.normal(0.0, rng.uniform(0.01, 1.0), (3, rank))
        cov = A @ A.T
        error = rng.normal(0.0, 0.3, 3)
        if rank == 2:
            cov[2, :] = cov[:, 2] = 0.0
            error[2] *= rng.integers(0, 2)  # in the covariance's range, or off it (inf)
        if rank == 0 and rng.integers(0, 2):
            error[:] = 0.0
        errors.append(error)
        covs.append(cov)
    got = nees_many(np.array(errors), np.array(covs))
    want = [nees(e, c) for e, c in zip(errors, covs, strict=True)]
    assert got == want
    assert {v == np.inf for v, _ in want} == {True, False}
    assert {dof for _, dof in want} == {0, 1, 2, 3}
    assert nees_many(np.zeros((0, 3)), np.zeros((0, 3, 3))) == []
    bad = np.array(covs[:3])
    bad[1] = -np.eye(3)
    with pytest.raises(ValueError, match="semidefinite"):
        nees_many(np.array(errors[:3]), bad)
    with pytest.raises(ValueError, match=r"\(M, n\)"):
        nees_many(np.array(errors[:3]), np.array(covs[:2]))


@pytest.mark.parametrize(
    ("cov", "match"),
    [
        (np.eye(6)[:5], "shape"),
        (np.triu(np.ones((6, 6))), "symmetric"),
        (-np.eye(6), "semidefinite"),
        (np.full((6, 6), np.nan), "finite"),
    ],
)
def test_bad_covariances_are_refused(cov, match):
    with pytest.raises(ValueError, match=match):
        compose(np.eye(4), cov, np.eye(4), np.eye(6))


def test_bad_order_and_rays_that_miss_the_ground():
    with pytest.raises(ValueError, match="order"):
        compose(np.eye(4), np.eye(6), np.eye(4), np.eye(6), order=3)
    up = se3.make(np.eye(3), [0.0, 0.0, 5.0])  # optical axis along world z: up
    with pytest.raises(ValueError, match="does not reach the ground"):
        point_from_ground(CAMERA, up, [320.0, 240.0], cov_uv=np.eye(2), cov_T_w_c=np.eye(6))
