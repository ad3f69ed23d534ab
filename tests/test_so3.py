"""vnav.so3: exp, log, rotation checks, roll-pitch-yaw; against OpenCV, SciPy and MuJoCo.

The group laws SO(3) shares with SE(3) and the unit quaternions are in test_group_laws.py.
"""

from __future__ import annotations

import cv2
import mujoco
import numpy as np
import pytest
from helpers import (
    N_REFERENCE,
    PROPERTY_SETTINGS,
    assert_same_rotvec,
    rotation_vectors,
    rotations,
    rotvecs,
)
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from vnav import quat, so3

N = N_REFERENCE
SETTINGS = PROPERTY_SETTINGS
R_OK = so3.rot_z(0.3)


# ------------------------------------------------------------------------------- unit tests


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


def test_vee_inverts_skew_and_gives_the_cross_product_vector():
    rng = np.random.default_rng(5)
    v = rng.normal(size=(20, 3))
    np.testing.assert_array_equal(so3.vee(so3.skew(v)), v)
    u = rng.normal(size=3)
    # skew(v) u = v x u (lecture chapter 5), checked against numpy's cross product.
    np.testing.assert_allclose(so3.skew(v[0]) @ u, np.cross(v[0], u), atol=1e-15)
    with pytest.raises(ValueError, match="shape"):
        so3.vee(np.zeros((3, 2)))


# ---------------------------------------------------------------------------- properties


@SETTINGS
@given(rotvecs())
def test_exp_log_round_trip(v):
    R = so3.exp(v)
    assert so3.is_rotation(R, atol=1e-14)
    w = so3.log(R)
    assert 0.0 <= np.linalg.norm(w) <= np.pi + 1e-15  # the angle, up to rounding of the norm
    assert_same_rotvec(w, v, atol=1e-12)
    np.testing.assert_allclose(so3.exp(w), R, atol=1e-15)


@SETTINGS
@given(rotations())
def test_log_exp_round_trip_from_matrix(R):
    np.testing.assert_allclose(so3.exp(so3.log(R)), R, atol=1e-12)


@SETTINGS
@given(
    st.floats(-np.pi + 1e-9, np.pi),
    st.floats(-np.pi / 2 + 1e-6, np.pi / 2 - 1e-6),
    st.floats(-np.pi + 1e-9, np.pi),
)
def test_rpy_round_trip_away_from_gimbal_lock(roll, pitch, yaw):
    R = so3.from_rpy(roll, pitch, yaw)
    np.testing.assert_allclose(R, so3.rot_z(yaw) @ so3.rot_y(pitch) @ so3.rot_x(roll), atol=1e-15)
    assert not so3.gimbal_locked(R)
    rpy = so3.to_rpy(R)
    # Angles come back where they are well conditioned; the matrix always does.
    np.testing.assert_allclose(so3.from_rpy(*rpy), R, atol=1e-15)
    if abs(pitch) < np.pi / 2 - 1e-3:
        np.testing.assert_allclose(rpy, [roll, pitch, yaw], atol=1e-12)


@SETTINGS
@given(
    st.floats(-np.pi, np.pi),
    st.sampled_from([-np.pi / 2, np.pi / 2]),
    st.floats(-np.pi, np.pi),
    st.floats(-1e-10, 1e-10),
)
def test_rpy_at_and_near_gimbal_lock_reproduces_R(roll, pitch, yaw, nudge):
    R = so3.from_rpy(roll, pitch + nudge, yaw)
    locked = so3.gimbal_locked(R)
    rpy = so3.to_rpy(R, warn=False)
    if locked:
        assert rpy[0] == 0.0
        assert abs(abs(rpy[1]) - np.pi / 2) < 1e-9
    np.testing.assert_allclose(so3.from_rpy(*rpy), R, atol=1e-9 if locked else 1e-15)


# ------------------------------------------------------------ independent implementations


def test_from_rpy_matches_mju_euler2quat_zyx(rng):
    # docs/CONVENTIONS.md: Rz(yaw) Ry(pitch) Rx(roll) is MuJoCo's intrinsic "zyx" sequence with
    # angles [yaw, pitch, roll].
    rpy = rng.uniform(-np.pi, np.pi, (N, 3))
    rpy[:, 1] /= 2.0
    R = so3.from_rpy(rpy[:, 0], rpy[:, 1], rpy[:, 2])
    for (roll, pitch, yaw), R_vnav in zip(rpy, R, strict=True):
        res = np.zeros(4)
        mujoco.mju_euler2Quat(res, np.array([yaw, pitch, roll]), "zyx")
        np.testing.assert_allclose(R_vnav, quat.to_matrix(quat.wxyz_to_xyzw(res)), atol=1e-15)


