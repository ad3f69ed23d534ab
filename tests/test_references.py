"""vnav against independent implementations on many random inputs: MuJoCo, OpenCV, SciPy.

MuJoCo stores quaternions as [w, x, y, z]; every crossing goes through quat.xyzw_to_wxyz /
quat.wxyz_to_xyzw. SciPy is scalar last, like vnav.
"""

from __future__ import annotations

import cv2
import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from tests._geometry_samples import quaternions, rotation_vectors, unit_vectors
from vnav import quat, se3, so3

N = 300


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20240516)


def same_rotation_quat(a: np.ndarray, b: np.ndarray, atol: float) -> None:
    """a and b are the same rotation: equal up to the sign (q and -q)."""
    sign = np.where(np.sum(a * b, axis=-1) < 0.0, -1.0, 1.0)[..., None]
    np.testing.assert_allclose(a, sign * b, atol=atol)


# ------------------------------------------------------------------------------------ MuJoCo


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


def test_from_axis_angle_matches_mju_axisangle2quat(rng):
    axes = unit_vectors(rng, N) * rng.uniform(0.1, 5.0, (N, 1))  # not unit: vnav normalises
    angles = rng.uniform(-2 * np.pi, 2 * np.pi, N)
    q = quat.from_axis_angle(axes, angles)
    for axis, angle, q_vnav in zip(axes, angles, q, strict=True):
        res = np.zeros(4)
        mujoco.mju_axisAngle2Quat(res, axis / np.linalg.norm(axis), angle)
        np.testing.assert_allclose(q_vnav, quat.wxyz_to_xyzw(res), atol=1e-15)


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


# ------------------------------------------------------------------------------------ OpenCV


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


# ------------------------------------------------------------------------------------- SciPy


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


def test_slerp_matches_scipy(rng):
    q0, q1 = quaternions(rng, 200), quaternions(rng, 200)
    times = np.linspace(0.0, 1.0, 7)
    for a, b in zip(q0, q1, strict=True):
        ours = quat.slerp(a, b, times)
        # SciPy's Slerp also takes the shorter path between rotations.
        theirs = Slerp([0.0, 1.0], Rotation.from_quat([a, b]))(times).as_quat()
        same_rotation_quat(ours, theirs, atol=1e-12)


def test_se3_apply_matches_scipy_rigid_transform(rng):
    from scipy.spatial.transform import RigidTransform

    for v, t in zip(rotation_vectors(rng, 50), rng.uniform(-5, 5, (50, 3)), strict=True):
        T = se3.make(so3.exp(v), t)
        p = rng.uniform(-10, 10, (1000, 3))
        rigid = RigidTransform.from_matrix(T)
        np.testing.assert_allclose(se3.apply(T, p), rigid.apply(p), atol=1e-13)
        np.testing.assert_allclose(se3.invert(T), rigid.inv().as_matrix(), atol=1e-14)
