"""Unit tests of so3, quat and se3 beyond the lecture, references and properties."""

from __future__ import annotations

import numpy as np
import pytest

from vnav import quat, se3, so3


@pytest.mark.parametrize("eps", [0.0, 1e-15, 1e-12, 1e-9, 1e-6])
@pytest.mark.parametrize("axis", [[0, 0, 1], [1, 0, 0], [0.3, -0.5, 0.81], [1, 1, 1], [-2, 1, 0.1]])
def test_log_near_and_at_pi(axis, eps):
    u = np.asarray(axis, float) / np.linalg.norm(axis)
    v = (np.pi - eps) * u
    R = so3.exp(v)
    w = so3.log(R)
    if eps == 0.0 and np.dot(w, v) < 0:
        w = -w  # at pi both signs are right
    np.testing.assert_allclose(w, v, atol=1e-12)
    np.testing.assert_allclose(so3.exp(w), R, atol=1e-15)
    # The arccos of the trace alone would lose ~half the digits here.


@pytest.mark.parametrize("angle", [0.0, 1e-300, 1e-15, 1e-9, 1e-5, 1e-4, 1.1e-4])
def test_exp_log_near_zero(angle):
    v = angle * np.array([0.6, -0.8, 0.0])
    R = so3.exp(v)
    np.testing.assert_allclose(so3.log(R), v, atol=1e-18, rtol=1e-12)
    assert so3.is_rotation(R, atol=1e-15)


def test_batched_shapes():
    rng = np.random.default_rng(1)
    v = rng.normal(size=(4, 5, 3))
    R = so3.exp(v)
    assert R.shape == (4, 5, 3, 3)
    np.testing.assert_allclose(R[2, 3], so3.exp(v[2, 3]), atol=0)
    assert so3.log(R).shape == (4, 5, 3)
    assert so3.skew(v).shape == (4, 5, 3, 3)
    assert so3.rot_x(np.zeros(7)).shape == (7, 3, 3)
    assert so3.from_rpy(np.zeros(6), 0.1, np.zeros((2, 1))).shape == (2, 6, 3, 3)
    assert so3.to_rpy(R).shape == (4, 5, 3)
    assert so3.gimbal_locked(R).shape == (4, 5)
    q = quat.from_matrix(R)
    assert q.shape == (4, 5, 4)
    assert quat.to_matrix(q).shape == (4, 5, 3, 3)
    assert quat.slerp(q[0, 0], q[1, 1], np.linspace(0, 1, 9)).shape == (9, 4)
    assert se3.make(R, np.zeros(3)).shape == (4, 5, 4, 4)
    assert se3.invert(se3.make(R, np.zeros(3))).shape == (4, 5, 4, 4)
    p = rng.normal(size=(1000, 3))
    assert se3.apply(se3.make(R[0, 0], [1, 2, 3]), p).shape == (1000, 3)


def test_skew_is_cross_product():
    a, b = np.array([1.0, -2.0, 0.5]), np.array([0.3, 0.1, -4.0])
    np.testing.assert_allclose(so3.skew(a) @ b, np.cross(a, b), atol=1e-15)


def test_nearest_rotation():
    rng = np.random.default_rng(2)
    R = so3.exp(rng.normal(size=(10, 3)))
    noisy = R + 1e-4 * rng.normal(size=R.shape)
    P = so3.nearest_rotation(noisy)
    assert so3.is_rotation(P, atol=1e-14)
    np.testing.assert_allclose(P, R, atol=1e-3)
    np.testing.assert_allclose(so3.nearest_rotation(R), R, atol=1e-14)
    # A reflection is projected onto a rotation (det fixed to +1).
    assert so3.is_rotation(so3.nearest_rotation(np.diag([1.0, 1.0, -1.0])))


def test_quaternion_conventions():
    q = quat.from_axis_angle([0.0, 0.0, 2.0], np.pi / 2)  # axis need not be unit
    np.testing.assert_allclose(q, [0, 0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-16)
    np.testing.assert_array_equal(quat.xyzw_to_wxyz([1.0, 2.0, 3.0, 4.0]), [4, 1, 2, 3])
    np.testing.assert_array_equal(quat.wxyz_to_xyzw([4.0, 1.0, 2.0, 3.0]), [1, 2, 3, 4])
    axis, angle = quat.to_axis_angle(-q)  # sign canonicalised
    np.testing.assert_allclose(axis, [0, 0, 1], atol=1e-16)
    np.testing.assert_allclose(angle, np.pi / 2, atol=1e-16)
    axis, angle = quat.to_axis_angle([0.0, 0.0, 0.0, 1.0])
    assert angle == 0.0 and np.linalg.norm(axis) == 1.0
    # Rotations by pi: from_matrix w = 0, still a valid quaternion of the rotation.
    for v in ([np.pi, 0, 0], [0, np.pi, 0], [0, 0, np.pi], np.pi * np.array([1, 1, 1]) / 3**0.5):
        R = so3.exp(v)
        np.testing.assert_allclose(quat.to_matrix(quat.from_matrix(R)), R, atol=1e-15)


def test_slerp_takes_the_short_way():
    a = quat.from_axis_angle([0, 0, 1], 0.0)
    b = -quat.from_axis_angle([0, 0, 1], 0.4)  # same rotation as +b, opposite hemisphere
    mid = quat.slerp(a, b, 0.5)
    np.testing.assert_allclose(quat.to_matrix(mid), so3.rot_z(0.2), atol=1e-15)
    np.testing.assert_allclose(quat.slerp(a, a, 0.3), a, atol=1e-16)


def test_se3_invert_is_closed_form_exact():
    T = se3.make(so3.exp([0.4, -1.2, 2.9]), [100.0, -3.0, 0.25])
    T_inv = se3.invert(T)
    assert T_inv[3].tolist() == [0.0, 0.0, 0.0, 1.0]  # exact bottom row, unlike a general inverse
    np.testing.assert_array_equal(T_inv[:3, :3], T[:3, :3].T)
    np.testing.assert_allclose(T_inv @ T, np.eye(4), atol=1e-13)


def test_apply_nan_points_pass_through():
    T = se3.make(so3.rot_z(0.5), [1.0, 2.0, 3.0])
    p = np.array([[1.0, 2.0, 3.0], [np.nan, np.nan, np.nan]])
    out = se3.apply(T, p)
    assert np.all(np.isfinite(out[0])) and np.all(np.isnan(out[1]))
    # The chunked fast path agrees with the plain formula at every length around its blocks.
    rng = np.random.default_rng(3)
    for n in (1, 511, 512, 513, 131071, 131073):
        p = rng.normal(size=(n, 3))
        np.testing.assert_allclose(se3.apply(T, p), p @ T[:3, :3].T + T[:3, 3], atol=1e-14)


def test_vee_inverts_skew_and_gives_the_cross_product_vector():
    rng = np.random.default_rng(5)
    v = rng.normal(size=(20, 3))
    np.testing.assert_array_equal(so3.vee(so3.skew(v)), v)
    u = rng.normal(size=3)
    # skew(v) u = v x u (lecture chapter 5), checked against numpy's cross product.
    np.testing.assert_allclose(so3.skew(v[0]) @ u, np.cross(v[0], u), atol=1e-15)
    with pytest.raises(ValueError, match="shape"):
        so3.vee(np.zeros((3, 2)))
