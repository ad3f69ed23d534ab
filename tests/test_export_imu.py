"""The IMU in the exports (``scenarios.export``): EuRoC's ``imu0/``, the ROS 2 bag's ``/imu`` and
``imu_link``, Kalibr's ``T_cam_imu`` and ``timeshift_cam_imu``, each read back by a reader
nobody here wrote (pandas, PyYAML, rosbags with the ROS 2 Humble type store, SciPy for the
rotations) and checked against what the run's IMU read (``RunResult.imu``), the scenario's
figures and each format's documentation: EuRoC's ``imu0`` files (the ASL dataset's header and
``sensor.yaml`` keys), ``sensor_msgs/msg/Imu``'s definition (``orientation_covariance[0] = -1``
for no orientation), Kalibr's wiki "Yaml formats" (``T_cam_imu`` takes IMU coordinates into
the camera's, ``t_imu = t_cam + timeshift_cam_imu``)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from scenarios import pipeline
from scenarios.cli import main
from scenarios.export import euroc
from scenarios.export.kalibr import ImuExtrinsics, camchain_yaml
from scenarios.export.ros2_msgs import msgdef
from scenarios.record.reader import imu_mount_declared
from scenarios.scenario import builtin
from sim.config import ImuConfig
from vnav.camera import PinholeCamera

HUMBLE = get_typestore(Stores.ROS2_HUMBLE)

IMU_SENSOR_KEYS = [
    "sensor_type",
    "comment",
    "T_BS",
    "rate_hz",
    "gyroscope_noise_density",
    "gyroscope_random_walk",
    "accelerometer_noise_density",
    "accelerometer_random_walk",
]
"""The keys of a EuRoC IMU's ``sensor.yaml`` (``mav0/imu0``), in the dataset's order."""

EUROC_IMU_HEADER = (
    "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
    "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]"
)
"""The EuRoC dataset's ``imu0/data.csv`` header, as the dataset writes it."""


@pytest.fixture(scope="module")
def imu_run(tmp_path_factory) -> pipeline.Outcome:
    """The ``imu`` built-in (an IMU turned and off-centre on the body, its declared mount a
    little off the true one, its clock 15 ms ahead of the camera's, ADIS16448 noise) for 1 s,
    exported as EuRoC and MCAP."""
    spec = dataclasses.replace(builtin.load("imu"), duration_s=1.0)
    out = tmp_path_factory.mktemp("imu")
    return pipeline.run(spec, seed=1, out_dir=out, exports=("euroc", "mcap"))


