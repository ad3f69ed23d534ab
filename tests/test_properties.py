"""Hypothesis properties of the geometry core, in float64.

Rotation samplers mix uniform angles with near-identity, near-pi and exactly-pi ones, so the
small-angle and antipodal branches of exp, log and from_matrix are exercised.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from vnav import frames, quat, se3, so3

SETTINGS = settings(max_examples=150, deadline=None)

unit_float = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)


@st.composite
def unit_axes(draw) -> np.ndarray:
    v = np.array([draw(unit_float), draw(unit_float), draw(unit_float)])
    n = np.linalg.norm(v)
    if n < 1e-3:
        v, n = np.array([0.0, 0.0, 1.0]), 1.0
    return v / n


angles = st.one_of(
    st.floats(0.0, np.pi),
    st.floats(-15.0, -3.0).map(lambda e: 10.0**e),  # near identity
    st.floats(-15.0, -3.0).map(lambda e: np.pi - 10.0**e),  # near pi
    st.just(np.pi),
    st.just(0.0),
)


@st.composite
def rotvecs(draw) -> np.ndarray:
    return draw(unit_axes()) * draw(angles)


@st.composite
def rotations(draw) -> np.ndarray:
    return so3.exp(draw(rotvecs()))


@st.composite
def unit_quaternions(draw) -> np.ndarray:
    q = quat.from_rotvec(draw(rotvecs()))
    return -q if draw(st.booleans()) else q  # both signs


translations = st.lists(st.floats(-100.0, 100.0), min_size=3, max_size=3).map(np.array)


@st.composite
def transforms(draw) -> np.ndarray:
    return se3.make(draw(rotations()), draw(translations))


def assert_same_rotvec(a: np.ndarray, b: np.ndarray, atol: float) -> None:
    """Equal rotation vectors; at an angle of pi, u pi and -u pi are the same rotation."""
    if np.linalg.norm(b) > np.pi - 1e-6 and np.dot(a, b) < 0:
        b = -b
    np.testing.assert_allclose(a, b, atol=atol)


# --------------------------------------------------------------------------------- group axioms


@SETTINGS
@given(rotations(), rotations(), rotations())
def test_so3_group_axioms(A, B, C):
    assert so3.is_rotation(A @ B)  # closure
    np.testing.assert_allclose((A @ B) @ C, A @ (B @ C), atol=1e-14)  # associativity
    np.testing.assert_allclose(A @ np.eye(3), A, atol=0)  # identity
    # inverse = transpose, to float64 rounding: exp's output is orthogonal to ~16 eps
    # (3.4e-15 worst over 2e5 random rotation vectors), so allow 1e-14 as the lines around.
    np.testing.assert_allclose(A.T @ A, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(so3.exp(-so3.log(A)), A.T, atol=1e-14)


@SETTINGS
@given(transforms(), transforms(), transforms())
def test_se3_group_axioms(T1, T2, T3):
    se3.check_transform(T1 @ T2)  # closure
    np.testing.assert_allclose((T1 @ T2) @ T3, T1 @ (T2 @ T3), atol=1e-11)
    # Translations reach 100 m: 1e-12 is a few ulps of them.
    np.testing.assert_allclose(se3.invert(T1) @ T1, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(T1 @ se3.invert(T1), np.eye(4), atol=1e-12)
    np.testing.assert_allclose(se3.invert(T1 @ T2), se3.invert(T2) @ se3.invert(T1), atol=1e-12)


@SETTINGS
@given(transforms(), st.lists(translations, min_size=1, max_size=20))
def test_apply_is_homogeneous_multiplication(T, points):
    p = np.array(points)
    p_h = np.column_stack([p, np.ones(len(p))])
    np.testing.assert_allclose(se3.apply(T, p), (T @ p_h.T).T[:, :3], atol=1e-12)
    np.testing.assert_allclose(se3.apply(se3.invert(T), se3.apply(T, p)), p, atol=1e-11)
    np.testing.assert_allclose(se3.apply(T, p[0]), se3.apply(T, p)[0], atol=1e-12)


# ------------------------------------------------------------------------------- round trips


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


# --------------------------------------------------------------------------- roll-pitch-yaw


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


# ------------------------------------------------------------------------------- frame tree


@SETTINGS
@given(st.lists(transforms(), min_size=4, max_size=4), st.data())
def test_frame_tree_lookup_equals_manual_composition(Ts, data):
    # world -> body -> camera, and world -> landmark; body -> imu, all random.
    T_w_b, T_b_c, T_w_l, T_b_i = Ts
    tree = frames.FrameTree()
    tree.add("world", "body", T_w_b)
    tree.add("body", "camera", T_b_c)
    tree.add("world", "landmark", T_w_l)
    tree.add("body", "imu", T_b_i)
    manual = {
        "world": np.eye(4),
        "body": T_w_b,
        "camera": T_w_b @ T_b_c,
        "landmark": T_w_l,
        "imu": T_w_b @ T_b_i,
    }  # T_w_x
    a = data.draw(st.sampled_from(sorted(manual)))
    b = data.draw(st.sampled_from(sorted(manual)))
    expected = se3.invert(manual[a]) @ manual[b]
    np.testing.assert_allclose(tree.lookup(a, b), expected, atol=1e-10)
    np.testing.assert_allclose(tree.lookup(a, b) @ tree.lookup(b, a), np.eye(4), atol=1e-10)
