"""A camera calibration as Kalibr's camchain YAML (ethz-asl/kalibr, wiki "Yaml formats").

Kalibr describes each camera under ``cam0:``, ``cam1:``...: ``camera_model``, ``intrinsics``
(``[fu, fv, pu, pv]`` for a pinhole), ``distortion_model`` and ``distortion_coeffs``,
``resolution`` (``[width, height]``), ``rostopic``, ``cam_overlaps``, and, calibrated against an
IMU, ``T_cam_imu`` (IMU to camera coordinates, ``p_cam = T_cam_imu p_imu``) and
``timeshift_cam_imu`` (``t_imu = t_cam + shift``). vnav-sim calibrates the camera against the
body's pose stream, so the file says so in its key names:

- ``T_cam_body``: body to camera coordinates, ``p_cam = T_cam_body p_body``, the inverse of
  the project's ``T_b_c`` (the camera's pose in the body);
- ``timeshift_cam_body``: ``t_body = t_cam + shift``, with ``t_body`` the pose clock: the
  project's ``time_offset_s`` (``t_pose = t_cam + offset``), same sign.

A run with an IMU (``ImuExtrinsics``) also has Kalibr's own two keys:

- ``T_cam_imu``: IMU to camera coordinates, ``p_cam = T_cam_imu p_imu``, composed through the
  body: ``inverse(T_b_c) @ T_b_i``, the camera's mount as calibrated and the IMU's as the
  ``ImuExtrinsics`` give it (the declared mount when there is no camera-IMU calibration);
- ``timeshift_cam_imu``: ``t_imu = t_cam + shift``, the project's ``[imu] time_offset_s``
  convention, same sign (0.0, the clocks taken as synchronised, when not calibrated).

``cam0.vnav_sim.imu_extrinsics`` says where the IMU's figures come from.

A camera calibrated against the IMU itself (``vnav.imu_calibration``, ``imu_camchain_yaml``)
has Kalibr's two keys alone, as ``kalibr_calibrate_imu_camera`` writes them: ``T_cam_imu``, the
inverse of the recovered ``T_i_c``, and ``timeshift_cam_imu``, the recovered offset; no body.

The project's own figures sit in ``cam0.vnav_sim``, a key no Kalibr reader looks up. Not at the
top level: Kalibr's ``CameraChainParameters.numCameras()`` counts every top-level key as a
camera. The intrinsics are the project's (``vnav.camera.PinholeCamera``: OpenCV's pixel-centre
convention, which Kalibr's pinhole shares); the images are rendered without distortion.
Numbers are written in full (``repr``) and every float with a decimal point, as YAML 1.1
(PyYAML, which Kalibr reads with) needs to read it as a float.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vnav import se3
from vnav.camera import PinholeCamera

__all__ = ["IMAGE_TOPIC", "ImuExtrinsics", "camchain_yaml", "imu_camchain_yaml", "yaml_float"]

IMAGE_TOPIC = "/camera/image_raw"
"""The image topic of the run's ROS 2 bag (``scenarios.export.mcap``)."""


@dataclass(frozen=True)
class ImuExtrinsics:
    """The IMU's mount and clock for a camchain's ``T_cam_imu`` and ``timeshift_cam_imu``.

    Attributes
    ----------
    T_b_i : ndarray, shape (4, 4)
        The IMU frame in the body.
    timeshift_cam_imu_s : float
        ``t_imu = t_cam + shift``, seconds.
    source : str
        Where they come from, one sentence (written as ``cam0.vnav_sim.imu_extrinsics``).
    """

    T_b_i: np.ndarray
    timeshift_cam_imu_s: float
    source: str

    @classmethod
    def declared(cls, T_b_i_declared: np.ndarray) -> ImuExtrinsics:
        """No camera-IMU calibration: the declared mount, and the clocks taken as
        synchronised (a shift of 0.0)."""
        return cls(
            np.asarray(T_b_i_declared, dtype=np.float64),
            0.0,
            "declared: T_cam_imu uses the IMU's declared mount (no camera-IMU calibration); "
            "timeshift_cam_imu 0.0 is not calibrated (the clocks taken as synchronised)",
        )


