"""``vnav-demo calibrate`` on recordings written by ``vnav-demo run``, and the built-in
``calibration`` scenario's in-run calibration, against the simulator's truth."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys

import numpy as np
import pytest
import yaml

from scenarios.cli import main
from scenarios.judge.calibration import inputs_from_run
from scenarios.record.reader import calibration_inputs
from vnav import so3


def _yaml_numbers(text: str) -> dict:
    """The mount and offset of the camchain ``calibrate`` writes, read by PyYAML (what Kalibr
    reads it with) from Kalibr's keys and the project's section."""
    cam0 = yaml.safe_load(text)["cam0"]
    ours = cam0["vnav_sim"]
    return {
        "T_cam_body": np.array(cam0["T_cam_body"]),
        "timeshift_cam_body": cam0["timeshift_cam_body"],
        "T_b_c": np.array(ours["T_b_c"]),
        "time_offset_s": ours["time_offset_s"],
        "reprojection_rms_px": ours["reprojection_rms_px"],
        "frames_used": ours["frames_used"],
    }


def test_calibrate_a_recording_recovers_the_true_mount_and_offset(
    builtin_runs, tmp_path, capsys, monkeypatch
):
    """The built-in ``calibration`` run's recording (mount 2.4 deg and 3 cm off, clock 30 ms
    off): the YAML's mount and offset against the scenario's truth, within what the detector's
    apexes allow (they sit about 0.25 px above the true apex: 0.1 deg, 1 cm, 1 ms). The output
    named as the README does, ``--out calib.yaml``: every printed line fits 80 columns (a long
    temporary path would not, whatever the command prints)."""
    run = builtin_runs["calibration"]
    monkeypatch.chdir(tmp_path)
    assert main(["calibrate", str(run.rrd), "--out", "calib.yaml"]) == 0
    printed = capsys.readouterr().out
    assert "against the truth" in printed and "wrote calib.yaml" in printed
    assert all(len(line) <= 80 for line in printed.splitlines())
    out = tmp_path / "calib.yaml"
    got = _yaml_numbers(out.read_text())
    cam = run.spec.scene.camera
    true_mount = cam.T_b_c_declared @ cam.mount_error.T
    # Kalibr's T_cam_body is the inverse of the project's T_b_c, its shift the same offset.
    np.testing.assert_allclose(got["T_cam_body"] @ got["T_b_c"], np.eye(4), atol=1e-12)
    assert got["timeshift_cam_body"] == got["time_offset_s"]
    R_err = got["T_b_c"][:3, :3].T @ true_mount[:3, :3]
    assert math.degrees(np.linalg.norm(so3.log(R_err))) < 0.1
    assert np.linalg.norm(got["T_b_c"][:3, 3] - true_mount[:3, 3]) < 0.01
    assert got["time_offset_s"] == pytest.approx(run.spec.timing.camera_clock_offset_s, abs=1e-3)
    assert got["frames_used"] > 0.8 * len(run.result.ticks)
    assert 0.0 < got["reprojection_rms_px"] < 1.0
    assert [p.name for p in tmp_path.iterdir()] == ["calib.yaml"]  # no partial file left


def test_recording_inputs_are_the_runs(builtin_runs):
    """What ``inputs_from_recording`` reads back equals what the run held: the pose stream
    (float32 in the file), the camera stamps, the camera's intrinsics, the map, the declared
    mount and the truth."""
    run = builtin_runs["calibration"]
    cam = run.spec.scene.camera
    from vnav.camera import PinholeCamera

    camera = PinholeCamera.from_fovy(cam.fovy_deg, cam.width, cam.height)
    mine = inputs_from_run(run.result, camera)
    read = calibration_inputs(run.rrd)
    np.testing.assert_allclose(read.pose_stamps_s, mine.pose_stamps_s, atol=1e-9)
    np.testing.assert_allclose(read.T_w_b, mine.T_w_b, atol=1e-5)
    np.testing.assert_allclose(read.image_stamps_cam_s, mine.image_stamps_cam_s, atol=1e-12)
    assert read.camera.fx == pytest.approx(camera.fx, rel=1e-6)
    assert (read.camera.cx, read.camera.cy) == pytest.approx((camera.cx, camera.cy), abs=1e-4)
    np.testing.assert_allclose(read.apex_w, mine.apex_w, atol=1e-6)
    np.testing.assert_allclose(read.T_b_c_declared, mine.T_b_c_declared, atol=1e-6)
    np.testing.assert_allclose(read.truth.T_b_c, mine.truth.T_b_c, atol=1e-6)
    assert read.truth.time_offset_s == mine.truth.time_offset_s
    # The recording holds every detection's apex, the run's inputs those clear of the border.
    assert sum(len(a) for a in read.apex_uv) >= sum(len(a) for a in mine.apex_uv)


def test_in_run_calibration_meets_the_scenario_targets(builtin_runs):
    """The built-in's own checks (0.05 deg, 5 mm, 1 ms) passed, and the report's errors are
    the recovered mount's against the truth."""
    run = builtin_runs["calibration"]
    assert all(c.passed for c in run.judged), [c.shown for c in run.judged]
    c = run.result.calibration
    cam = run.spec.scene.camera
    true_mount = cam.T_b_c_declared @ cam.mount_error.T
    angle = math.degrees(np.linalg.norm(so3.log(c.T_b_c[:3, :3].T @ true_mount[:3, :3])))
    assert c.errors["rotation_deg"] == pytest.approx(angle, abs=1e-9)
    assert run.report["calibration"]["errors"]["rotation_deg"] == pytest.approx(angle, abs=1e-8)


