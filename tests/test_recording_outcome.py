"""What a finished recording holds of the judged run, read back from the ``.rrd``: the checks'
verdicts, and in the calibration built-in the declared, true and recovered camera mounts, held
against the JSON report and the simulator's truth (MuJoCo's own camera pose); and the order in
which ``scenarios.pipeline.run`` runs, judges and finishes the recording."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import time

import numpy as np
import pytest
from helpers import mujoco_T_w_c, read_rows

from scenarios import pipeline
from scenarios.judge import checks, report
from scenarios.record.outputs import OutputPair
from scenarios.record.recording import Recording
from scenarios.record.viewer import FRAME, entity
from scenarios.run.runner import STAGES
from scenarios.scenario import builtin
from sim.world import World
from vnav import metrics, quat, se3, so3
from vnav.camera import PinholeCamera
from vnav.cone import TRAFFIC_CONE
from vnav.methods import METHOD_NAMES, method

FLOAT32_ATOL = 1e-6
"""Rerun stores translations and quaternions as float32: ~1e-7 relative, metres below 1."""


def _static_transform(rrd, path: str) -> tuple[np.ndarray, dict]:
    """The one static Transform3D logged at ``path``: (4, 4) and its row."""
    rows = [r for r in read_rows(rrd, path) if r.get("Transform3D:translation")]
    assert len(rows) == 1 and "tick" not in rows[0], f"{path}: one static transform expected"
    row = rows[0]
    R = quat.to_matrix(np.asarray(row["Transform3D:quaternion"][0]), normalize=True)
    return se3.make(R, row["Transform3D:translation"][0]), row


def _mujoco_T_b_c(spec) -> np.ndarray:
    """Independent truth: the camera mount MuJoCo renders through (``cam_xpos`` / ``cam_xmat``
    in the optical frame), in the body frame, at an arbitrary pose."""
    world = World.from_config(spec.scene)
    world.set_pose(se3.make(so3.from_rpy(0.2, -0.1, 0.7), [1.0, -2.0, 4.0]))
    return se3.invert(world.T_w_b) @ mujoco_T_w_c(world)


def _angle_deg(T_a: np.ndarray, T_b: np.ndarray) -> float:
    return math.degrees(float(np.linalg.norm(so3.log(T_a[:3, :3].T @ T_b[:3, :3]))))


def _limit(spec, kind: str) -> float:
    return next(c.limit for c in spec.checks if c.kind == kind)


def test_recovered_mount_is_the_reports_and_within_the_checks_of_the_truth(builtin_runs):
    """The calibration built-in's recording draws the recovered mount as a named frame on the
    body: it is the JSON report's ``calibration.T_b_c`` and lies within the scenario's checks
    (0.05 deg, 5 mm) of MuJoCo's camera; the declared mount beside it is the scenario's, the
    one the estimator was told at every tick, and is off MuJoCo's by the scenario's mount
    error. (Before the recording was finished after judging, neither frame existed.)"""
    run = builtin_runs["calibration"]
    spec = run.spec
    rep = json.loads(run.json_path.read_text())
    T_b_c_true = _mujoco_T_b_c(spec)

    T_b_c_recovered, row = _static_transform(run.rrd, entity.CAMERA_RECOVERED)
    assert row["Transform3D:parent_frame"] == [FRAME.BODY]
    assert row["Transform3D:child_frame"] == [FRAME.CAMERA_RECOVERED]
    T_b_c_reported = np.array(rep["calibration"]["T_b_c"])
    assert np.allclose(T_b_c_recovered[:3, 3], T_b_c_reported[:3, 3], atol=FLOAT32_ATOL)
    assert np.allclose(T_b_c_recovered[:3, :3], T_b_c_reported[:3, :3], atol=FLOAT32_ATOL)
    assert _angle_deg(T_b_c_recovered, T_b_c_true) < _limit(spec, "calibration_rotation")
    translation_m = np.linalg.norm(T_b_c_recovered[:3, 3] - T_b_c_true[:3, 3])
    assert translation_m < _limit(spec, "calibration_translation")

    T_b_c_declared, row = _static_transform(run.rrd, entity.CAMERA_DECLARED)
    assert row["Transform3D:parent_frame"] == [FRAME.BODY]
    assert row["Transform3D:child_frame"] == [FRAME.CAMERA_DECLARED]
    assert np.allclose(T_b_c_declared, spec.scene.camera.T_b_c_declared, atol=FLOAT32_ATOL)
    told = [r for r in read_rows(run.rrd, entity.MOUNT_DECLARED) if "tick" in r]
    assert len(told) == len(run.result.ticks)
    for r in told:
        assert np.allclose(r["Transform3D:translation"][0], T_b_c_declared[:3, 3], atol=1e-6)
    # T_b_c_true = T_b_c_declared @ E: the declared mount is off by E's rotation and E's
    # translation (rotated into the body, which keeps its length).
    E = spec.scene.camera.mount_error.T
    assert _angle_deg(T_b_c_declared, T_b_c_true) == pytest.approx(
        math.degrees(np.linalg.norm(so3.log(E[:3, :3]))), abs=1e-4
    )
    assert np.linalg.norm(T_b_c_declared[:3, 3] - T_b_c_true[:3, 3]) == pytest.approx(
        np.linalg.norm(E[:3, 3]), abs=1e-6
    )

    # Each is drawn as its own axes, in its own frame, labelled once.
    for path, frame, label in (
        (entity.CAMERA_DECLARED_AXES, FRAME.CAMERA_DECLARED, "declared"),
        (entity.CAMERA_RECOVERED_AXES, FRAME.CAMERA_RECOVERED, "recovered"),
    ):
        rows = read_rows(run.rrd, path)
        assert any(r.get("CoordinateFrame:frame") == [frame] for r in rows)
        arrows = next(r for r in rows if r.get("Arrows3D:vectors"))
        vectors = np.array(arrows["Arrows3D:vectors"])
        assert np.allclose(vectors / np.linalg.norm(vectors, axis=1)[:, None], np.eye(3))
        assert [x for x in arrows["Arrows3D:labels"] if x] == [label]


def test_no_mounts_drawn_where_nothing_is_calibrated(builtin_runs):
    """Only a run whose checks ask for calibration has the declared and recovered frames."""
    for name, run in builtin_runs.items():
        has = bool(read_rows(run.rrd, entity.CAMERA_RECOVERED))
        assert has == run.spec.checks_calibration, name


_NUMBER = r"-?\d+\.\d+"


def _mounts_block(text: str) -> list[str]:
    """The panel's mounts block: from its titles to its clock lines."""
    lines = text.split("```")[1].strip("\n").splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("T_b_c declared"))
    return lines[start : start + 8]


