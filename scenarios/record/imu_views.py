"""What a recording adds for a run with an ``[imu]``: the IMU frame on the body and its readings.

The IMU reads in its own frame ``i`` (docs/CONVENTIONS.md): the specific force ``f_i`` and the
angular rate ``omega_i`` (``vnav.imu``). Its recording draws (``scenarios.record.recording``
calls ``log_imu_frames`` when the run starts and ``send_imu`` once it is over)::

    world/body/imu                 Transform3D T_b_i (body <- imu: the true mount, where the
                                   simulator's IMU sits, the frame of its readings), static
    world/body/imu/axes, name      in imu: its axes, thin arrows, and its name on a dot past
                                   the tip of z (static)
    world/body/imu_declared        with an [imu.mount_error] only: Transform3D T_b_i_declared
                                   (body <- the mount the estimator is told), static
    world/body/imu_declared/axes, name   in imu_declared: its axes (yellow) and its name on a
                                   yellow dot past the tip of x (static)
    imu/specific_force_i           Scalars x, y, z: each reading's specific force, m/s^2, in
                                   the IMU frame (noise and bias included)
    imu/angular_rate_i             Scalars x, y, z: each reading's angular rate, rad/s, in the
                                   IMU frame
    imu/specific_force_i_noise_free, imu/angular_rate_i_noise_free
                                   Scalars x, y, z: vnav.imu's chain fed the body's true
                                   motion at each reading's physics step (no noise)

The readings are logged on ``sim_time`` alone, at their stamps on the IMU's clock
(``ImuRecord.t_s``: ``t_imu = t_cam + time_offset_s``; a reading has no camera tick), as one
column batch each. A run without ``[imu]`` logs none of it. The plots' tab is
``viewer.imu_tab``, the scenario document's paragraph ``viewer.describe_imu``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from scenarios.record.viewer import (
    AXIS_COLORS,
    AXIS_LENGTH_M,
    CAMERA_AXES_UI_POINTS,
    DECLARED_MOUNT_COLOR,
    FRAME,
    IMU_CHAIN,
    IMU_CHAIN_COLOR,
    IMU_DECLARED_NAME_X_M,
    IMU_NAME_Z_M,
    MOUNT_AXIS_LENGTH_M,
    entity,
    imu_series_names,
)
from scenarios.run.records import RunResult
from scenarios.scenario.spec import ScenarioSpec
from vnav import quat

if TYPE_CHECKING:
    from sim.config import ImuConfig

__all__ = ["IMU_CHAIN_LINE_WIDTH", "IMU_LINE_WIDTH", "log_imu_frames", "send_imu"]

IMU_LINE_WIDTH = 1.5
"""Width of a reading's curve in the IMU plots, points."""
IMU_CHAIN_LINE_WIDTH = 0.75
"""Width of the noise-free prediction's curve, points: thinner, so the readings show round it."""


def _mount_transform(T_b_i: np.ndarray, frame: str) -> rr.Transform3D:
    """``T_b_i`` as Rerun's parent-from-child transform from ``frame`` to the body (vnav and
    Rerun both order quaternions x, y, z, w: no reordering)."""
    return rr.Transform3D(
        translation=T_b_i[:3, 3],
        quaternion=rr.Quaternion(xyzw=quat.from_matrix(T_b_i[:3, :3])),
        child_frame=frame,
        parent_frame=FRAME.BODY,
    )


def log_imu_frames(rec: rr.RecordingStream, spec: ScenarioSpec) -> None:
    """The IMU frame on the body, static: the true mount with its axes and name, and, with an
    ``[imu.mount_error]``, the declared mount in yellow. Nothing without an ``[imu]``."""
    imu = spec.scene.imu
    if imu is None:
        return
    declared = not imu.mount_error.is_zero
    _log_true_imu(rec, imu, declared)
    if declared:
        _log_declared_imu(rec, imu)


