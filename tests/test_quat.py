"""vnav.quat: unit quaternions [x, y, z, w] (scalar last); against MuJoCo and SciPy.

MuJoCo stores quaternions as [w, x, y, z]; every crossing goes through quat.xyzw_to_wxyz /
quat.wxyz_to_xyzw. SciPy is scalar last, like vnav. The group laws the unit quaternions share
with SO(3) and SE(3) are in test_group_laws.py.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from helpers import (
    N_REFERENCE,
    PROPERTY_SETTINGS,
    assert_same_rotvec,
    quaternions,
    rotation_vectors,
    rotations,
    rotvecs,
    same_rotation_quat,
    unit_quaternions,
    unit_vectors,
)
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation, Slerp

from vnav import quat, so3

N = N_REFERENCE
SETTINGS = PROPERTY_SETTINGS


# ------------------------------------------------------------------------------- unit tests


def test_batched_shapes():
    rng = np.random.default_rng(1)
    R = so3.exp(rng.normal(size=(4, 5, 3)))
    q = quat.from_matrix(R)
    assert q.shape == (4, 5, 4)
    assert quat.to_matrix(q).shape == (4, 5, 3, 3)
    assert quat.slerp(q[0, 0], q[1, 1], np.linspace(0, 1, 9)).shape == (9, 4)


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


# ---------------------------------------------------------------------------- properties


@SETTINGS
@given(rotations())
def test_matrix_quaternion_round_trip(R):
    q = quat.from_matrix(R)
    assert q[3] >= 0.0
    np.testing.assert_allclose(np.linalg.norm(q), 1.0, atol=1e-15)
    np.testing.assert_allclose(quat.to_matrix(q), R, atol=1e-15)


@SETTINGS
@given(unit_quaternions())
def test_quaternion_matrix_round_trip_and_double_cover(q):
    R = quat.to_matrix(q)
    np.testing.assert_allclose(quat.to_matrix(-q), R, atol=0)  # q and -q: one rotation
    back = quat.from_matrix(R)
    sign = 1.0 if np.dot(back, q) >= 0 else -1.0
    np.testing.assert_allclose(back, sign * q, atol=1e-15)


@SETTINGS
@given(rotvecs())
def test_quaternion_rotvec_and_axis_angle_round_trips(v):
    q = quat.from_rotvec(v)
    np.testing.assert_allclose(quat.to_matrix(q), so3.exp(v), atol=1e-15)
    assert_same_rotvec(quat.to_rotvec(q), v, atol=1e-12)
    assert_same_rotvec(quat.to_rotvec(-q), v, atol=1e-12)
    axis, angle = quat.to_axis_angle(-q)
    assert 0.0 <= angle <= np.pi
    np.testing.assert_allclose(
        quat.to_matrix(quat.from_axis_angle(axis, angle)), so3.exp(v), atol=1e-15
    )


@SETTINGS
@given(unit_quaternions(), unit_quaternions())
def test_multiply_is_matrix_product(a, b):
    np.testing.assert_allclose(
        quat.to_matrix(quat.multiply(a, b)), quat.to_matrix(a) @ quat.to_matrix(b), atol=1e-15
    )
    np.testing.assert_allclose(quat.multiply(a, quat.conjugate(a)), [0, 0, 0, 1], atol=1e-15)


@SETTINGS
@given(unit_quaternions(), unit_quaternions(), st.floats(0.0, 1.0))
def test_slerp_shortest_constant_speed(a, b, t):
    q = quat.slerp(a, b, t)
    np.testing.assert_allclose(np.linalg.norm(q), 1.0, atol=1e-15)
    R_a, R_b, R_t = quat.to_matrix(a), quat.to_matrix(b), quat.to_matrix(q)
    total = np.linalg.norm(so3.log(R_a.T @ R_b))
    # Rotation angle from a to q is t times the whole (shortest) angle, within rounding.
    np.testing.assert_allclose(np.linalg.norm(so3.log(R_a.T @ R_t)), t * total, atol=1e-7)
    np.testing.assert_allclose(quat.to_matrix(quat.slerp(a, b, 0.0)), R_a, atol=1e-15)
    np.testing.assert_allclose(quat.to_matrix(quat.slerp(a, b, 1.0)), R_b, atol=1e-14)


# ------------------------------------------------------------ independent implementations


def test_to_matrix_matches_mju_quat2mat(rng):
    q_xyzw = quaternions(rng, N)
    R = quat.to_matrix(q_xyzw)
    for q, R_vnav in zip(q_xyzw, R, strict=True):
        mat = np.zeros(9)
        mujoco.mju_quat2Mat(mat, quat.xyzw_to_wxyz(q))
        np.testing.assert_allclose(R_vnav, mat.reshape(3, 3), atol=1e-15)


def test_multiply_matches_mju_mulquat(rng):
    a, b = quaternions(rng, N), quaternions(rng, N)
    ab = quat.multiply(a, b)
    for qa, qb, q_vnav in zip(a, b, ab, strict=True):
        res = np.zeros(4)
        mujoco.mju_mulQuat(res, quat.xyzw_to_wxyz(qa), quat.xyzw_to_wxyz(qb))
        np.testing.assert_allclose(q_vnav, quat.wxyz_to_xyzw(res), atol=1e-15)


def test_from_matrix_matches_mju_mat2quat(rng):
    R = so3.exp(rotation_vectors(rng, N))
    q = quat.from_matrix(R)
    assert np.all(q[:, 3] >= 0.0)
    for R_i, q_vnav in zip(R, q, strict=True):
        res = np.zeros(4)
        mujoco.mju_mat2Quat(res, R_i.reshape(9))
        same_rotation_quat(q_vnav, quat.wxyz_to_xyzw(res), atol=1e-12)


def test_from_matrix_assume_valid_skips_only_the_check(rng):
    R = so3.exp(rotation_vectors(rng, N))
    q = quat.from_matrix(R, assume_valid=True)
    for R_i, q_vnav in zip(R, q, strict=True):
        res = np.zeros(4)
        mujoco.mju_mat2Quat(res, R_i.reshape(9))
        same_rotation_quat(q_vnav, quat.wxyz_to_xyzw(res), atol=1e-12)
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 3, 3\); got \(4, 4\)"):
        quat.from_matrix(np.eye(4), assume_valid=True)
    with pytest.raises(ValueError):  # without it, a matrix that is not a rotation is refused
        quat.from_matrix(2.0 * np.eye(3))


def test_from_axis_angle_matches_mju_axisangle2quat(rng):
    axes = unit_vectors(rng, N) * rng.uniform(0.1, 5.0, (N, 1))  # not unit: vnav normalises
    angles = rng.uniform(-2 * np.pi, 2 * np.pi, N)
    q = quat.from_axis_angle(axes, angles)
    for axis, angle, q_vnav in zip(axes, angles, q, strict=True):
        res = np.zeros(4)
        mujoco.mju_axisAngle2Quat(res, axis / np.linalg.norm(axis), angle)
        np.testing.assert_allclose(q_vnav, quat.wxyz_to_xyzw(res), atol=1e-15)


def test_quaternion_conversions_match_scipy(rng):
    q = quaternions(rng, 2000)
    np.testing.assert_allclose(quat.to_matrix(q), Rotation.from_quat(q).as_matrix(), atol=1e-15)
    R = Rotation.from_quat(q).as_matrix()
    same_rotation_quat(quat.from_matrix(R), Rotation.from_matrix(R).as_quat(), atol=1e-15)
    np.testing.assert_allclose(
        so3.exp(quat.to_rotvec(q)), Rotation.from_quat(q).as_matrix(), atol=1e-14
    )
    rotvec = rotation_vectors(rng, 2000)
    same_rotation_quat(quat.from_rotvec(rotvec), Rotation.from_rotvec(rotvec).as_quat(), 1e-15)


def test_slerp_matches_scipy(rng):
    q0, q1 = quaternions(rng, 200), quaternions(rng, 200)
    times = np.linspace(0.0, 1.0, 7)
    for a, b in zip(q0, q1, strict=True):
        ours = quat.slerp(a, b, times)
        # SciPy's Slerp also takes the shorter path between rotations.
        theirs = Slerp([0.0, 1.0], Rotation.from_quat([a, b]))(times).as_quat()
        same_rotation_quat(ours, theirs, atol=1e-12)


# ------------------------------------------------------------------------------- bad input
# Bad input raises ValueError with a message that names the problem (docs/CONVENTIONS.md, "Errors").


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (
            lambda: quat.to_matrix([0.0, 0.0, 1.0]),
            r"q must have shape \(\.\.\., 4\); got shape \(3,\)",
        ),
    ],
)
def test_wrong_shapes(call, match):
    with pytest.raises(ValueError, match=match):
        call()


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nan_and_inf(bad):
    with pytest.raises(ValueError, match=r"q must be finite"):
        quat.to_matrix([0.0, 0.0, bad, 1.0])


def test_not_orthogonal_says_how_far_and_the_determinant():
    with pytest.raises(ValueError, match=r"not a rotation matrix"):
        quat.from_matrix(np.ones((3, 3)))


def test_zero_axis():
    with pytest.raises(ValueError, match=r"axis must be non-zero"):
        quat.from_axis_angle([0.0, 0.0, 0.0], 1.0)


@pytest.mark.parametrize(
    "call",
    [
        lambda q: quat.to_matrix(q),
        lambda q: quat.multiply(q, q),
        lambda q: quat.to_rotvec(q),
        lambda q: quat.to_axis_angle(q),
        lambda q: quat.slerp(q, q, 0.5),
        lambda q: quat.check_quaternion(q),
    ],
)
def test_non_unit_quaternion_needs_explicit_opt_in(call):
    with pytest.raises(ValueError, match=r"unit quaternion .*got norm 2(\.0+)?\b.*normalize=True"):
        call(np.array([0.0, 0.0, 0.0, 2.0]))
    with pytest.raises(ValueError, match=r"zero quaternion \(norm 0\)"):
        call(np.zeros(4))


def test_non_unit_quaternion_with_opt_in():
    q = np.array([0.0, 0.0, 1.0, 1.0])  # norm sqrt(2)
    np.testing.assert_allclose(quat.to_matrix(q, normalize=True), so3.rot_z(np.pi / 2), atol=1e-15)
    np.testing.assert_allclose(quat.to_rotvec(q, normalize=True), [0, 0, np.pi / 2], atol=1e-15)
    np.testing.assert_allclose(quat.normalize(q), q / np.sqrt(2.0))
    with pytest.raises(ValueError, match=r"zero quaternion"):
        quat.to_matrix(np.zeros(4), normalize=True)
    with pytest.raises(ValueError, match=r"zero quaternion"):
        quat.normalize(np.zeros(4))
    # Within the tolerance (1e-6) a quaternion is accepted and still gives an exact rotation.
    R = quat.to_matrix(np.array([0.0, 0.0, 0.0, 1.0 + 5e-7]))
    np.testing.assert_allclose(R, np.eye(3), atol=1e-15)


# ---------------------------------------------------------------- garbage in: an error, not garbage


def test_from_rotvec_too_long_raises_like_so3_exp():
    for fn in (quat.from_rotvec, so3.exp):
        with pytest.raises(ValueError, match="rotvec is too long"):
            fn([1e155, 0.0, 0.0])


def test_from_axis_angle_huge_and_tiny_axes_give_unit_quaternions():

    for axis in ([1e200, 1e200, 0.0], [1e-200, 0.0, 1e-200], [3e307, -3e307, 1e307]):
        q = quat.from_axis_angle(axis, 1.0)
        assert abs(np.linalg.norm(q) - 1.0) < 1e-15
        direction = np.array(axis) / np.max(np.abs(axis))
        expected = Rotation.from_rotvec(direction / np.linalg.norm(direction)).as_quat()
        np.testing.assert_allclose(q, expected, atol=1e-15)


def test_multiply_stays_unit_over_repeated_products_scipy_stability_test():
    """SciPy's stability test: ``rs = rs * q * rs`` repeated 50 times. The product is
    renormalised, so its norm stays 1 (unrenormalised it drifts past 6e-8 by step 27 and the
    next product is refused), and each step agrees with SciPy's composition of the same inputs
    (the map squares ``rs``, so trajectories of two implementations part; steps do not)."""
    q = Rotation.random(1000, random_state=1).as_quat()
    rs = Rotation.random(1000, random_state=2).as_quat()
    for _ in range(50):
        expected = (
            Rotation.from_quat(rs) * Rotation.from_quat(q) * Rotation.from_quat(rs)
        ).as_quat()
        rs = quat.multiply(quat.multiply(rs, q), rs)
        assert np.max(np.abs(np.linalg.norm(rs, axis=1) - 1.0)) < 1e-12
        same_sign = np.where(np.sum(rs * expected, axis=1, keepdims=True) < 0.0, -1.0, 1.0)
        np.testing.assert_allclose(rs, same_sign * expected, atol=1e-12)


@pytest.mark.parametrize("atol", [float("nan"), -1e-9, float("inf")])
def test_quaternion_tolerance_must_be_a_finite_non_negative_number(atol):
    with pytest.raises(ValueError, match="atol must be a finite number >= 0"):
        quat.check_quaternion([0.0, 0.0, 0.0, 2.0], atol=atol)


def test_from_rotvec_at_the_limit_agrees_with_so3_exp():
    """Just below the overflow limit both still answer, and with the same rotation."""
    v = np.array([1e150, -2e150, 3e149])
    np.testing.assert_allclose(quat.to_matrix(quat.from_rotvec(v)), so3.exp(v), atol=1e-12)
    for bad in ([1e155, 0.0, 0.0], [[0.1, 0.0, 0.0], [0.0, -2e154, 1.5e154]]):
        with pytest.raises(ValueError, match=r"^rotvec is too long"):
            quat.from_rotvec(bad)
    for bad in (np.nan, np.inf):
        with pytest.raises(ValueError, match=r"^rotvec must be finite"):
            quat.from_rotvec([bad, 0.0, 0.0])


@pytest.mark.parametrize("axis", [[np.nan, 0.0, 1.0], [np.inf, 0.0, 0.0], [1e-320, 0.0, 0.0]])
def test_from_axis_angle_non_finite_axes_raise_and_subnormal_axes_work(axis):
    if np.isfinite(axis).all():
        np.testing.assert_allclose(
            quat.from_axis_angle(axis, 0.5), Rotation.from_rotvec([0.5, 0.0, 0.0]).as_quat()
        )
    else:
        with pytest.raises(ValueError, match=r"^axis must be finite"):
            quat.from_axis_angle(axis, 0.5)


def test_float32_quaternions_use_a_dtype_aware_norm_tolerance():
    """A float32 unit quaternion from SciPy passes every check (results float64, equal to
    SciPy's); a float32 quaternion off by more than 16 float32 eps is refused, and the message
    names the widened tolerance and the dtype."""
    rot = Rotation.random(200, random_state=7)
    q32 = rot.as_quat().astype(np.float32)
    q64 = q32.astype(np.float64)
    assert quat.check_quaternion(q32, atol=1e-12).dtype == np.float64  # widened to 1.9e-6
    R = quat.to_matrix(q32)
    assert R.dtype == np.float64
    np.testing.assert_allclose(R, Rotation.from_quat(q64).as_matrix(), atol=1e-15)
    same_rotation_quat(quat.multiply(q32, q32), (rot * rot).as_quat(), atol=1e-6)
    # |q| - 1 = 1.43e-6: above the float64 default (1e-6), inside the float32 one (1.9e-6).
    q = np.array([0.0, 0.0, 0.0, 1.0 + 1.5e-6], dtype=np.float32)
    np.testing.assert_allclose(quat.to_matrix(q), np.eye(3), atol=1e-15)
    assert quat.check_quaternion(q).dtype == np.float64
    with pytest.raises(ValueError, match=r"got norm 1\.0000015"):
        quat.to_matrix(q.astype(np.float64))
    off = np.array([0.0, 0.0, 0.0, 1.0 + 1e-5], dtype=np.float32)
    for call in (quat.check_quaternion, quat.to_matrix, quat.to_rotvec):
        with pytest.raises(
            ValueError,
            match=r"\|norm - 1\| > 1\.9\d*e-06 \(the tolerance for "
            r"float32 input\)",
        ):
            call(off)


@pytest.mark.parametrize("atol", [float("nan"), -1.0, float("inf"), "x"])
def test_quaternion_tolerance_is_checked_before_anything_else(atol):
    for q in ([0.0, 0.0, 0.0, 1.0], np.zeros((0, 4))):
        with pytest.raises(ValueError, match=r"^atol must be a (finite )?number"):
            quat.check_quaternion(q, atol=atol)


def test_from_matrix_matches_its_lecture_form(rng):
    """The vectorised kernel against Shepperd's four branches matrix by matrix, on random
    rotations and on rotations by pi (where w = 0 and another component dominates)."""
    R = so3.exp(rng.normal(size=(200, 3)))
    axes = rng.normal(size=(20, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    R = np.concatenate([R, so3.exp(np.pi * axes)])
    q = quat.from_matrix(R)
    for Ri, qi in zip(R, q, strict=True):
        ref = quat._from_matrix_reference(Ri)
        if abs(ref[3]) < 1e-12:  # at w = 0, q and -q are both canonical
            ref = ref if ref @ qi >= 0 else -ref
        np.testing.assert_allclose(qi, ref, atol=1e-15)


def test_from_matrix_kernel_matches_its_lecture_form_across_chunks(rng):
    """The chunked kernel over more than one chunk (the full chunks read through
    cv2.transpose with ``assume_valid``, the tail through numpy): against Shepperd's form on
    a sample of rows, the same numbers validated or not, and one matrix alone (plain floats)
    bit for bit the same as in a stack."""
    n = so3._CHUNK + 77
    R = so3.exp(rotation_vectors(rng, n))
    q = quat.from_matrix(R)
    np.testing.assert_array_equal(quat.from_matrix(R, assume_valid=True), q)
    for i in [*rng.integers(0, n, 300), n - 1]:
        ref = quat._from_matrix_reference(R[i])
        ref = ref if ref @ q[i] >= 0 else -ref  # at w = 0 both signs are canonical
        np.testing.assert_allclose(q[i], ref, atol=1e-15)
        np.testing.assert_array_equal(quat.from_matrix(R[i]), q[i])
    # A stack of slices of 4x4 transforms (strided entries) reads the same numbers.
    T = np.zeros((n, 4, 4))
    T[:, :3, :3] = R
    np.testing.assert_array_equal(quat.from_matrix(T[:, :3, :3], assume_valid=True), q)


def test_from_matrix_checks_every_chunk(rng):
    """The check fused into the kernel finds a bad matrix in any chunk, with check_rotation's
    message; a float32 stack is allowed its widened tolerance."""
    n = so3._CHUNK + 10
    R = so3.exp(rotation_vectors(rng, n))
    for i in (0, so3._CHUNK - 1, n - 1):
        bad = R.copy()
        bad[i] *= 1.001
        with pytest.raises(ValueError, match=r"R is not a rotation matrix: max \|R\^T R - I\|"):
            quat.from_matrix(bad)
        bad[i] = R[i] * [1.0, 1.0, -1.0]
        with pytest.raises(ValueError, match="reflection"):
            quat.from_matrix(bad)
        bad[i] = np.nan
        with pytest.raises(ValueError, match="must be finite"):
            quat.from_matrix(bad)
    q32 = quat.from_matrix(R.astype(np.float32))
    np.testing.assert_allclose(np.linalg.norm(q32, axis=1), 1.0, atol=1e-15)


def test_multiply_kernel_is_its_lecture_form_bit_for_bit(rng):
    """Above ``_SMALL_STACK`` products the chunked kernel runs: the same operations in the same
    order as ``_multiply_reference``, so the same bits, for equal shapes, a single quaternion
    against a stack, and stacks that broadcast."""
    for n in (quat._SMALL_STACK + 1, quat._CHUNK + 3):
        a = quat.normalize(rng.normal(size=(n, 4)))
        b = quat.normalize(rng.normal(size=(n, 4)))
        np.testing.assert_array_equal(quat.multiply(a, b), quat._multiply_reference(a, b))
        np.testing.assert_array_equal(quat.multiply(a[0], b), quat._multiply_reference(a[0], b))
    a = quat.normalize(rng.normal(size=(3, 1, 4)))
    b = quat.normalize(rng.normal(size=(50, 4)))
    np.testing.assert_array_equal(quat.multiply(a, b), quat._multiply_reference(a, b))
    with pytest.raises(ValueError, match="must broadcast"):
        quat.multiply(a[:, 0], b)


def test_multiply_kernel_checks_both_factors(rng):
    """The norm check fused into the kernel raises check_quaternion's messages, naming the
    factor, wherever the bad quaternion sits; float32 factors keep their widened tolerance."""
    n = quat._CHUNK + 5
    a = quat.normalize(rng.normal(size=(n, 4)))
    b = quat.normalize(rng.normal(size=(n, 4)))
    for i in (0, n - 1):
        off = b.copy()
        off[i] *= 1.01
        with pytest.raises(ValueError, match=r"^b must be a unit quaternion"):
            quat.multiply(a, off)
        off[i] = np.inf
        with pytest.raises(ValueError, match=r"^b must be finite"):
            quat.multiply(a, off)
        with pytest.raises(ValueError, match=r"^a is the zero quaternion"):
            quat.multiply(np.zeros((n, 4)), b)
    # 1.5e-6 off unit length: beyond float64's tolerance (1e-6), within float32's (1.9e-6).
    a[n - 1] *= 1.0 + 1.5e-6
    with pytest.raises(ValueError, match=r"^a must be a unit quaternion"):
        quat.multiply(a, b)
    a32 = a.astype(np.float32)
    np.testing.assert_allclose(quat.multiply(a32, b), quat._multiply_reference(a32, b), atol=1e-6)


def test_to_matrix_kernel_matches_its_lecture_form(rng):
    """``to_matrix``'s chunked kernel (``I + (2/|q|^2)(...)``, sharing its rows with
    ``so3.exp``) against the lecture's ``R11 = q1^2 - q2^2 - q3^2 + q4^2``, ..., over more than
    one chunk, both signs of q, and a stack of any leading shape."""
    q = quaternions(rng, quat._CHUNK + 13)
    q[::2] *= -1.0
    np.testing.assert_allclose(quat.to_matrix(q), quat._to_matrix_reference(q), atol=2e-15)
    q = quat.normalize(rng.normal(size=(2, 3, 4)))
    np.testing.assert_allclose(quat.to_matrix(q), quat._to_matrix_reference(q), atol=2e-15)


def test_chunked_kernels_keep_their_scratch_per_thread(rng):
    """numpy releases the GIL inside the kernels' loops: threads running them at once (each
    with its own scratch arrays) get the answers they get alone."""
    from concurrent.futures import ThreadPoolExecutor

    stacks = [so3.exp(rotation_vectors(rng, quat._CHUNK + 9)) for _ in range(4)]
    alone = [(quat.from_matrix(R), so3.log(R), quat.to_matrix(quat.from_matrix(R))) for R in stacks]

    def work(R):
        return quat.from_matrix(R), so3.log(R), quat.to_matrix(quat.from_matrix(R))

    with ThreadPoolExecutor(max_workers=4) as pool:
        together = list(pool.map(work, stacks * 3))
    for got, want in zip(together, alone * 3, strict=True):
        for a, b in zip(got, want, strict=True):
            np.testing.assert_array_equal(a, b)