def test_state_panel_shows_the_three_mounts_and_their_errors(builtin_runs):
    """At every tick of the calibration built-in the state panel shows the declared, true and
    recovered ``T_b_c`` side by side (rotation to 3 decimals, translation to the millimetre):
    the scenario's declared mount, MuJoCo's and the report's; under each its error against the
    true one (the declared one's that of the scenario's mount error, the recovered one's the
    report's) and the clock offset, true and recovered."""
    run = builtin_runs["calibration"]
    spec = run.spec
    rep = json.loads(run.json_path.read_text())
    panels = [r for r in read_rows(run.rrd, entity.STATE) if "tick" in r]
    assert sorted(r["tick"] for r in panels) == [t.tick for t in run.result.ticks]  # once each

    expected = [
        spec.scene.camera.T_b_c_declared,
        _mujoco_T_b_c(spec),
        np.array(rep["calibration"]["T_b_c"]),
    ]
    E = spec.scene.camera.mount_error.T
    errors = rep["calibration"]["errors"]
    blocks = {"\n".join(_mounts_block(r["TextDocument:text"][0])) for r in panels}
    assert len(blocks) == 1  # calibration is of the whole flight: the same at every tick
    block = blocks.pop().splitlines()
    assert block[0].split("   ")[0].strip() == "T_b_c declared (told)"
    numbers = np.array([[float(x) for x in re.findall(_NUMBER, line)] for line in block[1:5]])
    assert numbers.shape == (4, 12)
    for k, T in enumerate(expected):
        shown = numbers[:, 4 * k : 4 * k + 4]
        assert np.allclose(shown[:, :3], T[:, :3], atol=5e-4 + 1e-9)  # 3 decimals
        assert np.allclose(shown[:, 3], T[:, 3], atol=5e-4 + 1e-9)  # millimetres
    shown_errors = [
        (float(deg), float(mm))
        for deg, mm in re.findall(rf"error ({_NUMBER}) deg, ({_NUMBER}) mm", block[5])
    ]
    assert len(shown_errors) == 2 and "(the reference)" in block[5]
    (declared_deg, declared_mm), (recovered_deg, recovered_mm) = shown_errors
    # 4 decimals of a degree, 2 of a millimetre.
    assert declared_deg == pytest.approx(
        math.degrees(np.linalg.norm(so3.log(E[:3, :3]))), abs=5e-5 + 1e-9
    )
    assert declared_mm == pytest.approx(1e3 * np.linalg.norm(E[:3, 3]), abs=5e-3 + 1e-9)
    assert recovered_deg == pytest.approx(errors["rotation_deg"], abs=5e-5 + 1e-9)
    assert recovered_mm == pytest.approx(1e3 * errors["translation_m"], abs=5e-3 + 1e-9)
    true_ms, recovered_ms = (float(x) for x in re.findall(rf"\+ ({_NUMBER}) ms", block[6]))
    assert true_ms == pytest.approx(1e3 * spec.timing.camera_clock_offset_s, abs=5e-4)
    assert recovered_ms == pytest.approx(1e3 * rep["calibration"]["time_offset_s"], abs=5e-4)
    assert f"over {rep['calibration']['frames_used']} images" in block[7]


