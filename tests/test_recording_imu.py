"""A run with an ``[imu]`` in its recording, read back from the ``imu`` built-in's ``.rrd``: the
IMU frame on the body at its true and declared mounts, the readings in the IMU frame at their
stamps (the run's own, ``RunResult.imu``, and as many as the report counts), the noise-free
prediction beside them, and the description naming the frame, rate and noise figures; a
recording of a scenario without ``[imu]`` holds nothing of it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import entity_paths, read_rows

from scenarios.record.viewer import (
    AXIS_LENGTH_M,
    DECLARED_MOUNT_COLOR,
    FRAME,
    IMU_CHAIN,
    IMU_SERIES,
    entity,
    imu_series_names,
)
from scenarios.scenario import builtin
from vnav import quat, se3
from vnav.imu import GRAVITY_W

IMU_BUILTINS = [n for n in builtin.names() if builtin.load(n).scene.imu is not None]


def _pose(row) -> np.ndarray:
    R = quat.to_matrix(np.asarray(row["Transform3D:quaternion"][0]), normalize=True)
    return se3.make(R, row["Transform3D:translation"][0])


def _series(rrd, path: str) -> tuple[np.ndarray, np.ndarray]:
    """A plot's rows: their ``sim_time`` stamps (s) and values (N, 3)."""
    rows = [r for r in read_rows(rrd, path) if "Scalars:scalars" in r]
    assert all("tick" not in r for r in rows)  # a reading has no camera tick
    t_s = np.array([r["sim_time"] for r in rows]) * 1e-9
    return t_s, np.array([r["Scalars:scalars"] for r in rows])


def test_the_imu_builtin_is_registered():
    assert IMU_BUILTINS == ["imu"]


@pytest.mark.parametrize("name", IMU_BUILTINS)
def test_readings_are_the_runs_at_their_stamps(builtin_runs, name):
    """Each plot holds every reading of the run, at its stamp on the IMU's clock, with the
    values ``RunResult.imu`` holds; as many as the report counts."""
    run = builtin_runs[name]
    record = run.result.imu
    for path, values in (
        (entity.IMU_SPECIFIC_FORCE, record.accel_i),
        (entity.IMU_ANGULAR_RATE, record.gyro_i),
        (entity.IMU_SPECIFIC_FORCE_CHAIN, record.accel_chain_i),
        (entity.IMU_ANGULAR_RATE_CHAIN, record.gyro_chain_i),
    ):
        t_s, logged = _series(run.rrd, path)
        assert len(t_s) == run.report["imu"]["readings"] == len(record.t_s)
        np.testing.assert_allclose(t_s, record.t_s, atol=1e-9)
        np.testing.assert_allclose(logged, values, rtol=1e-12, atol=1e-12)
    # The stamps are the IMU clock's: the simulator's reading times (every 1 / rate_hz) moved
    # by t_imu - t_sim = time_offset_s - camera_clock_offset_s.
    imu = run.spec.scene.imu
    offset_s = imu.time_offset_s - run.spec.timing.camera_clock_offset_s
    np.testing.assert_allclose(
        record.t_s, np.arange(len(record.t_s)) / imu.rate_hz + offset_s, atol=1e-9
    )


@pytest.mark.parametrize("name", IMU_BUILTINS)
def test_each_plot_names_its_axes_in_the_imu_frame(builtin_runs, name):
    rrd = builtin_runs[name].rrd
    for path in [*IMU_SERIES, *IMU_CHAIN.values()]:
        (names,) = [
            r["SeriesLines:names"] for r in read_rows(rrd, path) if "SeriesLines:names" in r
        ]
        assert names == imu_series_names(path)
        for n, axis in zip(names, "xyz", strict=True):
            assert f" {axis} in the IMU frame" in n
        if path in IMU_CHAIN.values():
            assert all("noise-free" in n for n in names)


@pytest.mark.parametrize("name", IMU_BUILTINS)
def test_at_hover_the_prediction_is_gravitys_reaction_in_imu_axes(builtin_runs, name):
    """Hovering (the first second), the noise-free prediction logged is ``-g`` turned into the
    IMU frame by the true pose of the IMU at the camera ticks (``R_i_w (0, 0, +9.81)``: up,
    not down), and the gyroscope's is zero; the readings scatter round it by the declared
    white noise."""
    run = builtin_runs[name]
    imu, record = run.spec.scene.imu, run.result.imu
    t_s, f_logged = _series(run.rrd, entity.IMU_SPECIFIC_FORCE_CHAIN)
    _, w_logged = _series(run.rrd, entity.IMU_ANGULAR_RATE_CHAIN)
    offset_s = imu.time_offset_s - run.spec.timing.camera_clock_offset_s
    hover = [t for t in run.result.ticks if 0.1 < t.t_s < 1.0]
    assert hover
    for tick in hover:
        j = int(np.argmin(np.abs(t_s - offset_s - tick.t_s)))
        assert abs(t_s[j] - offset_s - tick.t_s) < 1e-9
        R_w_i = tick.T_w_b[:3, :3] @ imu.T_b_i[:3, :3]
        np.testing.assert_allclose(f_logged[j], R_w_i.T @ -GRAVITY_W, atol=1e-3)
        np.testing.assert_allclose(w_logged[j], 0.0, atol=1e-6)
    # White noise per reading: density / sqrt(dt); the first differences of reading minus
    # prediction cancel the (slow) bias and carry twice its variance.
    for values, chain, density in (
        (record.accel_i, record.accel_chain_i, imu.accelerometer_noise_density),
        (record.gyro_i, record.gyro_chain_i, imu.gyroscope_noise_density),
    ):
        sigma = float(np.std(np.diff(values - chain, axis=0))) / math.sqrt(2.0)
        assert sigma == pytest.approx(density * math.sqrt(imu.rate_hz), rel=0.05)


