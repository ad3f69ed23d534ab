"""A scenario's ``[imu]``: the keys, their checks and messages, and a run that reads the IMU.

The run flies a controlled flight with an IMU off the body origin, turned and mis-mounted;
its report holds the readings' count and how closely MuJoCo's noise-free sensors followed
``vnav.imu``'s chain at every physics step (the ``imu_consistent`` check); the readings are
stamped on the IMU's clock (Kalibr's ``t_imu = t_cam + timeshift_cam_imu``) and carry the
declared noise.
"""

from __future__ import annotations

import json
import math
import tomllib

import numpy as np
import pytest

from scenarios import pipeline
from scenarios.scenario import schema, toml_out
from scenarios.scenario.spec import ScenarioError, from_dict, load_toml
from sim.config import SceneConfig


def _scenario(imu: dict | None = None, **top) -> dict:
    data = {
        "name": "imu-flight",
        "camera_rate_hz": 2.0,
        "cones": [{"position_w": [6.0, 1.0, 0.0]}],
        "flight": {
            "mode": "controlled",
            "waypoints": [
                {"t": 0.0, "position_w": [0.0, 0.0, 3.0]},
                {"t": 2.0, "position_w": [1.0, 0.5, 3.5], "yaw_deg": 30.0},
                {"t": 4.0, "position_w": [0.0, 0.0, 3.0], "yaw_deg": -20.0},
            ],
        },
        **top,
    }
    if imu is not None:
        data["imu"] = imu
    return data


IMU = {
    "rate_hz": 100.0,
    "position_b": [0.05, -0.03, 0.02],
    "rpy_deg": [180.0, 0.0, 90.0],
    "mount_error": {"position_m": [0.004, 0.0, -0.002], "rpy_deg": [1.0, -0.5, 2.0]},
    "time_offset_s": 0.012,
    "accelerometer_noise_density": 2.0e-3,
    "accelerometer_random_walk": 3.0e-3,
    "gyroscope_noise_density": 1.6968e-4,
    "gyroscope_random_walk": 1.9393e-5,
}


def test_the_imu_table_becomes_the_scenes_imu():
    spec = from_dict(_scenario(IMU))
    imu = spec.scene.imu
    assert imu.rate_hz == 100.0 and imu.time_offset_s == 0.012
    assert imu.noise.gyroscope_random_walk == 1.9393e-5
    # The declared mount R_b_i = Rz(90) Rx(180): x_i = y_b, y_i = x_b, z_i = -z_b.
    np.testing.assert_allclose(
        imu.T_b_i_declared[:3, :3], [[0, 1, 0], [1, 0, 0], [0, 0, -1]], atol=1e-12
    )
    np.testing.assert_allclose(imu.T_b_i, imu.T_b_i_declared @ imu.mount_error.T)


def test_without_an_imu_table_the_scene_is_the_same_as_before():
    spec = from_dict(_scenario())
    assert spec.scene.imu is None
    assert spec.scene == SceneConfig(
        cones_w=((6.0, 1.0, 0.0),),
        start_position_w=(0.0, 0.0, 3.0),
        start_quat_xyzw=(0.0, 0.0, 0.0, 1.0),
    )


@pytest.mark.parametrize(
    ("imu", "message"),
    [
        ({"rate": 100.0}, "imu.rate: unknown key"),
        ({"rate_hz": 400.0}, "imu.rate_hz: must be at most the physics rate, 200 Hz"),
        ({"rate_hz": 0.0}, "imu.rate_hz: must be > 0"),
        ({"gyroscope_random_walk": -1e-5}, "imu.gyroscope_random_walk: must be >= 0"),
        ({"time_offset_s": 6.0}, "imu.time_offset_s: must be <= 5"),
        ({"position_b": [0.0, 0.0]}, "imu.position_b: must be a list of 3 numbers"),
        ({"mount_error": {"rpy_deg": [0.0, 50.0, 0.0]}}, "imu.mount_error.rpy_deg[1]: must be <="),
        ({"mount_error": {"xyz": [0.0, 0.0, 0.0]}}, "imu.mount_error.xyz: unknown key"),
        ([1, 2], "imu: must be a table"),
    ],
)
def test_bad_imu_keys_are_named(imu, message):
    with pytest.raises(ScenarioError, match=rf"^<scenario>: {_escaped(message)}"):
        from_dict(_scenario(imu))