def test_exp_matches_cv2_rodrigues(rng):
    rotvec = rotation_vectors(rng, N)
    R = so3.exp(rotvec)
    for v, R_vnav in zip(rotvec, R, strict=True):
        R_cv, _ = cv2.Rodrigues(v.reshape(3, 1))
        np.testing.assert_allclose(R_vnav, R_cv, atol=1e-15)


def test_log_matches_cv2_rodrigues_away_from_pi(rng):
    # OpenCV's inverse Rodrigues is good to ~1e-11 (vnav's log is checked against the true
    # rotation vector to 1e-12 below), returns zero below ~1e-5 rad and is inaccurate near pi,
    # where both signs are valid at pi: there compare only the rotation.
    rotvec = rotation_vectors(rng, N)
    R = so3.exp(rotvec)
    for v_true, R_i, v_vnav in zip(rotvec, R, so3.log(R), strict=True):
        v_cv = cv2.Rodrigues(R_i)[0].ravel()
        if 1e-5 < np.linalg.norm(v_vnav) < np.pi - 1e-3:
            np.testing.assert_allclose(v_vnav, v_true, atol=1e-12)
            np.testing.assert_allclose(v_vnav, v_cv, atol=1e-9)
        np.testing.assert_allclose(so3.exp(v_vnav), R_i, atol=1e-15)


def test_exp_log_match_scipy_rotvec(rng):
    rotvec = rotation_vectors(rng, 2000)
    R = so3.exp(rotvec)
    np.testing.assert_allclose(R, Rotation.from_rotvec(rotvec).as_matrix(), atol=1e-15)
    v = so3.log(R)
    v_sp = Rotation.from_matrix(R).as_rotvec()
    angle = np.linalg.norm(v, axis=1)
    away = angle < np.pi - 1e-6  # at pi, u pi and -u pi are both right
    np.testing.assert_allclose(v[away], v_sp[away], atol=1e-12)
    np.testing.assert_allclose(angle, np.linalg.norm(v_sp, axis=1), atol=1e-12)


def test_rpy_matches_scipy_euler_ZYX(rng):
    rpy = np.column_stack(
        [
            rng.uniform(-np.pi, np.pi, 2000),
            rng.uniform(-np.pi / 2 + 1e-6, np.pi / 2 - 1e-6, 2000),
            rng.uniform(-np.pi, np.pi, 2000),
        ]
    )
    R = so3.from_rpy(rpy[:, 0], rpy[:, 1], rpy[:, 2])
    np.testing.assert_allclose(R, Rotation.from_euler("ZYX", rpy[:, ::-1]).as_matrix(), atol=1e-15)
    ypr = Rotation.from_matrix(R).as_euler("ZYX")
    np.testing.assert_allclose(so3.to_rpy(R), ypr[:, ::-1], atol=1e-9)


# ------------------------------------------------------------------------------- bad input
# Bad input raises ValueError with a message that names the problem (docs/CONVENTIONS.md, "Errors").


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (
            lambda: so3.check_rotation(np.eye(4)),
            r"R must have shape \(\.\.\., 3, 3\); got shape \(4, 4\)",
        ),
        (lambda: so3.check_rotation(np.ones(3)), r"got shape \(3,\)"),
        (lambda: so3.exp([1.0, 2.0]), r"rotvec must have shape \(\.\.\., 3\); got shape \(2,\)"),
        (lambda: so3.log(np.eye(3)[:2]), r"got shape \(2, 3\)"),
        (lambda: so3.skew(np.zeros((2, 4))), r"v must have shape"),
    ],
)
def test_wrong_shapes(call, match):
    with pytest.raises(ValueError, match=match):
        call()


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nan_and_inf(bad):
    R = R_OK.copy()
    R[1, 2] = bad
    with pytest.raises(ValueError, match=r"R must be finite; got \d NaN and \d inf"):
        so3.check_rotation(R)
    with pytest.raises(ValueError, match=r"rotvec must be finite"):
        so3.exp([0.1, bad, 0.0])
    with pytest.raises(ValueError, match=r"angle must be finite"):
        so3.rot_x(bad)
    with pytest.raises(ValueError, match=r"pitch must be finite"):
        so3.from_rpy(0.0, bad, 0.0)


def test_not_orthogonal_says_how_far_and_the_determinant():
    M = R_OK + 1e-6
    with pytest.raises(
        ValueError, match=r"not a rotation matrix: max \|R\^T R - I\| = [0-9.e-]+.*det = "
    ):
        so3.check_rotation(M)
    with pytest.raises(ValueError, match=r"R_w_b is not a rotation matrix"):
        so3.check_rotation(2.0 * np.eye(3), name="R_w_b")
    with pytest.raises(ValueError, match=r"det = 8"):
        so3.check_rotation(2.0 * np.eye(3))
    assert not so3.is_rotation(M)
    assert so3.is_rotation(M, atol=1e-3)