def test_calibrate_refuses_what_it_cannot_use(builtin_runs, tmp_path, capsys):
    """One line and exit 2, nothing written: no file, not a recording, a flight with one cone
    (the ``approach``), an output directory that does not exist."""
    out = tmp_path / "calib.yaml"
    cases = [
        ([str(tmp_path / "none.rrd"), "--out", str(out)], "no such file"),
        (
            [str(builtin_runs["approach"].json_path), "--out", str(out)],
            "not a readable Rerun recording",
        ),
        ([str(builtin_runs["approach"].rrd), "--out", str(out)], "too few|does not determine"),
        ([str(builtin_runs["calibration"].rrd), "--out", str(tmp_path / "no" / "c.yaml")], "no"),
    ]
    for argv, message in cases:
        assert main(["calibrate", *argv]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and re.search(message, err), err
    assert not out.exists()


def test_calibration_with_image_noise_stays_within_the_noisy_targets():
    """The built-in with 8 levels of image noise (the most under which the detector's
    keypoints stay calibrated, ``vnav.sensor_noise``) at 5 Hz: the errors are reported and
    stay within the targets set for a noisy flight, 0.2 deg, 2 cm and 3 ms."""
    import dataclasses

    from scenarios import pipeline
    from scenarios.scenario import builtin

    spec = builtin.load("calibration")
    spec = dataclasses.replace(
        spec,
        camera_rate_hz=5.0,
        noise=dataclasses.replace(spec.noise, intensity_std_grey=8.0),
    )
    outcome = pipeline.run(spec, seed=2)
    errors = outcome.report["calibration"]["errors"]
    assert errors["rotation_deg"] < 0.2
    assert errors["translation_m"] < 0.02
    assert errors["time_offset_s"] < 0.003


@pytest.mark.parametrize(("duration_s", "ticks"), [("0.001", 1), ("0.5", 11)])
def test_a_flight_too_short_to_calibrate_is_no_data_with_its_reason(
    tmp_path, capsys, duration_s, ticks
):
    """The built-in cut to one camera tick (one pose sample) or to half a second (the clock
    offset's search left the 0.5 s pose stream): the calibration checks have no data and say
    why, the run is not an internal error (exit 1: a check did not pass), and ``calibrate`` on
    its recording refuses it in one line."""
    out = tmp_path / "out"
    status = main(["run", "calibration", "--duration", duration_s, "--out", str(out), "--quiet"])
    assert status == 1, capsys.readouterr().err
    assert "internal error" not in capsys.readouterr().err
    report = json.loads((out / "calibration.json").read_text())
    assert report["camera_ticks"] == ticks
    judged = [c for c in report["checks"] if c["kind"].startswith("calibration_")]
    assert len(judged) == 3
    for check in judged:
        assert check["outcome"] == "no data"
        assert check["reason"].startswith("calibration refused: the flight ")
    assert main(["calibrate", str(out / "calibration.rrd")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "cannot calibrate: the flight " in err, err


def test_a_truncated_recording_is_refused_in_one_line(tmp_path):
    """A recording cut short (no footer: Rerun warns on two lines before reading it) through
    the real command line: exit 2 and one line on stderr."""
    out = tmp_path / "out"
    assert main(["run", "frame-problem", "--duration", "0.2", "--out", str(out), "--quiet"]) in (
        0,
        1,
    )
    whole = (out / "frame-problem.rrd").read_bytes()
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(whole[: len(whole) // 2])
    proc = subprocess.run(
        [sys.executable, "-m", "scenarios", "calibrate", str(cut)],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONWARNINGS": "default"},
    )
    assert proc.returncode == 2, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert "not a readable Rerun recording" in proc.stderr