def _pose(translation, rotation) -> np.ndarray:
    """A 4x4 from a ROS translation and quaternion, by SciPy (not vnav)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([rotation.x, rotation.y, rotation.z, rotation.w]).as_matrix()
    T[:3, 3] = [translation.x, translation.y, translation.z]
    return T


def _ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


# ------------------------------------------------------------------------------ EuRoC


def test_euroc_imu_table_read_by_pandas_is_the_runs_readings(imu_run):
    """pandas reads ``imu0/data.csv`` (EuRoC's header, column for column): each row is a
    reading of the run, its stamp on the IMU's clock in integer nanoseconds, the angular rate
    then the specific force in the IMU frame, to the last bit."""
    path = imu_run.rrd_path.parent / "imu.euroc" / "mav0" / "imu0" / "data.csv"
    assert path.read_text().splitlines()[0] == EUROC_IMU_HEADER
    table = pd.read_csv(path)
    assert list(table.columns) == EUROC_IMU_HEADER.split(",")
    readings = imu_run.result.imu
    # 200 Hz over 1 s: a reading as each physics step is taken, from t = 0 (none after the
    # last, whose controls are never set).
    assert len(table) == len(readings.t_s) == 200
    np.testing.assert_array_equal(
        table.iloc[:, 0].to_numpy(), np.round(readings.t_s * 1e9).astype(np.int64)
    )
    np.testing.assert_allclose(table.iloc[:, 1:4].to_numpy(), readings.gyro_i, rtol=0, atol=1e-9)
    np.testing.assert_allclose(table.iloc[:, 4:7].to_numpy(), readings.accel_i, rtol=0, atol=1e-9)


def test_euroc_imu_is_on_its_own_clock_ahead_of_the_camera_by_the_offset(imu_run):
    """The documented clock choice: cam0 on the camera clock, imu0 on the IMU's, not
    converted. The first image and the first reading are both taken at the flight's start,
    so their stamps differ by the scenario's ``t_imu = t_cam + time_offset_s`` (15 ms); the
    export's note says so."""
    mav0 = imu_run.rrd_path.parent / "imu.euroc" / "mav0"
    images = [
        int(r.split(",")[0]) for r in (mav0 / "cam0" / "data.csv").read_text().splitlines()[1:]
    ]
    readings = [
        int(r.split(",")[0]) for r in (mav0 / "imu0" / "data.csv").read_text().splitlines()[1:]
    ]
    offset_s = imu_run.result.spec.scene.imu.time_offset_s
    assert offset_s == pytest.approx(0.015)
    assert imu_run.result.ticks[0].t_s == 0.0  # the first image is exposed at the start
    assert readings[0] - images[0] == round(offset_s * 1e9)
    note = imu_run.report["exports"]["euroc"]["note"]
    assert "imu0/ is stamped on the IMU's clock (t_imu = t_cam + 0.015 s)" in note


def test_euroc_imu_sensor_file_has_the_datasets_keys_and_the_declared_mount(imu_run):
    """``imu0/sensor.yaml`` read by PyYAML: EuRoC's keys in EuRoC's order, ``T_BS`` the
    declared mount (not the true one the simulator's IMU sits at), the rate and Kalibr's four
    noise figures as the scenario's, each a float."""
    imu = imu_run.result.spec.scene.imu
    sensor_path = imu_run.rrd_path.parent / "imu.euroc" / "mav0" / "imu0" / "sensor.yaml"
    sensor = yaml.safe_load(sensor_path.read_text())
    assert list(sensor) == IMU_SENSOR_KEYS
    assert sensor["sensor_type"] == "imu"
    assert "declared mount" in sensor["comment"] and "t_imu = t_cam + 0.015 s" in sensor["comment"]
    assert (sensor["T_BS"]["rows"], sensor["T_BS"]["cols"]) == (4, 4)
    T_BS = np.array(sensor["T_BS"]["data"], dtype=np.float64).reshape(4, 4)
    np.testing.assert_array_equal(T_BS, imu.T_b_i_declared)
    assert np.abs(T_BS - imu.T_b_i).max() > 1e-3  # the mount error is a few millimetres
    assert sensor["rate_hz"] == imu.rate_hz == 200.0
    for key in IMU_SENSOR_KEYS[4:]:
        assert type(sensor[key]) is float and sensor[key] == getattr(imu, key) > 0.0


def test_euroc_ground_truth_biases_are_unknown_with_a_drifting_imu(imu_run):
    """The IMU's biases drift (nonzero random walks) and the run does not keep them: the
    ground truth's six bias columns are NaN, not a zero that would be false; the pose columns
    are still the run's truth."""
    path = imu_run.rrd_path.parent / "imu.euroc" / "mav0" / "state_groundtruth_estimate0"
    header, *rows = (path / "data.csv").read_text().splitlines()
    assert header == euroc.GROUNDTRUTH_HEADER
    values = np.array([r.split(",")[1:] for r in rows], dtype=np.float64)
    assert len(values) == len(imu_run.result.ticks)
    assert np.isnan(values[:, 10:]).all() and np.isfinite(values[:, :10]).all()
    for row, tick in zip(values, imu_run.result.ticks, strict=True):
        np.testing.assert_allclose(row[:3], tick.T_w_b[:3, 3], atol=1e-9)
    comment = yaml.safe_load((path / "sensor.yaml").read_text())["comment"]
    assert "biases nan" in comment


# ------------------------------------------------------------------------------ MCAP


def _bag(outcome: pipeline.Outcome) -> dict[str, list]:
    out: dict[str, list] = {}
    with AnyReader([outcome.rrd_path.parent / "imu.mcap"], default_typestore=HUMBLE) as reader:
        for conn, log_time, raw in reader.messages():
            out.setdefault(conn.topic, []).append((log_time, reader.deserialize(raw, conn.msgtype)))
    return out


def test_the_bags_imu_read_by_rosbags_is_the_runs_readings(imu_run):
    """``/imu`` deserialised by rosbags (ROS 2 Humble's ``sensor_msgs/msg/Imu``): one message
    per reading, in ``imu_link``, stamped on the IMU's clock (the camera clock reads 0 at the
    start, so no whole-second origin), the rate and force equal to the readings (1e-9); no
    orientation (``orientation_covariance[0] = -1``); the two covariances diagonal with each
    axis' white-noise variance, Kalibr's ``density^2 * rate_hz``."""
    imu = imu_run.result.spec.scene.imu
    readings = imu_run.result.imu
    bag = _bag(imu_run)
    messages = bag["/imu"]
    assert len(messages) == len(readings.t_s)
    gyro_var = imu.gyroscope_noise_density**2 * imu.rate_hz
    accel_var = imu.accelerometer_noise_density**2 * imu.rate_hz
    for (log_time, msg), t_s, gyro_i, accel_i in zip(
        messages, readings.t_s, readings.gyro_i, readings.accel_i, strict=True
    ):
        assert msg.header.frame_id == "imu_link"
        assert _ns(msg.header.stamp) == log_time == round(t_s * 1e9)
        w, a = msg.angular_velocity, msg.linear_acceleration
        np.testing.assert_allclose([w.x, w.y, w.z], gyro_i, rtol=0, atol=1e-9)
        np.testing.assert_allclose([a.x, a.y, a.z], accel_i, rtol=0, atol=1e-9)
        assert msg.orientation_covariance[0] == -1.0
        np.testing.assert_allclose(
            msg.angular_velocity_covariance.reshape(3, 3), gyro_var * np.eye(3), rtol=1e-12
        )
        np.testing.assert_allclose(
            msg.linear_acceleration_covariance.reshape(3, 3), accel_var * np.eye(3), rtol=1e-12
        )
    assert readings.t_s[0] == pytest.approx(0.015)  # the IMU's clock, 15 ms ahead of the camera's
    assert "/imu is stamped on the IMU's clock" in imu_run.report["exports"]["mcap"]["note"]


def test_the_bags_static_transforms_hold_the_declared_imu_mount(imu_run):
    """``/tf_static`` is one message (a latched topic keeps its last one only) with the camera's
    mount and ``base_link`` -> ``imu_link``: the declared IMU mount, not the true one."""
    imu = imu_run.result.spec.scene.imu
    ((_, static),) = _bag(imu_run)["/tf_static"]
    by_child = {t.child_frame_id: t for t in static.transforms}
    assert set(by_child) == {"camera_optical_frame", "imu_link"}
    t = by_child["imu_link"]
    assert t.header.frame_id == "base_link"
    T_b_i = _pose(t.transform.translation, t.transform.rotation)
    np.testing.assert_allclose(T_b_i, imu.T_b_i_declared, atol=1e-12)
    assert np.abs(T_b_i - imu.T_b_i).max() > 1e-3


def test_the_imu_message_definition_is_ros2_humbles():
    """``sensor_msgs/msg/Imu``'s ``ros2msg`` text is the one rosbags' Humble type store
    generates."""
    assert msgdef("sensor_msgs/msg/Imu") == HUMBLE.generate_msgdef("sensor_msgs/msg/Imu", 2)[0]


def test_an_imu_clock_behind_the_camera_moves_the_origin_to_keep_stamps_positive(tmp_path):
    """An IMU clock 1.5 s behind the camera's (which reads 0 at the start): its first reading
    would be stamped -1.5 s, which ROS time cannot hold; the whole-second origin becomes 2 s
    and every stamp, the readings' and the images', is shifted by it."""
    spec = builtin.load("imu")
    scene = dataclasses.replace(
        spec.scene, imu=dataclasses.replace(spec.scene.imu, time_offset_s=-1.5)
    )
    spec = dataclasses.replace(spec, scene=scene, duration_s=0.2)
    outcome = pipeline.run(spec, seed=1, out_dir=tmp_path, exports=("mcap",))
    bag = _bag(outcome)
    origin_ns = 2_000_000_000
    imu_stamps = [log_time for log_time, _ in bag["/imu"]]
    assert imu_stamps == [round(t * 1e9) + origin_ns for t in outcome.result.imu.t_s]
    assert imu_stamps[0] == origin_ns - 1_500_000_000
    assert [t for t, _ in bag["/tf"]] == [
        round(r.timing.stamp_cam_s * 1e9) + origin_ns for r in outcome.result.ticks
    ]


# ------------------------------------------------------------------------------ Kalibr


def test_the_recording_gives_the_declared_imu_mount(imu_run):
    """``imu_mount_declared`` reads the declared mount from the recording
    (``world/body/imu_declared``), not the true one at ``world/body/imu``."""
    imu = imu_run.result.spec.scene.imu
    T_b_i = imu_mount_declared(imu_run.rrd_path)
    np.testing.assert_allclose(T_b_i, imu.T_b_i_declared, atol=1e-6)  # float32 in the file
    assert np.abs(T_b_i - imu.T_b_i).max() > 1e-3


def test_T_cam_imu_takes_imu_coordinates_into_the_camera():
    """Kalibr's ``T_cam_imu`` (IMU to camera coordinates): a point given in the IMU frame,
    carried into the body by ``T_b_i`` and into the camera by the inverse of ``T_b_c`` (both by
    SciPy), is ``T_cam_imu`` times the point; ``T_b_c @ T_cam_imu = T_b_i``;
    ``timeshift_cam_imu`` as given, with Kalibr's sign; ``T_cam_body`` kept beside it."""
    R_b_c = Rotation.from_euler("ZYX", [-90.0, 0.0, -105.0], degrees=True).as_matrix()
    T_b_c = np.eye(4)
    T_b_c[:3, :3], T_b_c[:3, 3] = R_b_c, [0.12, 0.01, -0.02]
    R_b_i = Rotation.from_euler("ZYX", [90.0, 30.0, 0.0], degrees=True).as_matrix()
    T_b_i = np.eye(4)
    T_b_i[:3, :3], T_b_i[:3, 3] = R_b_i, [0.04, -0.025, 0.015]
    imu = ImuExtrinsics(T_b_i, 0.015, "a test's")
    camera = PinholeCamera.from_fovy(50.0, 640, 480)
    cam0 = yaml.safe_load(camchain_yaml(camera, T_b_c, 0.03, {}, imu))["cam0"]
    T_cam_imu = np.array(cam0["T_cam_imu"])
    p_i = np.array([0.3, -0.2, 1.7])
    p_b = R_b_i @ p_i + T_b_i[:3, 3]
    p_c = R_b_c.T @ (p_b - T_b_c[:3, 3])
    np.testing.assert_allclose(T_cam_imu[:3, :3] @ p_i + T_cam_imu[:3, 3], p_c, atol=1e-12)
    np.testing.assert_allclose(T_b_c @ T_cam_imu, T_b_i, atol=1e-12)
    np.testing.assert_allclose(T_cam_imu[3], [0.0, 0.0, 0.0, 1.0])
    assert cam0["timeshift_cam_imu"] == 0.015  # t_imu = t_cam + shift: the IMU's clock ahead
    np.testing.assert_allclose(np.array(cam0["T_cam_body"]) @ T_b_c, np.eye(4), atol=1e-12)
    np.testing.assert_array_equal(cam0["vnav_sim"]["T_b_i"], T_b_i)
    assert cam0["vnav_sim"]["imu_extrinsics"] == "a test's"
    with pytest.raises(ValueError, match="T_b_i"):
        camchain_yaml(camera, T_b_c, 0.0, {}, ImuExtrinsics(2.0 * T_b_i, 0.0, "not rigid"))


def test_a_camchain_without_an_imu_has_no_imu_keys():
    """Without an IMU: no ``T_cam_imu`` nor ``timeshift_cam_imu`` (the body's keys stand in,
    and the header says so)."""
    text = camchain_yaml(PinholeCamera.from_fovy(50.0, 640, 480), np.eye(4), 0.0, {})
    cam0 = yaml.safe_load(text)["cam0"]
    assert "T_cam_imu" not in cam0 and "timeshift_cam_imu" not in cam0
    assert "T_cam_body" in cam0 and "# No IMU" in text


def test_calibrate_a_recording_with_an_imu_writes_T_cam_imu(tmp_path, capsys):
    """``vnav-demo calibrate --out`` on the ``calibration`` built-in flown with an IMU (no mount
    error, its clock 15 ms ahead): Kalibr's ``T_cam_imu`` is the recovered camera mount's
    inverse times the declared IMU mount (read back from the recording), so that the recovered
    ``T_b_c`` times it is the scenario's ``T_b_i``; ``timeshift_cam_imu`` is 0.0, said to be
    uncalibrated, as no camera-IMU calibration exists; the body's keys are kept."""
    spec = builtin.load("calibration")
    imu = ImuConfig(
        position_b=(0.04, -0.025, 0.015), rpy_deg=(0.0, 30.0, 90.0), time_offset_s=0.015
    )
    spec = dataclasses.replace(spec, scene=dataclasses.replace(spec.scene, imu=imu), duration_s=4.0)
    outcome = pipeline.run(spec, seed=1, out_dir=tmp_path)
    out = tmp_path / "calib.yaml"
    assert main(["calibrate", str(outcome.rrd_path), "--out", str(out)]) == 0
    capsys.readouterr()
    cam0 = yaml.safe_load(out.read_text())["cam0"]
    T_b_c = np.array(cam0["vnav_sim"]["T_b_c"])
    np.testing.assert_allclose(T_b_c @ np.array(cam0["T_cam_imu"]), imu.T_b_i, atol=1e-6)
    np.testing.assert_allclose(np.array(cam0["T_cam_body"]) @ T_b_c, np.eye(4), atol=1e-12)
    assert cam0["timeshift_cam_imu"] == 0.0
    assert cam0["timeshift_cam_body"] == cam0["vnav_sim"]["time_offset_s"]
    assert cam0["vnav_sim"]["imu_extrinsics"].startswith("declared")
    assert "not calibrated" in cam0["vnav_sim"]["imu_extrinsics"]


def test_calibrate_a_recording_without_an_imu_reads_no_mount(tmp_path):
    """A run without an ``[imu]``: the recording holds no IMU mount."""
    spec = dataclasses.replace(builtin.load("latency"), duration_s=0.2)
    outcome = pipeline.run(spec, seed=1, out_dir=tmp_path)
    assert imu_mount_declared(outcome.rrd_path) is None
    assert Path(outcome.rrd_path).is_file()