def test_reflection_is_rejected():
    with pytest.raises(ValueError, match=r"reflection, not a rotation: det = -1"):
        so3.check_rotation(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match=r"reflection"):
        so3.log(np.stack([np.eye(3), np.diag([-1.0, 1.0, 1.0])]))
    assert not so3.is_rotation(np.diag([1.0, -1.0, 1.0]))


def test_gimbal_lock_is_reported_and_can_be_silenced(recwarn):
    R = so3.from_rpy(0.2, np.pi / 2, -0.4)
    with pytest.warns(so3.GimbalLockWarning, match=r"gimbal lock"):
        so3.to_rpy(R)
    so3.to_rpy(R, warn=False)
    assert not [w for w in recwarn if issubclass(w.category, so3.GimbalLockWarning)]
    assert so3.gimbal_locked(R)
    assert not so3.gimbal_locked(so3.from_rpy(0.2, 1.0, -0.4))


# ---------------------------------------------------------------- tolerances and dtypes


@pytest.mark.parametrize("atol", [float("nan"), -1.0, float("inf")])
def test_rotation_tolerance_must_be_a_finite_non_negative_number(atol):
    shear = np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    with pytest.raises(ValueError, match="atol must be a finite number >= 0"):
        so3.check_rotation(shear, atol=atol)
    with pytest.raises(ValueError, match="atol must be a finite number >= 0"):
        so3.check_rotation(np.eye(3), atol=atol)