# ------------------------------------------------ the estimates before and after calibration


def _overlaps_another_cone(d, cone_index: int, cones_w, camera, T_c_w) -> bool:
    """Whether another cone's silhouette (the box of its extreme points, ``vnav.cone``,
    projected through the true camera) meets the detection's box: two cones one behind the
    other make one blob, outside what the accuracy contract promises (a cone seen alone)."""
    x0, y0, w, h = d.detection.bbox
    for j, other_w in enumerate(cones_w):
        if j == cone_index:
            continue
        uv = camera.project(se3.apply(T_c_w, TRAFFIC_CONE.extreme_points(other_w)))
        if np.isnan(uv).any():
            continue
        (u0, v0), (u1, v1) = uv.min(axis=0), uv.max(axis=0)
        if u0 <= x0 + w and u1 >= x0 and v0 <= y0 + h and v1 >= y0:
            return True
    return False


def _checked_errors(ticks, cones_w: np.ndarray, T_b_c_true: np.ndarray, camera, name: str):
    """``name``'s errors over the matched detections inside the contract's domain and clear
    of every other cone in the image, against ``cones_w``, and the contract's bound at each
    one's range from the true camera."""
    bound = method(name).bound
    errors, allowed = [], []
    for t in ticks:
        T_c_w = se3.invert(t.T_w_b @ T_b_c_true)
        for d in t.detections:
            if not (d.in_contract and name in d.estimates_w):
                continue
            if _overlaps_another_cone(d, d.cone_index, cones_w, camera, T_c_w):
                continue
            cone_w = cones_w[d.cone_index]
            errors.append(float(np.linalg.norm(d.estimates_w[name] - cone_w)))
            range_m = float(np.linalg.norm(se3.apply(T_c_w, cone_w)))
            allowed.append(float(bound.allowed_m(np.array([range_m]))[0]))
    return np.array(errors), np.array(allowed)


def test_the_recovered_mount_brings_depth_image_within_its_contract(builtin_runs):
    """The calibration built-in's declared mount is off by the scenario's mount error, which
    puts its depth_image estimates decimetres off, beyond the accuracy contract
    (``vnav.methods``): the mount's error, not the method's. The same images estimated again
    with the recovered mount (a new ``vnav.localize.Localizer``) are all within the contract,
    measured against MuJoCo's cones and camera (where no other cone shares the detection's
    box: two cones one behind the other are one blob, which the contract does not cover)."""
    run = builtin_runs["calibration"]
    world = World.from_config(run.spec.scene)
    cones_w, camera = world.cones_w, world.camera
    T_b_c_true = _mujoco_T_b_c(run.spec)
    before, allowed_before = _checked_errors(
        run.result.ticks, cones_w, T_b_c_true, camera, "depth_image"
    )
    assert np.mean(before > allowed_before) > 0.5 and np.mean(before) > 0.1
    recovered = run.result.with_recovered_mount()
    assert recovered is not None
    T_b_c_recovered = np.array(run.report["calibration"]["T_b_c"])
    assert all(np.allclose(t.T_b_c_est, T_b_c_recovered, atol=1e-8) for t in recovered.ticks)
    after, allowed_after = _checked_errors(
        recovered.ticks, cones_w, T_b_c_true, camera, "depth_image"
    )
    assert after.size == before.size > 100
    assert np.all(after <= allowed_after), float(np.max(after - allowed_after))


