"""The camchain ``vnav-demo calibrate --out`` writes, read by PyYAML (what Kalibr reads its
YAML with) and checked field by field against Kalibr's documented format (ethz-asl/kalibr
wiki, "Yaml formats"): ``cam0`` with ``camera_model``, ``intrinsics [fu, fv, pu, pv]``,
``distortion_model``, ``distortion_coeffs``, ``resolution [width, height]``, ``rostopic``,
``cam_overlaps``; ``T_cam_body`` and ``timeshift_cam_body`` where Kalibr has ``T_cam_imu``
(IMU to camera coordinates) and ``timeshift_cam_imu`` (``t_imu = t_cam + shift``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from scenarios.commands.calibrate import to_yaml, write_yaml
from scenarios.export.kalibr import yaml_float
from vnav import se3, so3
from vnav.calibration import CalibrationResult
from vnav.camera import PinholeCamera
from vnav.frames import R_FLU_RDF

CAMERA = PinholeCamera.from_fovy(50.0, 641, 479)


def _result(T_b_c: np.ndarray, time_offset_s: float) -> CalibrationResult:
    return CalibrationResult(
        T_b_c=T_b_c,
        time_offset_s=time_offset_s,
        reprojection_rms_px=0.1234,
        frames_used=57,
        observations_used=230,
        std_rotation_deg=3.5e-05,
        std_translation_m=0.000125,
        std_offset_s=2e-06,
        # [translation (m), rotation (rad), offset (s)] with the standard errors above.
        covariance=np.diag([1.25e-4**2] * 3 + [math.radians(3.5e-5) ** 2] * 3 + [2e-6**2]),
    )


# A forward-looking camera pitched down 10 deg, 12 cm ahead of the body, a few um to the side.
MOUNT = se3.make(so3.rot_y(math.radians(10.0)) @ R_FLU_RDF, [0.12, 3e-05, -0.02])


def test_the_camchain_has_kalibrs_fields_and_types():
    """One camera, ``cam0``, and nothing else at the top level (Kalibr's
    ``CameraChainParameters.numCameras`` counts every top-level key); each field of the
    documented format with the type Kalibr checks (``timeshift`` a float even when tiny); the
    project's own figures under ``cam0.vnav_sim``, equal to the result's to the last bit."""
    result = _result(MOUNT, -2.5e-05)
    chain = yaml.safe_load(to_yaml(result, CAMERA))
    assert list(chain) == ["cam0"]
    cam0 = chain["cam0"]
    assert cam0["camera_model"] == "pinhole"
    assert cam0["intrinsics"] == [CAMERA.fx, CAMERA.fy, CAMERA.cx, CAMERA.cy]
    assert cam0["intrinsics"][2:] == [320.0, 239.0]  # (W - 1) / 2, (H - 1) / 2
    assert cam0["distortion_model"] == "radtan"
    assert cam0["distortion_coeffs"] == [0.0] * 4
    assert all(type(v) is float for v in cam0["intrinsics"] + cam0["distortion_coeffs"])
    assert cam0["resolution"] == [641, 479]
    assert all(type(v) is int for v in cam0["resolution"])
    assert cam0["rostopic"] == "/camera/image_raw"
    assert cam0["cam_overlaps"] == []
    assert type(cam0["timeshift_cam_body"]) is float
    assert cam0["timeshift_cam_body"] == result.time_offset_s
    ours = cam0["vnav_sim"]
    np.testing.assert_array_equal(ours["T_b_c"], MOUNT)
    assert ours["time_offset_s"] == result.time_offset_s
    for key in ("reprojection_rms_px", "std_rotation_deg", "std_translation_m", "std_offset_s"):
        assert ours[key] == getattr(result, key)
        assert type(ours[key]) is float
    assert (ours["frames_used"], ours["observations_used"]) == (57, 230)


def test_T_cam_body_takes_body_coordinates_into_the_camera():
    """``T_cam_body`` composed with the project's ``T_b_c`` is the identity (1e-15), and it
    does what Kalibr's ``T_cam_imu`` does, maps body coordinates into the camera's: a point
    5 m straight ahead of the body, seen by the camera 12 cm ahead, 2 cm below and 30 um left
    of the body origin, pitched 10 deg down, worked out by hand from the axes (optical z =
    (cos 10, 0, -sin 10) in the body, y (down) = (-sin 10, 0, -cos 10), x (right) = -y_body):
    4.88 m along the axis, above the image centre (y < 0), 30 um right."""
    chain = yaml.safe_load(to_yaml(_result(MOUNT, 0.03), CAMERA))
    T_cam_body = np.array(chain["cam0"]["T_cam_body"])
    assert T_cam_body.shape == (4, 4)
    np.testing.assert_array_equal(T_cam_body[3], [0.0, 0.0, 0.0, 1.0])
    np.testing.assert_allclose(T_cam_body @ MOUNT, np.eye(4), atol=1e-15)
    p_cam = T_cam_body @ np.array([5.0, 0.0, 0.0, 1.0])
    c, s = math.cos(math.radians(10.0)), math.sin(math.radians(10.0))
    np.testing.assert_allclose(
        p_cam[:3], [3e-05, -4.88 * s - 0.02 * c, 4.88 * c - 0.02 * s], rtol=0, atol=1e-12
    )


def test_numbers_are_yaml_floats():
    """What Python writes as ``1e-05`` PyYAML reads as a string (YAML 1.1 wants a decimal
    point): every number goes out with one and comes back the same float."""
    assert yaml.safe_load("x: 1e-05")["x"] == "1e-05"  # the trap
    for value in (1e-05, -2.5e-07, 3e20, 0.0, -0.0, 1.0, 0.1 + 0.2, 123456789.123):
        back = yaml.safe_load(f"x: {yaml_float(value)}")["x"]
        assert type(back) is float and back == value
    with pytest.raises(ValueError, match="finite"):
        yaml_float(float("nan"))


def test_write_yaml_is_whole_or_absent(tmp_path):
    """The file is written through a temporary beside it, renamed into place; a refused
    (non-rigid) mount leaves nothing."""
    out = tmp_path / "calib.yaml"
    write_yaml(_result(MOUNT, 0.0), CAMERA, out)
    assert [p.name for p in tmp_path.iterdir()] == ["calib.yaml"]
    assert yaml.safe_load(out.read_text())["cam0"]["timeshift_cam_body"] == 0.0
    bad = MOUNT.copy()
    bad[0, 0] += 0.1
    with pytest.raises(ValueError, match="not a rotation matrix"):
        write_yaml(_result(bad, 0.0), CAMERA, tmp_path / "bad.yaml")
    assert [p.name for p in tmp_path.iterdir()] == ["calib.yaml"]
