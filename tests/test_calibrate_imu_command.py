"""``vnav-demo calibrate FILE.rrd --imu``: the camera calibrated against the IMU from a
recording (``scenarios.record.reader.imu_calibration_inputs``, the two passes of
``ImuCalibrationInputs.solve``), against the simulator's truth on mounts the calibration was
not tuned on, against the run's own calibration of the same flight, written as Kalibr's
camchain (ethz-asl/kalibr wiki, "Yaml formats": ``T_cam_imu`` takes IMU coordinates into the
camera's, ``t_imu = t_cam + timeshift_cam_imu``) and read back by PyYAML; and what it refuses.
"""

from __future__ import annotations

import contextlib
import io
import math
import re

import numpy as np
import pytest
import yaml

from benchmarks.calibrate import imu_held_out
from scenarios import pipeline
from scenarios.cli import main
from scenarios.record.reader import imu_calibration_inputs
from scenarios.scenario.spec import ScenarioSpec, from_dict
from vnav import se3, so3

SEEDS = (1, 2)


def _held_out(seed: int, checks: bool) -> ScenarioSpec:
    """``benchmarks.calibrate.imu_held_out``: the ``imu`` built-in's flight, noise-free, with
    mounts and a clock the calibration was not tuned on, drawn from ``seed``: the camera's
    mount error within +-2 deg about each axis and +-3 cm along each, the IMU's within +-2 deg
    and +-1 cm, the IMU's clock within +-40 ms of the camera's. With ``checks`` the run
    calibrates itself too (``calibration_imu_*``); without, it has none."""
    data = imu_held_out(seed)
    if not checks:
        data["checks"] = []
    return from_dict(data)


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    """Each held-out flight run once, its recording written, then ``calibrate --imu --out``
    on it: ``{seed: (spec, outcome, exit status, what it printed, the YAML file)}``. Only the
    first flight's run calibrates itself too (its checks), for the comparison with the
    recording's."""
    out = tmp_path_factory.mktemp("imu-flights")
    runs = {}
    for seed in SEEDS:
        spec = _held_out(seed, checks=seed == SEEDS[0])
        outcome = pipeline.run(spec, seed=seed, out_dir=out)
        yaml_path = out / f"calib-{seed}.yaml"
        printed = io.StringIO()
        with contextlib.redirect_stdout(printed):
            status = main(["calibrate", str(outcome.rrd_path), "--imu", "--out", str(yaml_path)])
        runs[seed] = (spec, outcome, status, printed.getvalue(), yaml_path)
    return runs


def _truth(spec: ScenarioSpec) -> tuple[np.ndarray, float]:
    """``T_i_c`` of the true mounts (each the declared one times its error) and the IMU's
    clock offset, from the scenario alone."""
    cam, imu = spec.scene.camera, spec.scene.imu
    T_b_c = cam.T_b_c_declared @ cam.mount_error.T
    T_b_i = imu.T_b_i_declared @ imu.mount_error.T
    return se3.invert(T_b_i) @ T_b_c, imu.time_offset_s


def _angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    # Printed to 5 decimals: projected back onto SO(3) before the angle is taken.
    return math.degrees(float(np.linalg.norm(so3.log(so3.nearest_rotation(R_a).T @ R_b))))


def _printed(text: str) -> tuple[np.ndarray, float]:
    """``T_i_c`` and the offset (s) as ``calibrate --imu`` prints them."""
    lines = text.splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith("camera in the IMU frame"))
    T_i_c = np.array([[float(v) for v in line.split()] for line in lines[at + 1 : at + 5]])
    offset_ms = re.search(r"t_imu = t_cam ([+-]) ([0-9.]+) ms", text)
    assert offset_ms is not None, text
    sign = -1.0 if offset_ms.group(1) == "-" else 1.0
    return T_i_c, sign * 1e-3 * float(offset_ms.group(2))


def _answers(flights, seed: int) -> tuple[ScenarioSpec, list[tuple[np.ndarray, float]]]:
    """The scenario and ``calibrate --imu``'s ``T_i_c`` and offset as printed and as written
    (``T_cam_imu`` inverted, ``timeshift_cam_imu``)."""
    spec, _, status, printed, yaml_path = flights[seed]
    assert status == 0
    assert "against the truth" in printed
    cam0 = yaml.safe_load(yaml_path.read_text())["cam0"]
    written = (se3.invert(np.array(cam0["T_cam_imu"])), cam0["timeshift_cam_imu"])
    return spec, [_printed(printed), written]


