"""A camera calibration as Kalibr's camchain YAML (ethz-asl/kalibr, wiki "Yaml formats").

Kalibr describes each camera under ``cam0:``, ``cam1:``...: ``camera_model``, ``intrinsics``
(``[fu, fv, pu, pv]`` for a pinhole), ``distortion_model`` and ``distortion_coeffs``,
``resolution`` (``[width, height]``), ``rostopic``, ``cam_overlaps``, and, calibrated against an
IMU, ``T_cam_imu`` (IMU to camera coordinates, ``p_cam = T_cam_imu p_imu``) and
``timeshift_cam_imu`` (``t_imu = t_cam + shift``). vnav-sim has no IMU yet; the camera is
calibrated against the body's pose stream instead, so the file says so in its key names:

- ``T_cam_body``: body to camera coordinates, ``p_cam = T_cam_body p_body``, the inverse of
  the project's ``T_b_c`` (the camera's pose in the body);
- ``timeshift_cam_body``: ``t_body = t_cam + shift``, with ``t_body`` the pose clock: the
  project's ``time_offset_s`` (``t_pose = t_cam + offset``), same sign.

The project's own figures sit in ``cam0.vnav_sim``, a key no Kalibr reader looks up. Not at the
top level: Kalibr's ``CameraChainParameters.numCameras()`` counts every top-level key as a
camera. The intrinsics are the project's (``vnav.camera.PinholeCamera``: OpenCV's pixel-centre
convention, which Kalibr's pinhole shares); the images are rendered without distortion.
Numbers are written in full (``repr``) and every float with a decimal point, as YAML 1.1
(PyYAML, which Kalibr reads with) needs to read it as a float.
"""

from __future__ import annotations

import math

import numpy as np

from vnav import se3
from vnav.camera import PinholeCamera

__all__ = ["IMAGE_TOPIC", "camchain_yaml", "yaml_float"]

IMAGE_TOPIC = "/camera/image_raw"
"""The image topic of the run's ROS 2 bag (``scenarios.export.mcap``)."""


def yaml_float(value: float) -> str:
    """``value`` in full, as YAML 1.1 reads a float: ``1e-05`` becomes ``1.0e-05``.

    Raises
    ------
    ValueError
        If ``value`` is not finite.
    """
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"a camchain number must be finite, got {value}")
    text = repr(value)
    mantissa, e, exponent = text.partition("e")
    if e and "." not in mantissa:
        text = f"{mantissa}.0e{exponent}"
    return text


def _row(values) -> str:
    return "[" + ", ".join(yaml_float(v) for v in values) + "]"


def camchain_yaml(
    camera: PinholeCamera,
    T_b_c: np.ndarray,
    time_offset_s: float,
    vnav_sim: dict[str, float | int | np.ndarray],
) -> str:
    """The camchain text of one camera calibrated against the body.

    Parameters
    ----------
    camera : PinholeCamera
        Intrinsics and resolution.
    T_b_c : ndarray, shape (4, 4)
        The camera's optical frame in the body (written inverted, as ``T_cam_body``).
    time_offset_s : float
        ``t_pose = t_cam + time_offset_s`` (written as ``timeshift_cam_body``).
    vnav_sim : dict of str to float, int or ndarray
        The project's own figures, written under ``cam0.vnav_sim`` in this order (a (4, 4)
        array as four rows).

    Raises
    ------
    ValueError
        If ``T_b_c`` is not a rigid transform or a number is not finite.
    """
    T_b_c = se3.check_pose(T_b_c, "T_b_c")
    T_cam_body = se3.invert(T_b_c)
    lines = [
        '# Kalibr camchain (ethz-asl/kalibr, wiki "Yaml formats"), written by vnav-sim.',
        "# No IMU: T_cam_body and timeshift_cam_body stand where Kalibr writes T_cam_imu and",
        "# timeshift_cam_imu, the body (base_link, x forward, y left, z up) in place of the IMU.",
        "cam0:",
        "  camera_model: pinhole",
        f"  intrinsics: {_row([camera.fx, camera.fy, camera.cx, camera.cy])}  # fu, fv, pu, pv",
        "  distortion_model: radtan",
        f"  distortion_coeffs: {_row([0.0, 0.0, 0.0, 0.0])}",
        f"  resolution: [{int(camera.width)}, {int(camera.height)}]",
        f"  rostopic: {IMAGE_TOPIC}",
        "  cam_overlaps: []",
        "  T_cam_body:  # body to camera: p_cam = T_cam_body p_body (the inverse of T_b_c)",
        *(f"  - {_row(row)}" for row in T_cam_body),
        f"  timeshift_cam_body: {yaml_float(time_offset_s)}  # t_body = t_cam + shift",
        "  vnav_sim:  # the project's names and figures; no Kalibr reader looks them up",
    ]
    for key, value in vnav_sim.items():
        if isinstance(value, np.ndarray):
            lines.append(f"    {key}:")
            lines += [f"    - {_row(row)}" for row in np.atleast_2d(value)]
        elif isinstance(value, (int, np.integer)) and not isinstance(value, bool):
            lines.append(f"    {key}: {int(value)}")
        else:
            lines.append(f"    {key}: {yaml_float(value)}")
    return "\n".join(lines) + "\n"
