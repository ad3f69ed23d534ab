"""Every worked example and quiz answer of MIT 16.485 VNAV lecture 1.

The expected values are the lecture's own printed numbers, typed in here (not read from
``scenarios.commands.lecture``), compared at the precision the lecture prints them.
"""

from __future__ import annotations

import numpy as np
import pytest

from vnav import frames, quat, se3, so3

# The lecture prints Rz(90 deg) in chapters 2, 5 and 6.
RZ90_LECTURE = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]], dtype=float)


def printed(decimals: int) -> float:
    """Tolerance for a number printed rounded to ``decimals`` decimals."""
    return 0.5 * 10.0**-decimals + 1e-12


def test_chapter0_landmark_after_90deg_clockwise_yaw():
    # Camera reports [0, 0, 3] (optical: 3 m straight ahead). Camera at the body origin looking
    # forward; the drone has yawed 90 deg clockwise (seen from above: -90 deg about up).
    p_c = np.array([0.0, 0.0, 3.0])
    T_b_c = se3.make(frames.R_FLU_RDF, [0.0, 0.0, 0.0])
    T_w_b = se3.make(so3.rot_z(np.radians(-90)), [0.0, 0.0, 0.0])
    p_w = se3.apply(T_w_b @ T_b_c, p_c)
    np.testing.assert_allclose(p_w, [0.0, -3.0, 0.0], atol=1e-12)


def test_chapter1_quiz_displacement_t12():
    T_w_1 = se3.make(np.eye(3), [1.0, 0.0, 0.0])
    T_w_2 = se3.make(np.eye(3), [4.0, 3.0, 0.0])
    t_12 = (se3.invert(T_w_1) @ T_w_2)[:3, 3]
    np.testing.assert_allclose(t_12, [3.0, 3.0, 0.0], atol=1e-12)


def test_chapter1_code_example_t12_and_inverse():
    T_w_1 = se3.make(np.eye(3), [1.0, 2.0, 0.5])
    T_w_2 = se3.make(np.eye(3), [3.0, 2.0, 0.5])
    T_1_2 = se3.invert(T_w_1) @ T_w_2
    np.testing.assert_allclose(T_1_2[:3, 3], [2.0, 0.0, 0.0], atol=1e-12)  # printed [2. 0. 0.]
    np.testing.assert_allclose(se3.invert(T_1_2)[:3, 3], [-2.0, 0.0, 0.0], atol=1e-12)