def _quoted(text: str) -> str:
    """A YAML single-quoted string."""
    return "'" + text.replace("'", "''") + "'"


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
    vnav_sim: dict[str, float | int | str | np.ndarray],
    imu: ImuExtrinsics | None = None,
) -> str:
    """The camchain text of one camera calibrated against the body (and, with ``imu``,
    referred to the IMU as Kalibr does).

    Parameters
    ----------
    camera : PinholeCamera
        Intrinsics and resolution.
    T_b_c : ndarray, shape (4, 4)
        The camera's optical frame in the body (written inverted, as ``T_cam_body``).
    time_offset_s : float
        ``t_pose = t_cam + time_offset_s`` (written as ``timeshift_cam_body``).
    vnav_sim : dict of str to float, int, str or ndarray
        The project's own figures, written under ``cam0.vnav_sim`` in this order (a (4, 4)
        array as four rows), then, with ``imu``, ``T_b_i`` and ``imu_extrinsics``.
    imu : ImuExtrinsics, optional
        The IMU's mount and clock: written as ``T_cam_imu = inverse(T_b_c) @ T_b_i`` and
        ``timeshift_cam_imu``.

    Raises
    ------
    ValueError
        If ``T_b_c`` or ``imu.T_b_i`` is not a rigid transform or a number is not finite.
    """
    T_b_c = se3.check_pose(T_b_c, "T_b_c")
    T_cam_body = se3.invert(T_b_c)
    head, imu_lines, vnav_sim = _imu_parts(T_cam_body, imu, vnav_sim)
    return _text(
        camera,
        head,
        [
            *imu_lines,
            "  T_cam_body:  # body to camera: p_cam = T_cam_body p_body (the inverse of T_b_c)",
            *(f"  - {_row(row)}" for row in T_cam_body),
            f"  timeshift_cam_body: {yaml_float(time_offset_s)}  # t_body = t_cam + shift",
        ],
        vnav_sim,
    )


def _imu_parts(
    T_cam_body: np.ndarray,
    imu: ImuExtrinsics | None,
    vnav_sim: dict[str, float | int | str | np.ndarray],
) -> tuple[list[str], list[str], dict[str, float | int | str | np.ndarray]]:
    """What ``camchain_yaml`` writes of the IMU: the comment heading the file, the lines of
    ``T_cam_imu`` and ``timeshift_cam_imu`` (none without ``imu``), and ``vnav_sim`` with the
    IMU's mount and its source added.

    Raises
    ------
    ValueError
        If ``imu.T_b_i`` is not a rigid transform or its shift is not finite.
    """
    if imu is None:
        head = [
            "# No IMU: T_cam_body and timeshift_cam_body stand where Kalibr writes T_cam_imu and",
            "# timeshift_cam_imu, the body (base_link, x forward, y left, z up) in place of the "
            "IMU.",
        ]
        return head, [], vnav_sim
    T_b_i = se3.check_pose(imu.T_b_i, "T_b_i")
    T_cam_imu = T_cam_body @ T_b_i
    head = [
        "# T_cam_imu and timeshift_cam_imu refer the camera to the IMU (cam0.vnav_sim.",
        "# imu_extrinsics says where the IMU's come from); T_cam_body and timeshift_cam_body",
        "# refer it to the body (base_link, x forward, y left, z up), as it was calibrated.",
    ]
    imu_lines = [
        "  T_cam_imu:  # IMU to camera: p_cam = T_cam_imu p_imu = inverse(T_b_c) T_b_i p_imu",
        *(f"  - {_row(row)}" for row in T_cam_imu),
        f"  timeshift_cam_imu: {yaml_float(imu.timeshift_cam_imu_s)}  # t_imu = t_cam + shift",
    ]
    return head, imu_lines, {**vnav_sim, "T_b_i": T_b_i, "imu_extrinsics": imu.source}