@pytest.mark.parametrize("name", IMU_BUILTINS)
def test_the_imu_frame_hangs_from_the_body_at_both_mounts(builtin_runs, name):
    """``world/body/imu`` is the true mount ``T_b_i`` (frame ``imu``, where the readings are
    taken), ``world/body/imu_declared`` the declared one, each drawn and named."""
    run = builtin_runs[name]
    imu = run.spec.scene.imu
    assert not imu.mount_error.is_zero
    for path, frame, T_b_i in (
        (entity.IMU, FRAME.IMU, imu.T_b_i),
        (entity.IMU_DECLARED, FRAME.IMU_DECLARED, imu.T_b_i_declared),
    ):
        (row,) = [r for r in read_rows(run.rrd, path) if "Transform3D:translation" in r]
        assert "tick" not in row and "sim_time" not in row
        assert row["Transform3D:child_frame"] == [frame]
        assert row["Transform3D:parent_frame"] == [FRAME.BODY]
        np.testing.assert_allclose(_pose(row), T_b_i, atol=1e-6)
    rows = read_rows(run.rrd, entity.IMU_AXES)
    (vectors,) = [r["Arrows3D:vectors"] for r in rows if "Arrows3D:vectors" in r]
    np.testing.assert_allclose(vectors, AXIS_LENGTH_M[FRAME.IMU] * np.eye(3), atol=1e-6)
    labels = {
        label
        for path in (entity.IMU_NAME, entity.IMU_DECLARED_NAME)
        for r in read_rows(run.rrd, path)
        for label in r.get("Points3D:labels") or []
    }
    assert labels == {"imu (true)", "imu declared"}
    (colors,) = [
        r["Arrows3D:colors"]
        for r in read_rows(run.rrd, entity.IMU_DECLARED_AXES)
        if "Arrows3D:colors" in r
    ]
    r, g, b = DECLARED_MOUNT_COLOR
    assert colors == [(r << 24) | (g << 16) | (b << 8) | 0xFF]


@pytest.mark.parametrize("name", IMU_BUILTINS)
def test_the_description_says_what_the_imu_frame_is(builtin_runs, name):
    run = builtin_runs[name]
    imu = run.spec.scene.imu
    texts = [
        r["TextDocument:text"][0]
        for r in read_rows(run.rrd, entity.DESCRIPTION)
        if "TextDocument:text" in r
    ]
    text = texts[-1]
    assert "frame `imu`" in text
    assert f"{list(imu.position_b)} m in the body frame" in text
    assert f"rpy_deg {list(imu.rpy_deg)}" in text
    assert f"{imu.rate_hz:g} Hz" in text
    assert f"t_imu = t_cam + {1e3 * imu.time_offset_s:g} ms" in text
    for key, unit in (
        ("accelerometer_noise_density", "m/s^2/sqrt(Hz)"),
        ("accelerometer_random_walk", "m/s^3/sqrt(Hz)"),
        ("gyroscope_noise_density", "rad/s/sqrt(Hz)"),
        ("gyroscope_random_walk", "rad/s^2/sqrt(Hz)"),
    ):
        assert f"{key} {getattr(imu, key):g} {unit}" in text
    assert f"{imu.mount_error.angle_deg:.2f} deg" in text


def test_recordings_without_an_imu_hold_nothing_of_it(builtin_runs):
    """Every built-in without ``[imu]``: no entity of the IMU, no IMU frame, no word of it in
    the scenario document."""
    others = [run for run in builtin_runs.values() if run.spec.scene.imu is None]
    assert len(others) == len(builtin_runs) - len(IMU_BUILTINS) > 0
    for run in others:
        paths = entity_paths(run.rrd)
        assert not [p for p in paths if "imu" in p.lower()], run.spec.name
        frames = {
            f
            for path in paths
            for r in read_rows(run.rrd, path)
            for key in ("Transform3D:child_frame", "CoordinateFrame:frame")
            for f in r.get(key) or []
        }
        assert not [f for f in frames if "imu" in f.lower()], run.spec.name
        texts = [
            r["TextDocument:text"][0]
            for r in read_rows(run.rrd, entity.DESCRIPTION)
            if "TextDocument:text" in r
        ]
        assert texts and not any("IMU" in t for t in texts), run.spec.name