def test_chapter2_rz90_and_its_properties():
    R = so3.rot_z(np.pi / 2)
    np.testing.assert_allclose(R, RZ90_LECTURE, atol=printed(4))
    # Columns are the body axes in the world: x_r = [0, 1, 0], y_r = [-1, 0, 0], z_r = [0, 0, 1].
    np.testing.assert_allclose(R[:, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(R[:, 1], [-1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=printed(4))
    assert round(float(np.linalg.det(R)), 4) == 1.0
    assert so3.is_rotation(R)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15)  # inverse is the transpose


def test_chapter3_rotate_point_forward_to_world_y():
    p_w = so3.rot_z(np.pi / 2) @ np.array([1.0, 0.0, 0.0])
    np.testing.assert_allclose(p_w, [0.0, 1.0, 0.0], atol=1e-15)


def test_chapter3_quiz_point_left_of_body():
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(so3.rot_z(np.pi / 2), R, atol=1e-15)
    p_w = so3.rot_z(np.pi / 2) @ np.array([0.0, 2.0, 0.0])
    np.testing.assert_allclose(p_w, [-2.0, 0.0, 0.0], atol=1e-15)


def test_chapter3_code_composition_and_inverse():
    R_w_r = so3.rot_z(np.radians(45))
    R_r_c = so3.rot_x(np.radians(-30))
    R_w_c = R_w_r @ R_r_c
    # Not printed in the lecture; by hand, Rz(45) Rx(-30) with c45 = s45 = 0.7071,
    # c30 = 0.8660, s30 = 0.5: row 1 [c45, -s45 c30, -s45 s30], row 2 [s45, c45 c30, c45 s30],
    # row 3 [0, -s30, c30].
    by_hand = [[0.707, -0.612, -0.354], [0.707, 0.612, 0.354], [0.0, -0.5, 0.866]]
    np.testing.assert_allclose(R_w_c, by_hand, atol=printed(3))
    assert so3.is_rotation(R_w_c)
    assert not np.allclose(R_w_r @ R_r_c, R_r_c @ R_w_r)  # not commutative
    # Landmark 1 m ahead with a 45 deg yaw: printed [0.707, 0.707, 0.0].
    np.testing.assert_allclose(R_w_r @ [1.0, 0.0, 0.0], [0.707, 0.707, 0.0], atol=printed(3))
    # Identity check, printed to 4 decimals.
    np.testing.assert_allclose(R_w_r @ R_w_r.T, np.eye(3), atol=printed(4))


def test_chapter4_gimbal_lock_identity():
    for alpha in (-1.0, 0.0, 0.4, 2.5):
        for delta in (-0.7, 0.3, 1.9):
            left = so3.rot_z(delta) @ so3.rot_y(np.pi / 2) @ so3.rot_x(alpha + delta)
            right = so3.rot_z(0.0) @ so3.rot_y(np.pi / 2) @ so3.rot_x(alpha)
            np.testing.assert_allclose(left, right, atol=1e-15)
            np.testing.assert_allclose(
                so3.from_rpy(alpha + delta, np.pi / 2, delta), right, atol=1e-15
            )
            with pytest.warns(so3.GimbalLockWarning):
                rpy = so3.to_rpy(left)
            assert rpy[0] == 0.0  # roll set to 0 at the lock
            np.testing.assert_allclose(so3.from_rpy(*rpy), left, atol=1e-15)


def test_chapter5_rodrigues_90deg_about_z():
    R = so3.exp(np.pi / 2 * np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(R, RZ90_LECTURE, atol=1e-15)
    # The lecture's worked terms: [u]x and u u^T.
    np.testing.assert_array_equal(so3.skew([0.0, 0.0, 1.0]), [[0, -1, 0], [1, 0, 0], [0, 0, 0]])


def test_chapter5_rodrigues_30deg_about_diagonal_axis_and_angle_recovery():
    axis = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)
    R = so3.exp(np.radians(30) * axis)
    lecture = [[0.933, 0.067, 0.354], [0.067, 0.933, -0.354], [-0.354, 0.354, 0.866]]
    np.testing.assert_allclose(R, lecture, atol=printed(3))
    rotvec = so3.log(R)
    assert f"{np.degrees(np.linalg.norm(rotvec)):.1f}" == "30.0"  # printed "30.0°"
    np.testing.assert_allclose(rotvec / np.linalg.norm(rotvec), axis, atol=1e-15)
    # The lecture's own recovery: trace(R) = 1 + 2 cos(theta).
    assert round(float(np.degrees(np.arccos((np.trace(R) - 1) / 2))), 1) == 30.0


def test_chapter6_quaternion_90deg_about_z_and_double_cover():
    q = quat.from_axis_angle([0.0, 0.0, 1.0], np.pi / 2)
    np.testing.assert_allclose(q, [0.0, 0.0, 0.707, 0.707], atol=printed(3))
    R = quat.to_matrix(q)
    np.testing.assert_allclose(R, RZ90_LECTURE, atol=printed(3))
    # The lecture's hand-checked entries: R11 = 0, R21 = 1, R33 = 1.
    assert abs(R[0, 0]) < 1e-15 and abs(R[1, 0] - 1) < 1e-15 and abs(R[2, 2] - 1) < 1e-15
    np.testing.assert_allclose(quat.to_matrix(-q), R, atol=1e-15)  # R(q) = R(-q)
    # Inverse = conjugate [-v; s].
    np.testing.assert_allclose(quat.conjugate(q), [0.0, 0.0, -0.707, 0.707], atol=printed(3))
    np.testing.assert_allclose(quat.multiply(q, quat.conjugate(q)), [0, 0, 0, 1], atol=1e-15)


def test_chapter7_camera_in_world_and_inverse():
    T_w_r = se3.make(so3.rot_z(np.pi / 2), [5.0, 0.0, 0.0])
    T_r_c = se3.make(np.eye(3), [0.3, 0.0, 0.2])
    T_w_c = T_w_r @ T_r_c
    np.testing.assert_allclose(T_w_c[:3, 3], [5.0, 0.3, 0.2], atol=printed(3))
    T_r_w = se3.invert(T_w_r)
    np.testing.assert_allclose(T_w_r @ T_r_w, np.eye(4), atol=printed(3))
    # Closed form by hand: R^T = Rz(-90), -R^T t = -Rz(-90) [5, 0, 0] = [0, 5, 0].
    np.testing.assert_allclose(T_r_w[:3, 3], [0.0, 5.0, 0.0], atol=1e-14)
    # Landmark 3 m ahead of the camera (the lecture's code; value worked by hand).
    np.testing.assert_allclose(se3.apply(T_w_c, [0.0, 0.0, 3.0]), [5.0, 0.3, 3.2], atol=1e-14)


def test_chapter8_transform_composer():
    tree = frames.FrameTree()
    tree.add("world", "body", se3.make(so3.rot_z(np.pi / 2), [5.0, 0.0, 0.0]))
    tree.add("body", "camera", se3.make(np.eye(3), [0.3, 0.0, 0.2]))
    np.testing.assert_allclose(tree.lookup("world", "camera")[:3, 3], [5.0, 0.3, 0.2], atol=1e-14)
    np.testing.assert_allclose(tree.lookup("camera", "body")[:3, 3], [-0.3, 0.0, -0.2], atol=1e-14)


def test_chapter9_quiz_camera_in_body_from_two_world_poses():
    T_w_r = se3.make(so3.rot_z(np.pi / 2), [5.0, 0.0, 0.0])
    T_w_c = se3.make(so3.rot_z(np.pi / 2), [5.0, 0.3, 0.2])  # chapter 7's answer
    T_r_c = se3.invert(T_w_r) @ T_w_c
    expected = [[1, 0, 0, 0.3], [0, 1, 0, 0.0], [0, 0, 1, 0.2], [0, 0, 0, 1]]
    np.testing.assert_allclose(T_r_c, expected, atol=1e-14)