def _escaped(text: str) -> str:
    return "".join("\\" + c if c in "[]().*+?" else c for c in text)


def test_a_kinematic_flight_cannot_carry_an_imu():
    data = _scenario({})
    data["flight"] = {
        "mode": "kinematic",
        "keyframes": [{"t": 0.0, "position_w": [0.0, 0.0, 3.0], "rpy_deg": [0.0, 0.0, 0.0]}],
    }
    with pytest.raises(ScenarioError, match="imu: needs a flight with dynamics"):
        from_dict(data)


def test_the_schema_documents_every_imu_key():
    for key in schema.IMU:
        assert schema.comment(f"imu.{key.name}") == key.doc
    for key in schema.IMU_MOUNT_ERROR:
        assert schema.comment(f"imu.mount_error.{key.name}") == key.doc
    assert "Hz" in schema.comment("imu.accelerometer_noise_density")


def test_a_scenario_with_an_imu_is_written_back_to_the_same_scenario(tmp_path):
    data = _scenario(IMU)
    text = toml_out.dumps(toml_out.complete(data), comments=True)
    assert "[imu.mount_error]" in text
    assert tomllib.loads(text)["imu"]["time_offset_s"] == 0.012
    path = tmp_path / "imu.toml"
    path.write_text(text)
    assert load_toml(path) == from_dict(data)


def test_a_run_reads_the_imu_and_checks_it_against_the_chain(tmp_path):
    data = _scenario(
        IMU,
        timing={"camera_clock_offset_s": 0.02},
        checks=[{"kind": "imu_consistent", "limit": 1e-6}],
    )
    spec = from_dict(data)
    out = pipeline.run(spec, seed=4, out_dir=tmp_path)
    report = json.loads(out.json_path.read_text())
    (check,) = report["checks"]
    assert check["kind"] == "imu_consistent" and check["passed"], check
    imu = report["imu"]
    assert imu["max_discrepancy"] < 1e-6
    # The check's value is the figure itself, not rounded away (it is about 1e-15).
    assert 0.0 < check["value"] == pytest.approx(imu["max_discrepancy"], rel=1e-8)
    # Every physics step of the 4 s flight (800 steps of 5 ms), as it is taken.
    assert imu["steps_checked"] == 800
    # 100 Hz over 4 s: readings 0 to 399 (the last state starts no step), stamped on the
    # IMU's clock: t_sim - 0.02 + 0.012.
    record = out.result.imu
    assert imu["readings"] == len(record.t_s) == 400
    np.testing.assert_allclose(record.t_s, np.arange(400) / 100.0 - 0.02 + 0.012, atol=1e-9)
    np.testing.assert_allclose(imu["T_b_i"], spec.scene.imu.T_b_i)
    # Mounted upside down (z_i = -z_b), the IMU reads the reaction to gravity on its -z in a
    # gentle flight, from the first reading on: it is taken as the first step is taken, under
    # the thrust that step applies (not free fall, the controls before any were set).
    assert record.accel_i[0, 2] < -9.0, record.accel_i[0]
    f_median = np.median(record.accel_i, axis=0)
    assert f_median[2] < -9.0 and np.all(np.abs(f_median[:2]) < 1.0), f_median


def sigma_a(imu: dict) -> float:
    """The accelerometer's white noise per reading, m/s^2 (Kalibr's density / sqrt(dt))."""
    return imu["accelerometer_noise_density"] * math.sqrt(imu["rate_hz"])