def test_float32_rotation_is_accepted_and_a_float32_shear_names_its_tolerance():

    R32 = Rotation.random(20, random_state=3).as_matrix().astype(np.float32)
    R = so3.check_rotation(R32)
    assert R.dtype == np.float64
    np.testing.assert_array_equal(R, R32.astype(np.float64))
    shear32 = np.array([[1.0, 1e-4, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], dtype=np.float32)
    with pytest.raises(ValueError, match=r"tolerance 1\.9\d*e-06 for float32 input"):
        so3.check_rotation(shear32)
    # float64 keeps its own tolerance: a 1e-7 shear is refused there.
    with pytest.raises(ValueError, match=r"tolerance 1e-09\)"):
        so3.check_rotation(np.array([[1.0, 1e-7, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]))


@pytest.mark.parametrize("atol", [float("nan"), -1e-9, float("inf"), "1e-9", None])
def test_every_rotation_tolerance_is_validated(atol):
    """A NaN tolerance would accept anything (or never detect gimbal lock): every function
    taking ``atol`` refuses it, naming ``atol``, rather than answering about ``R``."""
    shear = np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    locked = so3.from_rpy(0.0, np.pi / 2, 0.3)
    calls = [
        lambda: so3.check_rotation(shear, atol=atol),
        lambda: so3.is_rotation(shear, atol=atol),
        lambda: so3.is_rotation(np.eye(3), atol=atol),
        lambda: so3.gimbal_locked(locked, atol=atol),
        lambda: so3.to_rpy(locked, atol=atol, warn=False),
    ]
    for call in calls:
        with pytest.raises(ValueError, match=r"^atol must be a (finite )?number"):
            call()


def test_rotation_tolerance_accepts_numpy_scalars():
    shear = np.array([[1.0, 1e-4, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    for atol in (np.float64(1e-3), np.float32(1e-3), np.array(1e-3), 1):
        assert so3.is_rotation(shear, atol=atol)
    assert not so3.is_rotation(shear, atol=np.array(1e-9))
    assert so3.gimbal_locked(so3.from_rpy(0.0, np.pi / 2 - 1e-6, 0.3), atol=np.float32(1e-5))


def test_float32_shear_and_reflection_are_still_refused():
    """The float32 tolerance (16 eps = 1.9e-6) is wide enough for float32 rounding only."""
    # A float32 rotation that differs from orthogonal by 1e-5, five times the tolerance.
    R32 = Rotation.from_rotvec([0.1, 0.2, 0.3]).as_matrix() @ np.diag([1.0, 1.0, 1.0 + 1e-5])
    with pytest.raises(ValueError, match=r"R is not a rotation matrix.*tolerance 1\.9\d*e-06 for "):
        so3.check_rotation(R32.astype(np.float32))
    assert not so3.is_rotation(R32.astype(np.float32))
    with pytest.raises(ValueError, match=r"reflection"):
        so3.check_rotation(np.diag([1.0, 1.0, -1.0]).astype(np.float32))
    # An explicit atol wider than the float32 floor is used as given (and named without dtype).
    with pytest.raises(ValueError, match=r"tolerance 1e-06\)"):
        so3.check_rotation(
            np.array([[1.0, 1e-4, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), atol=1e-6
        )


def test_float32_rotations_go_through_every_rotation_function():
    """float32 rotations from SciPy: results are float64 and match SciPy (to float32 input)."""
    rot = Rotation.random(50, random_state=11)
    R32 = rot.as_matrix().astype(np.float32)
    R64 = R32.astype(np.float64)  # exactly the values received
    assert so3.log(R32).dtype == np.float64
    for ours, theirs in zip(so3.log(R32), rot.as_rotvec(), strict=True):
        assert_same_rotvec(ours, theirs, atol=1e-6)
    # The same values as float64 are judged at the float64 tolerance, and refused.
    assert not so3.is_rotation(R64)
    np.testing.assert_allclose(so3.from_rpy(*so3.to_rpy(R32, warn=False).T), R64, atol=1e-6)
    q = quat.from_matrix(R32)
    assert q.dtype == np.float64
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-15)


def test_fused_rotation_errors_match_the_lecture_form() -> None:
    """``_rotation_errors`` (one pass over the entries) against ``max |R^T R - I|`` by matmul
    and ``np.linalg.det``, on rotations, near-rotations, reflections and arbitrary matrices,
    in stacks of any leading shape."""
    from vnav.so3 import _orthogonality_error, _rotation_errors

    rng = np.random.default_rng(11)
    R = so3.exp(rng.normal(0.0, 1.0, (2, 5, 3)))
    samples = [
        R,
        R + rng.normal(0.0, 1e-6, R.shape),
        R * np.array([1.0, 1.0, -1.0]),
        rng.normal(0.0, 1.0, (7, 3, 3)),
        R[0, 0],
    ]
    for M in samples:
        err, det = _rotation_errors(M)
        assert err.shape == det.shape == M.shape[:-2]
        np.testing.assert_allclose(err, _orthogonality_error(M), rtol=0, atol=1e-14)
        np.testing.assert_allclose(det, np.linalg.det(M), rtol=1e-12, atol=1e-14)


def test_log_kernel_matches_its_lecture_form(rng) -> None:
    """``log``'s chunked kernel (through Markley's column of 4 q q^T) against the lecture's
    two-branch form ``_log_reference``, over more than one chunk, on uniform, tiny, near-pi
    and exactly-pi rotations; one matrix alone (plain floats) agrees with it in a stack."""
    n = so3._CHUNK + 33
    v = rotation_vectors(rng, n)
    R = so3.exp(v)
    w = so3.log(R)
    ref = so3._log_reference(R)
    at_pi = np.linalg.norm(ref, axis=1) > np.pi - 1e-9
    ref[at_pi] *= np.where(np.sum(w[at_pi] * ref[at_pi], axis=1) < 0.0, -1.0, 1.0)[:, None]
    np.testing.assert_allclose(w, ref, rtol=0, atol=2e-15)
    tiny = np.linalg.norm(v, axis=1) < 1e-3
    np.testing.assert_allclose(w[tiny], v[tiny], rtol=1e-12, atol=1e-300)
    for i in rng.integers(0, n, 200):
        np.testing.assert_allclose(so3.log(R[i]), w[i], rtol=0, atol=1e-15)


def test_stack_check_has_the_verdict_of_the_matrix_by_matrix_errors(rng) -> None:
    """The chunked check (``_stack_valid``) against ``_rotation_errors``: matrices whose error
    sits just below or just above the tolerance, in any chunk, get the same verdict."""
    n = so3._CHUNK + 5
    R = so3.exp(rotation_vectors(rng, n))
    for i in (3, so3._CHUNK + 2):
        for scale in (1.0 + 0.4e-9, 1.0 + 0.6e-9, 1.0 - 0.6e-9):
            M = R.copy()
            M[i] *= scale  # max |R^T R - I| ~ 2 |scale - 1|
            err, det = so3._rotation_errors(M)
            expected = bool(np.all(err <= 1e-9) and np.all(det > 0))
            assert so3._stack_valid(M, 1e-9) == expected
            assert so3.is_rotation(M) == expected
    bad = R.copy()
    bad[-1] = np.diag([1.0, 1.0, -1.0])
    with pytest.raises(ValueError, match=r"reflection.*worst matrix of the stack"):
        so3.check_rotation(bad)
    with pytest.raises(ValueError, match="reflection"):
        so3.log(bad)


def test_exp_kernel_matches_its_lecture_form(rng) -> None:
    """``exp``'s chunked kernel (Rodrigues' formula in half-angle form, with Taylor series near
    0) against the lecture's ``cos(t) I + sin(t) [u]x + (1 - cos(t)) u u^T``, over more than
    one chunk and for a stack of any leading shape."""
    v = rotation_vectors(rng, so3._CHUNK + 21)
    R = so3.exp(v)
    np.testing.assert_allclose(R, so3._exp_reference(v), rtol=0, atol=2e-15)
    v = rng.normal(size=(3, 4, 3))
    np.testing.assert_allclose(so3.exp(v), so3._exp_reference(v), rtol=0, atol=2e-15)