def test_estimating_again_with_the_declared_mount_gives_the_runs_estimates(builtin_runs):
    """The second estimate reuses the run's evaluation, not a copy of it: with the declared
    mount in place of the recovered one it gives every estimate of the run, bit for bit
    (same detections, depth under their masks, poses and covariances, a new Localizer), and
    their errors; not their NEES nor the single-image covariances, which nothing reads
    (the tracker's covariance, by which it refuses an estimate, the run's)."""
    from scenarios.judge.calibration import estimate_with_mount

    result = builtin_runs["calibration"].result
    cam = result.spec.scene.camera
    camera = PinholeCamera.from_fovy(cam.fovy_deg, cam.width, cam.height)
    again = estimate_with_mount(result, camera, result.ticks[0].T_b_c_est)
    assert len(again) == len(result.ticks)
    several = {name for name in METHOD_NAMES if method(name).needs_several_images}
    for a, b in zip(result.ticks, again, strict=True):
        for name in METHOD_NAMES:
            assert np.array_equal(a.estimates_w(name), b.estimates_w(name)), (a.tick, name)
        assert [d.errors_m for d in a.detections] == [d.errors_m for d in b.detections]
        for da, db in zip(a.detections, b.detections, strict=True):
            # Scored only where every estimate has its covariance: the tracker's alone.
            if not set(db.estimates_w) <= several:
                assert db.nees == {}
            assert set(db.covariances_w) == set(da.covariances_w) & several
            for name, cov_w in db.covariances_w.items():
                assert np.array_equal(cov_w, da.covariances_w[name])


def test_report_gives_each_methods_errors_with_both_mounts(builtin_runs):
    """``calibration.position_error_m``: with the declared mount, the run's own statistics;
    with the recovered one, those of the second estimate, recomputed here from its estimates
    and MuJoCo's cones (evo's statistics, ``vnav.metrics``)."""
    run = builtin_runs["calibration"]
    rep = json.loads(run.json_path.read_text())
    assert rep["report_version"] == report.REPORT_VERSION == 8
    by_mount = rep["calibration"]["position_error_m"]
    cones_w = World.from_config(run.spec.scene).cones_w
    recovered = run.result.with_recovered_mount()
    for name in METHOD_NAMES:
        assert by_mount["declared_mount"][name] == rep["methods"][name]["position_error_m"]
        errors = [
            float(np.linalg.norm(d.estimates_w[name] - cones_w[d.cone_index]))
            for t in recovered.ticks
            for d in t.detections
            if d.cone_index is not None and name in d.estimates_w
        ]
        stats = by_mount["recovered_mount"][name]
        expected = metrics.error_stats(np.array(errors))
        assert stats["count"] == len(errors) > 0
        for key in ("rmse", "mean", "median", "max"):
            assert stats[key] == pytest.approx(expected[key], abs=1e-8), (name, key)
    declared, after = by_mount["declared_mount"], by_mount["recovered_mount"]
    assert after["depth_image"]["mean"] < declared["depth_image"]["mean"] / 10
    for name, other in builtin_runs.items():
        if not other.spec.checks_calibration:
            assert other.report["calibration"] is None, name


def test_recording_shows_the_errors_with_the_recovered_mount(builtin_runs):
    """Each error plot of the calibration built-in's recording has a second curve, the mean
    error per tick with the recovered mount; the scenario document says what the mount error
    (its angle against MuJoCo's camera) does to the estimates, and gives each checked
    method's mean error with each mount, as the report does."""
    run = builtin_runs["calibration"]
    recovered = run.result.with_recovered_mount()
    rows = [r for r in read_rows(run.rrd, entity.error_recovered("depth_image")) if "tick" in r]
    plotted = {r["tick"]: r["Scalars:scalars"][0] for r in rows}
    expected = {t.tick: t.mean_error_m("depth_image") for t in recovered.ticks}
    assert plotted.keys() == expected.keys()
    for tick, value in expected.items():
        assert math.isnan(plotted[tick]) if value is None else plotted[tick] == value, tick
    text = [r["TextDocument:text"][0] for r in read_rows(run.rrd, entity.DESCRIPTION)][-1]
    assert "## Before and after calibration" in text
    angle_deg = _angle_deg(run.spec.scene.camera.T_b_c_declared, _mujoco_T_b_c(run.spec))
    assert f"mount error ({angle_deg:.2f} deg and " in text
    by_mount = run.report["calibration"]["position_error_m"]
    declared, after = by_mount["declared_mount"], by_mount["recovered_mount"]
    for name in ("depth_image", "ground_plane", "known_height", "triangulated"):
        assert (
            f"- {name}: mean {declared[name]['mean']:.3f} m with the declared mount, "
            f"{after[name]['mean']:.3f} m with the recovered one"
        ) in text


