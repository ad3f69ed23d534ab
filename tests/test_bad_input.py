"""Bad input raises ValueError with a message that names the problem (issue 2, "Bad input")."""

from __future__ import annotations

import numpy as np
import pytest

from vnav import frames, quat, se3, so3

R_OK = so3.rot_z(0.3)
T_OK = se3.make(R_OK, [1.0, 2.0, 3.0])


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
        (
            lambda: quat.to_matrix([0.0, 0.0, 1.0]),
            r"q must have shape \(\.\.\., 4\); got shape \(3,\)",
        ),
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
    with pytest.raises(ValueError, match=r"q must be finite"):
        quat.to_matrix([0.0, 0.0, bad, 1.0])
    with pytest.raises(ValueError, match=r"t must be finite"):
        se3.make(R_OK, [0.0, bad, 0.0])
    with pytest.raises(ValueError, match=r"angle must be finite"):
        so3.rot_x(bad)
    with pytest.raises(ValueError, match=r"pitch must be finite"):
        so3.from_rpy(0.0, bad, 0.0)
    T = T_OK.copy()
    T[0, 3] = bad
    with pytest.raises(ValueError, match=r"T must be finite"):
        se3.invert(T)


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
    with pytest.raises(ValueError, match=r"rotation block T\[:3, :3\] is not a rotation"):
        se3.check_transform(np.diag([1.0, 1.0, 1.1, 1.0]))
    with pytest.raises(ValueError, match=r"not a rotation matrix"):
        quat.from_matrix(np.ones((3, 3)))
    assert not so3.is_rotation(M)
    assert so3.is_rotation(M, atol=1e-3)


def test_reflection_is_rejected():
    with pytest.raises(ValueError, match=r"reflection, not a rotation: det = -1"):
        so3.check_rotation(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match=r"R is a reflection"):
        se3.make(-np.eye(3), [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"reflection"):
        so3.log(np.stack([np.eye(3), np.diag([-1.0, 1.0, 1.0])]))
    assert not so3.is_rotation(np.diag([1.0, -1.0, 1.0]))


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
    tree = frames.FrameTree()
    with pytest.raises(ValueError, match=r"T_world_body must have bottom row"):
        tree.add("world", "body", T)


def test_frame_tree_errors():
    tree = frames.FrameTree()
    tree.add("world", "body", T_OK)
    tree.add("body", "camera", T_OK)
    tree.add("map", "odom", T_OK)
    with pytest.raises(ValueError, match=r"unknown frame 'lidar'; known frames: 'world', 'body'"):
        tree.lookup("world", "lidar")
    with pytest.raises(ValueError, match=r"frames 'camera' and 'odom' are not connected"):
        tree.lookup("camera", "odom")
    with pytest.raises(ValueError, match=r"frame 'camera' already has parent 'body'"):
        tree.add("world", "camera", T_OK)
    with pytest.raises(ValueError, match=r"would close a cycle: 'world' is already an ancestor"):
        tree.add("camera", "world", T_OK)
    with pytest.raises(ValueError, match=r"cannot be its own parent"):
        tree.add("body", "body", T_OK)
    with pytest.raises(ValueError, match=r"no edge 'world' -> 'camera' to set"):
        tree.set("world", "camera", T_OK)
    with pytest.raises(ValueError, match=r"non-empty str"):
        tree.add("", "x", T_OK)


def test_gimbal_lock_is_reported_and_can_be_silenced(recwarn):
    R = so3.from_rpy(0.2, np.pi / 2, -0.4)
    with pytest.warns(so3.GimbalLockWarning, match=r"gimbal lock"):
        so3.to_rpy(R)
    so3.to_rpy(R, warn=False)
    assert not [w for w in recwarn if issubclass(w.category, so3.GimbalLockWarning)]
    assert so3.gimbal_locked(R)
    assert not so3.gimbal_locked(so3.from_rpy(0.2, 1.0, -0.4))