@pytest.mark.parametrize("seed", SEEDS)
def test_calibrate_imu_recovers_held_out_rotation_and_clock(flights, seed):
    """Both mounts off their declared poses by up to 2 deg and 3 cm, the IMU's clock up to
    40 ms off: ``R_i_c`` within 0.1 deg of the truth and the offset within 1 ms, as printed
    and as written; the declared mounts would be further off than that."""
    spec, answers = _answers(flights, seed)
    T_i_c_true, offset_true_s = _truth(spec)
    for T_i_c, offset_s in answers:
        assert _angle_deg(T_i_c[:3, :3], T_i_c_true[:3, :3]) < 0.1
        assert abs(offset_s - offset_true_s) < 0.001
    # Not the declared mounts' answer: those are off by more than the targets.
    cam, imu = spec.scene.camera, spec.scene.imu
    T_i_c_declared = se3.invert(imu.T_b_i_declared) @ cam.T_b_c_declared
    assert _angle_deg(T_i_c_declared[:3, :3], T_i_c_true[:3, :3]) > 0.3
    assert np.linalg.norm(T_i_c_declared[:3, 3] - T_i_c_true[:3, 3]) > 0.015


@pytest.mark.parametrize("seed", SEEDS)
def test_calibrate_imu_recovers_held_out_translation(flights, seed):
    """The same flights: ``t_i_c`` within 5 mm of the truth, as printed and as written."""
    spec, answers = _answers(flights, seed)
    T_i_c_true, _ = _truth(spec)
    for T_i_c, _ in answers:
        assert np.linalg.norm(T_i_c[:3, 3] - T_i_c_true[:3, 3]) < 0.005


def test_the_recording_gives_the_runs_own_answer(flights):
    """The inputs read back are the run's (stamps to the nanosecond Rerun keeps, every blob
    made a detection again exactly), and the command's two passes on them give the run's own
    calibration (``calibrate_imu_run``) to 1e-5 deg, 1 um and 1 ns: the intrinsics and the
    stamps come back in single precision and whole nanoseconds, not bit for bit (measured:
    1.3e-7 in ``T_i_c``'s entries, 3e-10 s)."""
    spec, outcome = flights[SEEDS[0]][:2]
    in_run = outcome.result.imu_calibration
    assert in_run.refused is None
    inputs = imu_calibration_inputs(outcome.rrd_path)
    record = outcome.result.imu
    np.testing.assert_allclose(inputs.imu_stamps_s, record.t_s, rtol=0.0, atol=1e-9)
    np.testing.assert_array_equal(inputs.gyro_i, record.gyro_i)
    np.testing.assert_array_equal(inputs.accel_i, record.accel_i)
    stamps = [t.timing.stamp_cam_s for t in outcome.result.ticks]
    np.testing.assert_array_equal(inputs.image_stamps_cam_s, stamps)
    found = [
        [d.detection for d in t.detections if not d.detection.touches_border]
        for t in outcome.result.ticks
    ]
    assert [len(d) for d in inputs.detections] == [len(d) for d in found]
    for got, had in zip(inputs.apex_uv, found, strict=True):
        np.testing.assert_array_equal(got, np.array([d.apex_uv for d in had]).reshape(-1, 2))
    T_i_c_true, offset_true_s = _truth(spec)
    np.testing.assert_allclose(inputs.T_i_c_true, T_i_c_true, atol=1e-6)
    assert inputs.time_offset_true_s == offset_true_s
    # The command's answer, written in full (repr) under cam0.vnav_sim.
    ours = yaml.safe_load(flights[SEEDS[0]][4].read_text())["cam0"]["vnav_sim"]
    T_i_c = np.array(ours["T_i_c"])
    assert _angle_deg(T_i_c[:3, :3], in_run.T_i_c[:3, :3]) < 1e-5
    assert np.linalg.norm(T_i_c[:3, 3] - in_run.T_i_c[:3, 3]) < 1e-6
    assert abs(ours["time_offset_s"] - in_run.time_offset_s) < 1e-9
    assert ours["frames_used"] == in_run.frames_used