NAMES = builtin.names()


@pytest.mark.parametrize("name", NAMES)
def test_scenario_document_lists_every_checks_verdict(builtin_runs, name):
    """The scenario document the recording ends with names the run's verdict and, for each
    check of the JSON report, its outcome, name and figure against its limit; a calibrated
    run's also what calibration recovered."""
    run = builtin_runs[name]
    rep = json.loads(run.json_path.read_text())
    docs = [r["TextDocument:text"][0] for r in read_rows(run.rrd, entity.DESCRIPTION)]
    text = docs[-1]  # the static row logged last is the one the viewer shows
    heading = re.search(r"^## Checks: (.+)$", text, flags=re.M)
    assert heading is not None
    assert heading.group(1).startswith("FAILED") == (not rep["passed"])
    words = {"passed": "passed", "failed": "FAILED", "no data": "NO DATA", "skipped": "skipped"}
    listed = re.findall(r"^\* \*\*([A-Za-z ]+)\*\* (.+)$", text, flags=re.M)
    assert listed == [(words[c["outcome"]], f"{c['name']}: {c['shown']}") for c in rep["checks"]]
    assert ("## Calibration" in text) == (rep["calibration"] is not None)


# ------------------------------------------------------------------- the pipeline's order


def _short(name: str = "frame-problem"):
    """A built-in at 2 Hz: the same flight, few ticks."""
    return dataclasses.replace(builtin.load(name), camera_rate_hz=2.0)


def test_recording_is_finished_after_judging_with_the_verdicts(tmp_path, monkeypatch):
    """run -> judge -> finish (with the verdicts) -> report -> commit; the runner no longer
    finishes the recording itself, and the finish's time is counted in ``setup``."""
    events: list[str] = []
    finish_s = 0.3
    given: dict = {}

    def spy(name, real):
        def wrapped(*args, **kwargs):
            out = real(*args, **kwargs)
            events.append(name)
            return out

        return wrapped

    real_finish = Recording.finish

    def finish(self, result, judged):
        events.append("finish")
        given["judged"] = list(judged)
        time.sleep(finish_s)  # a slow finish must show in the run's set-up time
        real_finish(self, result, judged)

    monkeypatch.setattr(pipeline, "run_scenario", spy("run", pipeline.run_scenario))
    monkeypatch.setattr(checks, "judge", spy("judge", checks.judge))
    monkeypatch.setattr(Recording, "finish", finish)
    monkeypatch.setattr(report, "build", spy("report", report.build))
    monkeypatch.setattr(OutputPair, "commit", spy("commit", OutputPair.commit))

    spec = _short()
    outcome = pipeline.run(spec, seed=1, out_dir=tmp_path)
    n = len(spec.checks)
    assert events == ["run", *["judge"] * n, "finish", "report", "commit"]
    assert given["judged"] == outcome.judged
    assert list(outcome.result.timing_s) == [
        *STAGES,
        "render_gl",
        "setup",
        "calibrate",
        "judge",
        "total",
        "total_cpu",
    ]
    assert outcome.result.timing_s["setup"] >= finish_s
    assert outcome.report["timing_s"]["setup"] >= finish_s


def test_a_failing_finish_aborts_the_recording_and_writes_nothing(tmp_path, monkeypatch):
    """The recording is open while the run is judged and finished: a failure there closes it
    and removes its file, as a failure during the run does; no pair, no temporary file."""
    aborted = []
    real_abort = Recording.abort

    def abort(self):
        aborted.append(self.rec is not None)  # still open when aborted
        real_abort(self)

    def finish(self, result, judged):
        raise RuntimeError("injected")

    monkeypatch.setattr(Recording, "abort", abort)
    monkeypatch.setattr(Recording, "finish", finish)
    with pytest.raises(RuntimeError, match="injected"):
        pipeline.run(_short(), seed=1, out_dir=tmp_path)
    assert aborted == [True]
    assert list(tmp_path.iterdir()) == []
