"""vnav.se3: rigid transforms as 4x4 matrices; against SciPy's RigidTransform.

The exponential map, its inverse and the adjoint are checked against the matrix exponential of
the 4x4 hat (``scipy.linalg.expm``) and SciPy's ``RigidTransform`` exponential coordinates,
and by their laws over Hypothesis-drawn transforms (near-identity and near-pi rotations
included). The group laws SE(3) shares with SO(3) and the unit quaternions are in
test_group_laws.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers import (
    PROPERTY_SETTINGS,
    assert_same_rotvec,
    random_poses,
    rotation_vectors,
    rotvecs,
    transforms,
    translations,
    unit_quaternions,
)
from hypothesis import given
from hypothesis import strategies as st

from vnav import quat, se3, so3

SETTINGS = PROPERTY_SETTINGS
R_OK = so3.rot_z(0.3)
T_OK = se3.make(R_OK, [1.0, 2.0, 3.0])


@st.composite
def twists(draw) -> np.ndarray:
    """``xi = [rho, phi]``: a translation part up to 100 m per axis and a rotation vector with
    its angle in [0, pi], near-identity and near-pi angles included (``helpers.angles``)."""
    return np.concatenate([draw(translations), draw(rotvecs())])


def _hat(xi: np.ndarray) -> np.ndarray:
    """``xi^ = [[phi^, rho], [0, 0]]``, the 4x4 matrix whose exponential is ``se3.exp(xi)``."""
    X = np.zeros((4, 4))
    X[:3, :3] = so3.skew(xi[3:])
    X[:3, 3] = xi[:3]
    return X


# ------------------------------------------------------------------------------- unit tests


def test_batched_shapes():
    rng = np.random.default_rng(1)
    R = so3.exp(rng.normal(size=(4, 5, 3)))
    assert se3.make(R, np.zeros(3)).shape == (4, 5, 4, 4)
    assert se3.invert(se3.make(R, np.zeros(3))).shape == (4, 5, 4, 4)
    p = rng.normal(size=(1000, 3))
    assert se3.apply(se3.make(R[0, 0], [1, 2, 3]), p).shape == (1000, 3)


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


# ---------------------------------------------------------------------------- properties


@SETTINGS
@given(transforms(), st.lists(translations, min_size=1, max_size=20))
def test_apply_is_homogeneous_multiplication(T, points):
    p = np.array(points)
    p_h = np.column_stack([p, np.ones(len(p))])
    np.testing.assert_allclose(se3.apply(T, p), (T @ p_h.T).T[:, :3], atol=1e-12)
    np.testing.assert_allclose(se3.apply(se3.invert(T), se3.apply(T, p)), p, atol=1e-11)
    np.testing.assert_allclose(se3.apply(T, p[0]), se3.apply(T, p)[0], atol=1e-12)


# ------------------------------------------------------------ independent implementations


def test_se3_apply_matches_scipy_rigid_transform(rng):
    from scipy.spatial.transform import RigidTransform

    for v, t in zip(rotation_vectors(rng, 50), rng.uniform(-5, 5, (50, 3)), strict=True):
        T = se3.make(so3.exp(v), t)
        p = rng.uniform(-10, 10, (1000, 3))
        rigid = RigidTransform.from_matrix(T)
        np.testing.assert_allclose(se3.apply(T, p), rigid.apply(p), atol=1e-13)
        np.testing.assert_allclose(se3.invert(T), rigid.inv().as_matrix(), atol=1e-14)


# ------------------------------------------------------- exponential map and adjoint


def _exp_atol(xi: np.ndarray) -> float:
    """How far ``se3.exp(xi)`` may be from the matrix exponential: rounding, plus the closed
    form's ``(1 - cos t) / t^2`` above the series branch (t >= 1e-6 rad), whose cancellation
    costs about ``eps / t^2`` on that coefficient, so ``eps |rho| / t`` on the translation (2e-8
    at 100 m and t = 1e-6: the price of keeping the results bit-for-bit as they were)."""
    rho = float(np.linalg.norm(xi[:3]))
    theta = float(np.linalg.norm(xi[3:]))
    cancellation = 2.2e-16 * rho / theta if theta >= 1e-6 else 0.0
    return 2e-13 * (1.0 + rho) + cancellation


@SETTINGS
@given(twists())
def test_exp_is_the_matrix_exponential_of_the_hat(xi):
    from scipy.linalg import expm

    np.testing.assert_allclose(se3.exp(xi), expm(_hat(xi)), rtol=0, atol=_exp_atol(xi))


def test_exp_and_log_match_scipy_exponential_coordinates(rng):
    """SciPy orders exponential coordinates ``[phi, rho]``; vnav, as B&F, ``[rho, phi]``."""
    from scipy.linalg import expm
    from scipy.spatial.transform import RigidTransform

    phis = rotation_vectors(rng, 300)  # uniform, near 0, near pi, exactly pi, 0
    rhos = rng.uniform(-10.0, 10.0, (300, 3))
    for phi, rho in zip(phis, rhos, strict=True):
        xi = np.concatenate([rho, phi])
        T = se3.exp(xi)
        oracle = RigidTransform.from_exp_coords(np.concatenate([phi, rho])).as_matrix()
        np.testing.assert_allclose(T, oracle, rtol=0, atol=_exp_atol(xi))
        np.testing.assert_allclose(T, expm(_hat(xi)), rtol=0, atol=_exp_atol(xi))
        if np.linalg.norm(phi) < np.pi - 1e-6:  # at pi, phi and -phi are one rotation
            coords = RigidTransform.from_matrix(T).as_exp_coords()
            np.testing.assert_allclose(
                se3.log(T), np.concatenate([coords[3:], coords[:3]]), atol=1e-11
            )
    # Angles beyond pi: exp is still the matrix exponential; log returns the angle in [0, pi].
    for angle in (3.5, 2.0 * np.pi - 1e-3, 5.0 * np.pi):
        xi = np.array([1.0, -2.0, 0.5, *(angle * np.array([0.6, 0.0, 0.8]))])
        T = se3.exp(xi)
        np.testing.assert_allclose(T, expm(_hat(xi)), atol=1e-12)
        assert np.linalg.norm(se3.log(T)[3:]) <= np.pi
        np.testing.assert_allclose(se3.exp(se3.log(T)), T, atol=1e-12)


@SETTINGS
@given(transforms())
def test_exp_of_log_is_the_transform(T):
    xi = se3.log(T)
    assert xi.shape == (6,) and np.linalg.norm(xi[3:]) <= np.pi + 1e-15
    np.testing.assert_allclose(se3.exp(xi), T, rtol=0, atol=_exp_atol(xi))


@SETTINGS
@given(twists())
def test_log_of_exp_is_the_twist(xi):
    back = se3.log(se3.exp(xi))
    atol = 4.0 * _exp_atol(xi)  # J^-1 is well conditioned for angles up to pi
    if np.linalg.norm(xi[3:]) < np.pi - 1e-6:
        np.testing.assert_allclose(back, xi, rtol=0, atol=atol)
    else:  # at pi the rotation vector may come back as -phi, and rho = J(phi)^-1 t with it
        assert_same_rotvec(back[3:], xi[3:], atol=1e-12)
        np.testing.assert_allclose(se3.exp(back), se3.exp(xi), rtol=0, atol=atol)


def test_exp_and_log_at_identity_and_across_the_small_angle_branch():
    from scipy.linalg import expm

    assert np.array_equal(se3.exp(np.zeros(6)), np.eye(4))
    assert np.array_equal(se3.log(np.eye(4)), np.zeros(6))
    axis = np.array([0.48, -0.6, 0.64])
    for angle in (1e-12, 1e-7, 9.99e-7, 1e-6, 1.01e-6, 1e-5):  # _SMALL_ANGLE is 1e-6
        xi = np.array([3.0, -1.0, 2.0, *(angle * axis)])
        np.testing.assert_allclose(se3.exp(xi), expm(_hat(xi)), rtol=0, atol=_exp_atol(xi))
        np.testing.assert_allclose(se3.log(se3.exp(xi)), xi, rtol=0, atol=4.0 * _exp_atol(xi))


@SETTINGS
@given(transforms(), twists())
def test_adjoint_moves_a_perturbation_across_the_pose(T, xi):
    """``T xi^ T^-1 = (Ad(T) xi)^`` (linear, to rounding) and so ``T exp(xi^) T^-1 =
    exp((Ad(T) xi)^)`` (B&F eq. 12)."""
    Ad = se3.adjoint(T)
    T_inv = se3.invert(T)
    np.testing.assert_allclose(T @ _hat(xi) @ T_inv, _hat(Ad @ xi), rtol=0, atol=1e-10)
    small = 1e-2 * xi / max(1.0, float(np.linalg.norm(xi)))
    np.testing.assert_allclose(T @ se3.exp(small) @ T_inv, se3.exp(Ad @ small), rtol=0, atol=1e-12)


def test_adjoint_is_a_group_homomorphism(rng):
    """``Ad(T1 T2) = Ad(T1) Ad(T2)`` and ``Ad(T^-1) = Ad(T)^-1``; the blocks as B&F write them."""
    T1, T2 = random_poses(rng, 2)
    np.testing.assert_allclose(
        se3.adjoint(T1 @ T2), se3.adjoint(T1) @ se3.adjoint(T2), rtol=0, atol=1e-12
    )
    np.testing.assert_allclose(
        se3.adjoint(se3.invert(T1)) @ se3.adjoint(T1), np.eye(6), rtol=0, atol=1e-13
    )
    Ad = se3.adjoint(T1)
    C, t = T1[:3, :3], T1[:3, 3]
    np.testing.assert_array_equal(Ad[:3, :3], C)
    np.testing.assert_array_equal(Ad[3:, 3:], C)
    np.testing.assert_array_equal(Ad[3:, :3], np.zeros((3, 3)))
    np.testing.assert_allclose(Ad[:3, 3:], np.cross(t, C, axis=0), rtol=0, atol=1e-14)


# ------------------------------------------ seven components: quaternion xyzw, translation


def _matrix_of(x: tuple) -> np.ndarray:
    """The 4x4 transform of components ``(qx, qy, qz, qw, x, y, z)`` (one pose)."""
    return se3.make(quat.to_matrix(np.array(x[:4])), np.array(x[4:]))


@SETTINGS
@given(unit_quaternions(), translations, unit_quaternions(), translations)
def test_compose_and_invert_xyzw_xyz_are_the_matrix_product_and_inverse(q_a, t_a, q_b, t_b):
    """On plain floats (one pose, as ``FrameBuffer``'s single lookups call them): the product
    and the closed-form inverse of the 4x4 matrices, quaternions of either sign."""
    x_a = tuple(float(c) for c in (*q_a, *t_a))
    x_b = tuple(float(c) for c in (*q_b, *t_b))
    x_ab = se3.compose_xyzw_xyz(x_a, x_b)
    assert len(x_ab) == 7 and all(type(c) is float for c in x_ab)
    T_a, T_b = _matrix_of(x_a), _matrix_of(x_b)
    np.testing.assert_allclose(_matrix_of(x_ab), T_a @ T_b, rtol=0, atol=1e-12)
    x_inv = se3.invert_xyzw_xyz(x_a)
    np.testing.assert_allclose(_matrix_of(x_inv), se3.invert(T_a), rtol=0, atol=1e-12)
    np.testing.assert_allclose(
        _matrix_of(se3.compose_xyzw_xyz(x_inv, x_a)), np.eye(4), rtol=0, atol=1e-12
    )


def test_compose_and_invert_xyzw_xyz_on_columns_are_the_same_arithmetic(rng):
    """(N,) columns give, pose by pose, exactly what plain floats give: one formula serves a
    single lookup and a vectorised one."""
    n = 64
    q_a, q_b = quat.from_matrix(so3.exp(rotation_vectors(rng, 2 * n))).reshape(2, n, 4)
    t_a, t_b = rng.uniform(-10.0, 10.0, (2, n, 3))
    cols_a = tuple(np.concatenate([q_a, t_a], axis=1).T)
    cols_b = tuple(np.concatenate([q_b, t_b], axis=1).T)
    composed = np.array(se3.compose_xyzw_xyz(cols_a, cols_b))
    inverted = np.array(se3.invert_xyzw_xyz(cols_a))
    for i in range(n):
        one_a = tuple(float(c[i]) for c in cols_a)
        one_b = tuple(float(c[i]) for c in cols_b)
        assert composed[:, i].tolist() == list(se3.compose_xyzw_xyz(one_a, one_b))
        assert inverted[:, i].tolist() == list(se3.invert_xyzw_xyz(one_a))


# ------------------------------------------------------------------------------- bad input
# Bad input raises ValueError with a message that names the problem (docs/CONVENTIONS.md, "Errors").


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: se3.make(R_OK, [1.0, 2.0]), r"t must have shape \(\.\.\., 3\); got shape \(2,\)"),
        (
            lambda: se3.check_transform(np.eye(3)),
            r"T must have shape \(\.\.\., 4, 4\); got shape \(3, 3\)",
        ),
        (
            lambda: se3.apply(T_OK, np.zeros((5, 2))),
            r"p must have shape \(\.\.\., 3\); got shape \(5, 2\)",
        ),
        (lambda: se3.apply(np.stack([T_OK, T_OK]), np.zeros(3)), r"T must have shape \(4, 4\)"),
        (lambda: se3.exp(np.zeros(5)), r"xi must have shape \(6,\); got shape \(5,\)"),
        (lambda: se3.exp(np.zeros((2, 6))), r"xi must have shape \(6,\); got shape \(2, 6\)"),
        (
            lambda: se3.log(np.stack([T_OK, T_OK])),
            r"T must be a single 4x4 transform, got shape \(2, 4, 4\)",
        ),
        (lambda: se3.log(np.eye(3)), r"T must have shape \(\.\.\., 4, 4\); got shape \(3, 3\)"),
        (lambda: se3.adjoint(np.eye(6)), r"T must have shape \(\.\.\., 4, 4\); got shape \(6, 6\)"),
    ],
)
def test_wrong_shapes(call, match):
    with pytest.raises(ValueError, match=match):
        call()


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nan_and_inf(bad):
    with pytest.raises(ValueError, match=r"t must be finite"):
        se3.make(R_OK, [0.0, bad, 0.0])
    T = T_OK.copy()
    T[0, 3] = bad
    with pytest.raises(ValueError, match=r"T must be finite"):
        se3.invert(T)
    with pytest.raises(ValueError, match=r"T must be finite"):
        se3.log(T)
    with pytest.raises(ValueError, match=r"T must be finite"):
        se3.adjoint(T)
    with pytest.raises(ValueError, match=r"xi must be finite; got \d NaN and \d inf"):
        se3.exp([0.0, 0.0, 0.0, bad, 0.0, 0.0])


def test_log_and_adjoint_refuse_a_matrix_that_is_not_rigid():
    sheared = T_OK.copy()
    sheared[0, 1] += 1e-3
    for fn in (se3.log, se3.adjoint):
        with pytest.raises(ValueError, match=r"rotation block T\[:3, :3\] is not a rotation"):
            fn(sheared)
    bottom = T_OK.copy()
    bottom[3, 0] = 1.0
    with pytest.raises(ValueError, match=r"T must have bottom row \[0, 0, 0, 1\]"):
        se3.adjoint(bottom)


def test_not_orthogonal_says_how_far_and_the_determinant():
    with pytest.raises(ValueError, match=r"rotation block T\[:3, :3\] is not a rotation"):
        se3.check_transform(np.diag([1.0, 1.0, 1.1, 1.0]))


def test_reflection_is_rejected():
    with pytest.raises(ValueError, match=r"R is a reflection"):
        se3.make(-np.eye(3), [0.0, 0.0, 0.0])


def test_bottom_row_not_0001():
    T = T_OK.copy()
    T[3] = [0.0, 0.0, 1.0, 1.0]
    with pytest.raises(
        ValueError, match=r"bottom row \[0, 0, 0, 1\].*got bottom row \[0\.?, 0\.?, 1\.?, 1\.?\]"
    ):
        se3.check_transform(T)
    with pytest.raises(ValueError, match=r"bottom row"):
        se3.invert(T)
    with pytest.raises(ValueError, match=r"T_w_b must have bottom row"):
        se3.check_transform(T, name="T_w_b")


def test_float32_transform_is_accepted_and_nan_tolerance_refused():
    from scipy.spatial.transform import Rotation

    T = np.eye(4, dtype=np.float32)
    T[:3, :3] = Rotation.random(random_state=5).as_matrix().astype(np.float32)
    T[:3, 3] = [1.0, 2.0, 3.0]
    assert se3.check_transform(T).dtype == np.float64
    with pytest.raises(ValueError, match="atol must be a finite number >= 0"):
        se3.check_transform(np.eye(4), atol=float("nan"))


def test_float32_transform_shear_names_the_float32_tolerance():
    T = np.eye(4, dtype=np.float32)
    T[0, 1] = 1e-4
    with pytest.raises(
        ValueError,
        match=r"rotation block T_w_b\[:3, :3\] is not .*tolerance 1\.9\d*e-06 for float32",
    ):
        se3.check_transform(T, name="T_w_b")
    for atol in (float("nan"), -1.0, float("inf")):
        with pytest.raises(ValueError, match=r"^atol must be a finite number >= 0"):
            se3.check_transform(T_OK, atol=atol)
    # The plain-float fast path and the full check agree on a float64 pose.
    assert se3.check_transform(T_OK) is T_OK
    np.testing.assert_array_equal(se3.check_pose(T_OK.astype(np.float32)), T_OK.astype(np.float32))


def test_apply_into_a_buffer_is_apply() -> None:
    """``out=``: the same numbers written into the caller's buffer, which is returned; a buffer
    of the wrong shape, dtype or layout, or one overlapping ``p``, is refused."""
    rng = np.random.default_rng(4)
    T = se3.make(so3.exp(rng.normal(size=3)), rng.normal(size=3))
    for shape in ((3,), (5, 3), (2, 7, 3), (20_000, 3)):
        p = rng.normal(size=shape)
        out = np.empty(shape)
        got = se3.apply(T, p, out=out)
        assert got is out
        np.testing.assert_array_equal(out, se3.apply(T, p))
    p = rng.normal(size=(4, 3))
    for bad in (np.empty((4, 3), np.float32), np.empty((3, 4)).T, np.empty((5, 3)), p):
        with pytest.raises(ValueError, match="out must"):
            se3.apply(T, p, out=bad)


def test_apply_kernel_matches_its_lecture_form() -> None:
    """cv2.transform (point sets) and the BLAS path (rotations OpenCV would treat as diagonal)
    against ``_apply_reference``, ``p R^T + t``: every shape, strided input, ``out=``, and a
    NaN or inf coordinate spreading to its whole row exactly as in the reference."""
    rng = np.random.default_rng(8)
    general = se3.make(so3.exp(rng.normal(size=3)), rng.normal(size=3))
    half_turn = se3.make(np.diag([1.0, -1.0, -1.0]), [1.0, 2.0, 3.0])
    for T in (general, half_turn, np.eye(4)):
        for shape in ((1, 3), (2, 3), (1000, 3), (4, 5, 3), (0, 3)):
            p = rng.uniform(-10.0, 10.0, shape)
            np.testing.assert_allclose(se3.apply(T, p), se3._apply_reference(T, p), atol=1e-13)
        p = rng.uniform(-10.0, 10.0, (20, 6))[:, ::2]  # not contiguous
        np.testing.assert_allclose(se3.apply(T, p), se3._apply_reference(T, p), atol=1e-13)
        p = rng.uniform(-10.0, 10.0, (10, 3))
        p[2, 1], p[3, 2], p[4] = np.nan, np.inf, np.nan
        with np.errstate(invalid="ignore"):
            ref = se3._apply_reference(T, p)
        got = se3.apply(T, p, out=np.empty_like(p))
        np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
        np.testing.assert_allclose(got, ref, atol=1e-13)
    assert not se3._opencv_treats_as_diagonal(general[:3, :3])
    assert se3._opencv_treats_as_diagonal(half_turn[:3, :3])