def imu_camchain_yaml(
    camera: PinholeCamera,
    T_i_c: np.ndarray,
    timeshift_cam_imu_s: float,
    vnav_sim: dict[str, float | int | str | np.ndarray],
) -> str:
    """The camchain text of one camera calibrated against an IMU, as Kalibr's
    ``kalibr_calibrate_imu_camera`` writes it: ``T_cam_imu`` and ``timeshift_cam_imu`` are the
    calibrated ones (``vnav.imu_calibration``); no body in it.

    Parameters
    ----------
    camera : PinholeCamera
        Intrinsics and resolution.
    T_i_c : ndarray, shape (4, 4)
        The camera's optical frame in the IMU frame (written inverted, as ``T_cam_imu``).
    timeshift_cam_imu_s : float
        ``t_imu = t_cam + shift``, seconds.
    vnav_sim : dict of str to float, int, str or ndarray
        The project's own figures, written under ``cam0.vnav_sim`` in this order (a (4, 4)
        array as four rows, a (3,) one as one list).

    Raises
    ------
    ValueError
        If ``T_i_c`` is not a rigid transform or a number is not finite.
    """
    T_cam_imu = se3.invert(se3.check_pose(T_i_c, "T_i_c"))
    head = [
        "# T_cam_imu and timeshift_cam_imu calibrated from the images and the IMU's readings",
        "# alone (cam0.vnav_sim.imu_extrinsics): the camera referred to the IMU, no body.",
    ]
    imu_lines = [
        "  T_cam_imu:  # IMU to camera: p_cam = T_cam_imu p_imu (the inverse of T_i_c)",
        *(f"  - {_row(row)}" for row in T_cam_imu),
        f"  timeshift_cam_imu: {yaml_float(timeshift_cam_imu_s)}  # t_imu = t_cam + shift",
    ]
    return _text(camera, head, imu_lines, vnav_sim)


def _text(
    camera: PinholeCamera,
    head: list[str],
    extrinsics: list[str],
    vnav_sim: dict[str, float | int | str | np.ndarray],
) -> str:
    """The camchain: ``head`` (comments), ``cam0`` with the camera's intrinsics, the
    ``extrinsics`` lines and the project's figures under ``vnav_sim``."""
    lines = [
        '# Kalibr camchain (ethz-asl/kalibr, wiki "Yaml formats"), written by vnav-sim.',
        *head,
        "cam0:",
        "  camera_model: pinhole",
        f"  intrinsics: {_row([camera.fx, camera.fy, camera.cx, camera.cy])}  # fu, fv, pu, pv",
        "  distortion_model: radtan",
        f"  distortion_coeffs: {_row([0.0, 0.0, 0.0, 0.0])}",
        f"  resolution: [{int(camera.width)}, {int(camera.height)}]",
        f"  rostopic: {IMAGE_TOPIC}",
        "  cam_overlaps: []",
        *extrinsics,
        "  vnav_sim:  # the project's names and figures; no Kalibr reader looks them up",
    ]
    for key, value in vnav_sim.items():
        if isinstance(value, str):
            lines.append(f"    {key}: {_quoted(value)}")
        elif isinstance(value, np.ndarray) and value.ndim == 1:
            lines.append(f"    {key}: {_row(value)}")
        elif isinstance(value, np.ndarray):
            lines.append(f"    {key}:")
            lines += [f"    - {_row(row)}" for row in np.atleast_2d(value)]
        elif isinstance(value, (int, np.integer)) and not isinstance(value, bool):
            lines.append(f"    {key}: {int(value)}")
        else:
            lines.append(f"    {key}: {yaml_float(value)}")
    return "\n".join(lines) + "\n"