def _log_true_imu(rec: rr.RecordingStream, imu: ImuConfig, declared: bool) -> None:
    """The IMU's true mount on the body, with its axes and its name past its z axis' tip.

    Parameters
    ----------
    rec : rerun.RecordingStream
        The recording, logged to statically.
    imu : ImuConfig
        The IMU: its true mount ``T_b_i``.
    declared : bool
        A declared mount is drawn beside it: the name then says "imu (true)".
    """
    rec.log(entity.IMU, _mount_transform(imu.T_b_i, FRAME.IMU), static=True)
    for path in (entity.IMU_AXES, entity.IMU_NAME):
        rec.log(path, rr.CoordinateFrame(FRAME.IMU), static=True)
    rec.log(
        entity.IMU_AXES,
        rr.Arrows3D(
            vectors=AXIS_LENGTH_M[FRAME.IMU] * np.eye(3),
            colors=AXIS_COLORS,
            radii=rr.Radius.ui_points(CAMERA_AXES_UI_POINTS),
        ),
        static=True,
    )
    rec.log(
        entity.IMU_NAME,
        rr.Points3D(
            [[0.0, 0.0, IMU_NAME_Z_M]],
            colors=[AXIS_COLORS[2]],
            radii=rr.Radius.ui_points(1.5),
            labels=["imu (true)" if declared else "imu"],
            show_labels=True,
        ),
        static=True,
    )


def _log_declared_imu(rec: rr.RecordingStream, imu: ImuConfig) -> None:
    """The IMU's declared mount on the body, in yellow, with its axes and name.

    Parameters
    ----------
    rec : rerun.RecordingStream
        The recording, logged to statically.
    imu : ImuConfig
        The IMU: its declared mount ``T_b_i_declared``.
    """
    rec.log(
        entity.IMU_DECLARED,
        _mount_transform(imu.T_b_i_declared, FRAME.IMU_DECLARED),
        static=True,
    )
    for path in (entity.IMU_DECLARED_AXES, entity.IMU_DECLARED_NAME):
        rec.log(path, rr.CoordinateFrame(FRAME.IMU_DECLARED), static=True)
    rec.log(
        entity.IMU_DECLARED_AXES,
        rr.Arrows3D(
            vectors=MOUNT_AXIS_LENGTH_M[FRAME.IMU_DECLARED] * np.eye(3),
            colors=[DECLARED_MOUNT_COLOR],
            radii=rr.Radius.ui_points(CAMERA_AXES_UI_POINTS),
        ),
        static=True,
    )
    # Named past the tip of its x axis: its z lies within a degree or two of the true IMU's,
    # where that one is named.
    rec.log(
        entity.IMU_DECLARED_NAME,
        rr.Points3D(
            [[IMU_DECLARED_NAME_X_M, 0.0, 0.0]],
            colors=[DECLARED_MOUNT_COLOR],
            radii=rr.Radius.ui_points(1.5),
            labels=["imu declared"],
            show_labels=True,
        ),
        static=True,
    )


def send_imu(rec: rr.RecordingStream, result: RunResult) -> None:
    """Every IMU reading of the run and its noise-free prediction, on ``sim_time`` at the
    reading's stamp, one column batch per entity, with their curves' names and colours.
    Nothing for a run without an ``[imu]``."""
    record = result.imu
    if record is None:
        return
    index = [rr.TimeColumn("sim_time", duration=np.asarray(record.t_s, dtype=np.float64))]
    values = {
        entity.IMU_SPECIFIC_FORCE: record.accel_i,
        entity.IMU_ANGULAR_RATE: record.gyro_i,
        entity.IMU_SPECIFIC_FORCE_CHAIN: record.accel_chain_i,
        entity.IMU_ANGULAR_RATE_CHAIN: record.gyro_chain_i,
    }
    chains = set(IMU_CHAIN.values())
    for path, series in values.items():
        if series is None:  # a record that kept no prediction
            continue
        chain = path in chains
        rec.log(
            path,
            rr.SeriesLines(
                colors=[IMU_CHAIN_COLOR] * 3 if chain else AXIS_COLORS,
                names=imu_series_names(path),
                widths=[IMU_CHAIN_LINE_WIDTH if chain else IMU_LINE_WIDTH] * 3,
            ),
            static=True,
        )
        if len(record.t_s):
            rec.send_columns(
                path, indexes=index, columns=rr.Scalars.columns(scalars=np.asarray(series))
            )