def test_the_camchain_holds_the_calibrated_T_cam_imu(flights):
    """Kalibr's camchain read back by PyYAML: one camera, its ``T_cam_imu`` the inverse of the
    printed ``T_i_c`` (to the 5 decimals printed) and of ``cam0.vnav_sim.T_i_c`` (to the last
    bits), ``timeshift_cam_imu`` the printed offset, the file saying they were calibrated; no
    ``T_cam_body`` (the body is not calibrated here); every printed line within 80 columns."""
    _, _, status, printed, yaml_path = flights[SEEDS[0]]
    assert status == 0
    assert all(len(line) <= 80 for line in printed.splitlines())
    assert f"wrote {yaml_path}" in printed
    chain = yaml.safe_load(yaml_path.read_text())
    assert list(chain) == ["cam0"]
    cam0 = chain["cam0"]
    T_cam_imu = np.array(cam0["T_cam_imu"])
    T_i_c, offset_s = _printed(printed)
    np.testing.assert_allclose(T_cam_imu @ T_i_c, np.eye(4), atol=2e-5)
    T_i_c_written = np.array(cam0["vnav_sim"]["T_i_c"])
    np.testing.assert_allclose(T_cam_imu @ T_i_c_written, np.eye(4), atol=1e-12)
    assert type(cam0["timeshift_cam_imu"]) is float
    assert cam0["timeshift_cam_imu"] == cam0["vnav_sim"]["time_offset_s"]
    assert cam0["timeshift_cam_imu"] == pytest.approx(offset_s, abs=5e-7)
    assert cam0["vnav_sim"]["imu_extrinsics"].startswith("calibrated")
    assert "T_cam_body" not in cam0 and "timeshift_cam_body" not in cam0
    assert sorted(p.name for p in yaml_path.parent.glob("calib-*")) == [
        f"calib-{seed}.yaml" for seed in SEEDS
    ]  # no partial file left


@pytest.fixture(scope="module")
def short_recordings(tmp_path_factory):
    """Two cheap recordings: the held-out flight cut to 1 s (too few images to calibrate) and
    the same without its IMU."""
    out = tmp_path_factory.mktemp("imu-short")
    data = {**imu_held_out(1), "duration_s": 1.0, "checks": []}
    with_imu = pipeline.run(from_dict({**data, "name": "short"}), seed=1, out_dir=out)
    no_imu = {k: v for k, v in data.items() if k != "imu"}
    without = pipeline.run(from_dict({**no_imu, "name": "no-imu"}), seed=1, out_dir=out)
    return with_imu.rrd_path, without.rrd_path


def test_calibrate_imu_refuses_what_it_cannot_use(short_recordings, tmp_path, capsys):
    """One line on stderr, no traceback, exit 2, nothing written: no such file, a file that is
    not a recording, a recording of a run without an IMU, a flight too short to determine the
    calibration, an output directory that does not exist."""
    short, no_imu = short_recordings
    text = tmp_path / "notes.rrd"
    text.write_text("not a recording\n")
    out = tmp_path / "calib.yaml"
    imu_out = ["--imu", "--out", str(out)]
    cases = [
        ([str(tmp_path / "none.rrd"), *imu_out], "no such file"),
        ([str(text), *imu_out], "not a readable Rerun recording"),
        (
            [str(no_imu), *imu_out],
            r"the recording has no IMU readings: run a scenario with \[imu\]",
        ),
        ([str(short), *imu_out], "too few images"),
        ([str(short), "--imu", "--out", str(tmp_path / "no" / "c.yaml")], "no such directory"),
    ]
    for argv, message in cases:
        assert main(["calibrate", *argv]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and re.search(message, err), err
        assert "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.rrd"]


def test_the_imu_builtin_recording(builtin_runs, capsys):
    """The ``imu`` built-in's recording (four cones): ``calibrate --imu`` answers, with its
    errors against the truth the recording holds, within the built-in's own gates."""
    run = builtin_runs["imu"]
    status = main(["calibrate", str(run.rrd), "--imu"])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    errors = re.search(
        r"against the truth: rotation ([0-9.]+) deg, translation ([0-9.]+) mm, offset "
        r"([0-9.]+) ms",
        captured.out,
    )
    assert errors is not None, captured.out
    rotation_deg, translation_mm, offset_ms = (float(v) for v in errors.groups())
    assert rotation_deg < 0.1 and translation_mm < 5.0 and offset_ms < 1.0, captured.out
