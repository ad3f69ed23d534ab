"""``vnav-demo run --export``: the run's data for other tools (``scenarios.export``), checked
with the tools that read it (evo's file readers and its APE, OpenCV's PNG decoder, a YAML
parser) against what the run itself saw (the images and truth handed to its observers)."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import threading
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from evo.core import metrics, sync
from evo.main_ape import ape
from evo.tools import file_interface

from scenarios import export, pipeline
from scenarios.cli import main
from scenarios.export import base, euroc
from scenarios.record import outputs
from scenarios.run.runner import FanOut
from scenarios.scenario import builtin
from sim.flight import KeyframeTrajectory
from vnav import quat, se3, so3


def _yaml(path: Path) -> dict:
    """A YAML file read by PyYAML (evo's dependency), as EuRoC readers read sensor.yaml."""
    return yaml.safe_load(path.read_text())


SENSOR_KEYS = [
    "sensor_type",
    "comment",
    "T_BS",
    "rate_hz",
    "resolution",
    "camera_model",
    "intrinsics",
    "distortion_model",
    "distortion_coefficients",
]
"""The keys of a EuRoC camera's ``sensor.yaml``, in the dataset's order."""


@dataclasses.dataclass
class Exported:
    out: Path
    outcome: pipeline.Outcome
    rgb: list[np.ndarray]
    depth_m: list[np.ndarray | None]
    records: list


def _run_capturing(spec, out: Path, exports: tuple[str, ...]) -> Exported:
    """``pipeline.run`` with ``exports``, keeping a copy of every image its observers got."""
    rgb, depth, records = [], [], []
    real = FanOut.on_tick

    def on_tick(self, record, image, depth_m):
        rgb.append(image.copy())
        depth.append(None if depth_m is None else depth_m.copy())
        records.append(record)
        real(self, record, image, depth_m)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(FanOut, "on_tick", on_tick)
        outcome = pipeline.run(spec, seed=1, out_dir=out, exports=exports)
    return Exported(out, outcome, rgb, depth, records)


@pytest.fixture(scope="module")
def calibration(tmp_path_factory) -> Exported:
    """The calibration built-in (8 cones, a camera clock 30 ms behind), 3 s, tum and euroc."""
    spec = dataclasses.replace(builtin.load("calibration"), duration_s=3.0)
    return _run_capturing(spec, tmp_path_factory.mktemp("calibration"), ("tum", "euroc"))


def _mav0(exported: Exported) -> Path:
    return exported.out / f"{exported.outcome.result.spec.name}.euroc" / "mav0"


def _csv(path: Path) -> tuple[str, list[list[str]]]:
    header, *rows = path.read_text().splitlines()
    return header, [r.split(",") for r in rows]


# ------------------------------------------------------------------------------ EuRoC


def test_euroc_ground_truth_read_by_evo_is_the_tum_truth(calibration):
    """evo reads the EuRoC ground truth (the body) and the TUM truth (the camera): the body
    pose times cam0's ``T_BS`` is the camera pose, at the same stamps."""
    mav0 = _mav0(calibration)
    body = file_interface.read_euroc_csv_trajectory(
        str(mav0 / "state_groundtruth_estimate0" / "data.csv")
    )
    camera = file_interface.read_tum_trajectory_file(str(calibration.out / "calibration.truth.tum"))
    sensor = _yaml(mav0 / "cam0" / "sensor.yaml")
    T_b_c = np.array(sensor["T_BS"]["data"], dtype=np.float64).reshape(4, 4)
    assert body.num_poses == camera.num_poses == len(calibration.records)
    np.testing.assert_allclose(body.timestamps, camera.timestamps, rtol=0, atol=1e-9)
    for T_w_b, T_w_c in zip(body.poses_se3, camera.poses_se3, strict=True):
        np.testing.assert_allclose(T_w_b @ T_b_c, T_w_c, atol=1e-7)


def test_euroc_ground_truth_is_the_runs_truth(calibration):
    """Row by row: the stamp (camera clock, ns), the body's position, its attitude (w first)
    and velocity as the run's records hold them; the biases zero; EuRoC's header."""
    header, rows = _csv(_mav0(calibration) / "state_groundtruth_estimate0" / "data.csv")
    assert header == euroc.GROUNDTRUTH_HEADER
    assert len(header.split(",")) == 17
    for row, record in zip(rows, calibration.records, strict=True):
        assert int(row[0]) == round(record.timing.stamp_cam_s * 1e9)
        values = np.array(row[1:], dtype=np.float64)
        np.testing.assert_allclose(values[0:3], record.T_w_b[:3, 3], atol=1e-9)
        R = quat.to_matrix(np.roll(values[3:7], -1), normalize=True)  # w, x, y, z -> x, y, z, w
        assert np.linalg.norm(so3.log(R.T @ record.T_w_b[:3, :3])) < 1e-8
        np.testing.assert_allclose(values[7:10], record.v_w_b_mps, atol=1e-9)
        assert not values[10:].any()
    assert int(rows[0][0]) < 0  # the camera clock is 30 ms behind the pose clock


def test_euroc_images_are_the_images_the_run_saw(calibration):
    """cam0/data.csv names one PNG per image, by its stamp; OpenCV reads each back equal to
    the image the run's observers got, pixel for pixel."""
    mav0 = _mav0(calibration)
    header, rows = _csv(mav0 / "cam0" / "data.csv")
    assert header == "#timestamp [ns],filename"
    _, truth_rows = _csv(mav0 / "state_groundtruth_estimate0" / "data.csv")
    assert [r[0] for r in rows] == [r[0] for r in truth_rows]
    assert sorted(p.name for p in (mav0 / "cam0" / "data").iterdir()) == sorted(
        f"{t}.png" for t, _ in rows
    )
    for (t_ns, name), rgb in zip(rows, calibration.rgb, strict=True):
        assert name == f"{t_ns}.png"
        bgr = cv2.imread(str(mav0 / "cam0" / "data" / name), cv2.IMREAD_UNCHANGED)
        assert bgr.dtype == np.uint8 and bgr.shape == rgb.shape
        assert np.array_equal(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), rgb)


def test_euroc_depth_is_the_runs_depth_in_millimetres(calibration):
    """depth0: a 16-bit PNG per image, the run's depth to the millimetre, 0 where there was
    no return (the sky reads the far plane) or beyond 65.535 m."""
    mav0 = _mav0(calibration)
    _, rows = _csv(mav0 / "depth0" / "data.csv")
    far_m = calibration.outcome.result.spec.scene.zfar_m
    assert len(rows) == len(calibration.depth_m)
    for (_, name), depth_m in zip(rows, calibration.depth_m, strict=True):
        mm = cv2.imread(str(mav0 / "depth0" / "data" / name), cv2.IMREAD_UNCHANGED)
        assert mm.dtype == np.uint16 and mm.shape == depth_m.shape
        # A return nearer than the far plane and than 65.535 m, the most 16 bits hold.
        valid = (depth_m > 0) & (depth_m < far_m) & (depth_m < 65.5355)
        assert valid.any() and (~valid).any()  # ground and sky
        assert np.all(np.abs(mm[valid] / 1000.0 - depth_m[valid]) <= 0.0005 + 1e-6)
        assert not mm[~valid].any()


def _mm_exact(d: float, far_m: float) -> int:
    """The depth ``d`` in millimetres by exact rational arithmetic (``Fraction``), rounded half
    to even (Python's ``round``), 0 without a return: the reference of ``depth_mm``."""
    if not math.isfinite(d) or d <= 0 or d >= far_m:
        return 0
    mm = round(Fraction(d) * 1000)
    return mm if mm <= 65535 else 0


def test_depth_mm_rounds_each_depth_exactly_to_the_millimetre():
    """``base.depth_mm`` (float32 depth -> uint16 mm) against exact rational arithmetic: at and
    beside every half millimetre (where float32 arithmetic would round the wrong way), zero,
    negative, NaN, infinite depths, the far plane (as float32, as the sky reads it) and just
    below it, 65.5355 m and its neighbours, and random depths."""
    far_m = 50.0 / 3.0  # not a float32: compared as the renderer's float32 sky reads it
    f32 = np.float32
    halves = np.arange(0.5, 20_000, 997.0) / 1000.0
    edge = [0.0, -0.0, -1.0, np.nan, np.inf, -np.inf, far_m, 65.5355, 70.0, 1e-4, 4e-4]
    values = np.concatenate(
        [
            np.asarray(edge, dtype=f32),
            halves.astype(f32),
            np.nextafter(halves.astype(f32), f32(0)),
            np.nextafter(halves.astype(f32), f32(100)),
            np.nextafter(np.asarray([far_m, 65.5355], f32), f32(0)),
            np.nextafter(np.asarray([far_m, 65.5355], f32), f32(100)),
            np.random.default_rng(3).uniform(-1, 80, 4000).astype(f32),
        ]
    )
    far_f32 = float(f32(far_m))  # the sky's depth: the renderer's far plane in float32
    want = np.array([_mm_exact(float(d), far_f32) for d in values], dtype=np.uint16)
    got = base.depth_mm(values.reshape(-1, 1), far_m).ravel()
    assert got.dtype == np.uint16
    np.testing.assert_array_equal(got, want)
    assert got[list(values).index(f32(far_m))] == 0  # the sky


def test_a_ticks_depth_in_millimetres_is_made_once_for_every_exporter(calibration):
    """``tick_depth_mm``: the same tick's record and depth give the same handle, whose ``get``
    makes ``depth_mm`` once (the very array for every exporter, read-only); another tick's
    record, or another far plane, a new handle."""
    record, other = calibration.records[:2]
    depth_m = calibration.depth_m[0]
    shared = base.tick_depth_mm(record, depth_m, 100.0)
    assert base.tick_depth_mm(record, depth_m, 100.0) is shared
    first = shared.get()
    assert shared.get() is first and not first.flags.writeable
    np.testing.assert_array_equal(first, base.depth_mm(depth_m, 100.0))
    assert base.tick_depth_mm(other, depth_m, 100.0) is not shared
    assert base.tick_depth_mm(other, depth_m, 20.0).get() is not first


def test_a_flush_that_fails_is_an_error(tmp_path):
    """``Flusher``: files flushed on its threads; a file it cannot flush (here, one that is not
    there) raises from ``wait``, and from the next ``submit`` once it is known."""
    flusher = base.Flusher(threads=2)
    try:
        for i in range(5):
            (tmp_path / f"{i}.png").write_bytes(b"x" * 1000)
            flusher.submit(tmp_path / f"{i}.png")
        flusher.wait()
        flusher.submit(tmp_path / "missing.png")
        with pytest.raises(FileNotFoundError):
            flusher.wait()
        flusher.submit(tmp_path / "missing.png")
        with pytest.raises(FileNotFoundError):
            for _ in range(1000):  # until the failed flush is done and seen
                flusher.submit(tmp_path / "0.png")
    finally:
        flusher.shutdown()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread nice is Linux's")
def test_the_exporters_threads_are_nicer_than_the_run(tmp_path):
    """Each thread of an exporter's pool runs ``EXPORTER_NICE`` nicer than the thread that
    made the pool (the kernel's own figure, read back per thread), up to Linux's 19, also when
    another exporter thread starts it (as the EuRoC writer starts its ``Flusher``'s)."""

    def nice() -> int:
        return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())

    mine = nice()
    expected = min(19, mine + base.EXPORTER_NICE)
    with base.exporter_threads(1, "test-writer") as writer:
        inner = base.exporter_threads(2, "test-inner")
        try:
            # The inner pool's threads start from the writer's thread, already nicer.
            started = writer.submit(lambda: [inner.submit(nice) for _ in range(4)]).result()
            assert writer.submit(nice).result() == expected
            assert {f.result() for f in started} == {expected}
        finally:
            inner.shutdown()
    assert nice() == mine


def test_the_queue_holds_what_its_bytes_allow():
    """A 640x480 colour image and its float32 depth: 31 ticks in 64 MiB; the bound is the
    bytes, within the fewest and most ticks."""
    rgb = np.zeros((480, 640, 3), np.uint8)
    depth_m = np.zeros((480, 640), np.float32)
    assert base.queue_bound(rgb, depth_m) == base.QUEUED_BYTES_MAX // (rgb.nbytes + depth_m.nbytes)
    assert base.queue_bound(rgb, depth_m) == 31
    large_rgb = np.zeros((960, 1280, 3), np.uint8)  # 3.7 MB; no depth
    assert base.queue_bound(large_rgb, None) == base.QUEUED_BYTES_MAX // large_rgb.nbytes == 18
    assert base.queue_bound(np.zeros((4000, 4000, 3), np.uint8)) == base.QUEUED_TICKS_MIN
    assert base.queue_bound(np.zeros((48, 64, 3), np.uint8)) == base.QUEUED_TICKS_MAX


def test_euroc_sensor_files_describe_the_camera(calibration):
    """cam0/sensor.yaml has EuRoC's keys in its order; the intrinsics are the camera's,
    ``T_BS`` the true mount, row-major; the ground truth's T_BS the identity."""
    mav0 = _mav0(calibration)
    cam0 = _yaml(mav0 / "cam0" / "sensor.yaml")
    assert list(cam0) == SENSOR_KEYS
    spec = calibration.outcome.result.spec
    from vnav.camera import PinholeCamera

    c = spec.scene.camera
    camera = PinholeCamera.from_fovy(c.fovy_deg, c.width, c.height)
    assert cam0["intrinsics"] == [camera.fx, camera.fy, camera.cx, camera.cy]
    assert cam0["resolution"] == [c.width, c.height]
    assert cam0["rate_hz"] == spec.camera_rate_hz
    assert cam0["camera_model"] == "pinhole"
    assert cam0["distortion_model"] == "radial-tangential"
    assert cam0["distortion_coefficients"] == [0.0, 0.0, 0.0, 0.0]
    assert (cam0["T_BS"]["rows"], cam0["T_BS"]["cols"]) == (4, 4)
    T_BS = np.array(cam0["T_BS"]["data"]).reshape(4, 4)
    np.testing.assert_array_equal(T_BS, calibration.records[0].T_b_c)
    se3.check_transform(T_BS)
    depth0 = _yaml(mav0 / "depth0" / "sensor.yaml")
    assert list(depth0)[: len(SENSOR_KEYS)] == SENSOR_KEYS and depth0["depth_scale"] == 1000
    truth = _yaml(mav0 / "state_groundtruth_estimate0" / "sensor.yaml")
    np.testing.assert_array_equal(np.array(truth["T_BS"]["data"]).reshape(4, 4), np.eye(4))
    assert "comment" in _yaml(mav0 / "body.yaml")
    assert not (mav0 / "imu0").exists()
    assert "no IMU" in calibration.outcome.report["exports"]["euroc"]["note"]


def test_euroc_velocity_of_a_flight_with_dynamics_is_the_positions_derivative(tmp_path):
    """The approach built-in (MuJoCo's dynamics): the exported velocity (MuJoCo's) against
    the central difference of the exported positions, O(dt^2) apart."""
    spec = dataclasses.replace(builtin.load("approach"), duration_s=4.0)
    pipeline.run(spec, seed=1, out_dir=tmp_path, exports=("euroc",))
    _, rows = _csv(
        tmp_path / "approach.euroc" / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    )
    table = np.array(rows, dtype=np.float64)
    t_s, p_w, v_w = table[:, 0] / 1e9, table[:, 1:4], table[:, 8:11]
    central = (p_w[2:] - p_w[:-2]) / (t_s[2:] - t_s[:-2])[:, None]
    assert np.abs(v_w[1:-1]).max() > 0.3  # it moves
    np.testing.assert_allclose(v_w[1:-1], central, atol=0.02)


def test_keyframe_velocity_is_the_slope_of_the_interpolated_position():
    """``KeyframeTrajectory.velocity_w``: the derivative of ``pose`` (a central difference
    inside each segment), zero outside the keyframes."""
    rng = np.random.default_rng(3)
    times = np.array([0.0, 0.7, 1.5, 3.0])
    poses = np.array([se3.make(so3.exp(rng.normal(size=3)), rng.normal(size=3)) for _ in times])
    keyframes = KeyframeTrajectory(times, poses)
    for t in (0.1, 0.69, 0.71, 2.0, 2.99):
        h = 1e-4
        slope = (keyframes.pose(t + h)[:3, 3] - keyframes.pose(t - h)[:3, 3]) / (2 * h)
        np.testing.assert_allclose(keyframes.velocity_w(t), slope, atol=1e-7)
    for t in (-1.0, 3.0, 4.0):
        assert not keyframes.velocity_w(t).any()


# ------------------------------------------------------------------------------ the report


def test_report_lists_every_exported_file_with_its_size(calibration):
    """``exports``: per format every file it wrote (relative to the output directory) with
    its size in bytes: exactly the files on disk."""
    exports = calibration.outcome.report["exports"]
    on_disk = json.loads((calibration.out / "calibration.json").read_text())["exports"]
    assert on_disk == json.loads(json.dumps(exports))
    listed = {f["path"]: f["bytes"] for entry in exports.values() for f in entry["files"]}
    found = {}
    for path in calibration.out.rglob("*"):
        rel = path.relative_to(calibration.out).as_posix()
        if path.is_file() and not rel.startswith(".") and rel.split(".")[-1] not in ("rrd", "json"):
            found[rel] = path.stat().st_size
    assert listed == found
    assert {"calibration.truth.tum", "calibration.pnp.tum"} <= set(listed)


def test_pnp_error_statistics_are_evo_apes(calibration):
    """The report's ``pnp_ape_m`` are the numbers ``evo_ape tum truth.tum pnp.tum`` gives
    (evo's own reader, association and APE, no alignment, the translation part)."""

    ref = file_interface.read_tum_trajectory_file(str(calibration.out / "calibration.truth.tum"))
    est = file_interface.read_tum_trajectory_file(str(calibration.out / "calibration.pnp.tum"))
    ref, est = sync.associate_trajectories(ref, est, max_diff=0.01)
    stats = ape(ref, est, metrics.PoseRelation.translation_part).stats
    ours = calibration.outcome.report["exports"]["tum"]["pnp_ape_m"]
    assert set(stats) == set(ours) - {"count"}
    assert ours["count"] == est.num_poses >= 10
    for name, value in stats.items():
        assert ours[name] == pytest.approx(value, rel=1e-6, abs=1e-8), name


# ------------------------------------------------------------------------------ the command


def test_tum_with_no_pnp_pose_writes_no_empty_file_and_says_why(tmp_path, capsys):
    """One cone: PnP has no pose, so NAME.pnp.tum is not written (an earlier run's is
    removed with the commit), the run says why in one sentence and the report lists the
    truth file only."""
    stale = tmp_path / "frame-problem.pnp.tum"
    stale.write_text("0.0 0 0 0 0 0 0 1\n")  # what an earlier run with 4 cones left
    args = ["run", "frame-problem", "--duration", "0.5", "--export", "tum", "--out", str(tmp_path)]
    assert main(args) in (0, 1)  # half a second is short for the checks; the files are the point
    said = " ".join(capsys.readouterr().out.split())  # the summary wraps its lines
    assert (
        f"tum: wrote {tmp_path / 'frame-problem.truth.tum'}; frame-problem.pnp.tum not written: "
        "PnP needs 4 cones seen whole in one image; this run saw at most 1 " in said
    )
    assert not stale.exists()
    report = json.loads((tmp_path / "frame-problem.json").read_text())
    entry = report["exports"]["tum"]
    assert [f["path"] for f in entry["files"]] == ["frame-problem.truth.tum"]
    assert entry["note"].startswith("frame-problem.pnp.tum not written")
    assert "pnp_ape_m" not in entry
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [outputs.LOCK_NAME, "frame-problem.json", "frame-problem.rrd", "frame-problem.truth.tum"]
    )


@pytest.mark.parametrize("value", ["bogus", "tum,bogus", "tum,", ""])
def test_an_unknown_export_format_exits_2_in_one_line(tmp_path, capsys, value):
    assert main(["run", "frame-problem", "--export", value, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert f"the formats are {', '.join(export.available())}" in err
    assert list(tmp_path.iterdir()) == []


def test_a_format_whose_module_is_not_installed_is_not_offered(tmp_path, capsys, monkeypatch):
    """A format registered before its module lands (or whose extra is not installed) is
    refused like an unknown one, and not listed."""
    missing = export.Format("scenarios.export.no_such_module:X", ("{name}.x",), False, "x")
    monkeypatch.setitem(export.FORMATS, "nothere", missing)
    assert "nothere" not in export.available()
    assert main(["run", "frame-problem", "--export", "nothere", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown format 'nothere'" in err and "nothere," not in err


def test_a_file_under_the_euroc_directory_name_is_refused_before_running(tmp_path, capsys):
    (tmp_path / "frame-problem.euroc").write_text("mine")
    args = ["run", "frame-problem", "--export", "euroc", "--out", str(tmp_path), "--quiet"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is not a directory" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frame-problem.euroc"]


def _snapshot(directory: Path) -> dict[str, bytes]:
    return {
        p.relative_to(directory).as_posix(): p.read_bytes()
        for p in sorted(directory.rglob("*"))
        if p.is_file()
    }


def test_a_full_disk_during_the_export_keeps_the_previous_files(tmp_path, capsys, monkeypatch):
    """ENOSPC on the 5th EuRoC file write of a second run (in the export process,
    ``export_faults.FullDiskEuroc``): exit 3 in one line, and the first run's recording,
    report, TUM file and EuRoC directory are all as they were, with no temporary file left."""
    args = ["run", "frame-problem", "--duration", "1", "--export", "tum,euroc"]
    assert main([*args, "--out", str(tmp_path), "--quiet"]) in (0, 1)
    before = _snapshot(tmp_path)
    assert "frame-problem.euroc/mav0/cam0/data/0.png" in before
    full = dataclasses.replace(export.FORMATS["euroc"], exporter="export_faults:FullDiskEuroc")
    monkeypatch.setitem(export.FORMATS, "euroc", full)
    capsys.readouterr()
    assert main([*args, "--seed", "2", "--out", str(tmp_path), "--quiet"]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "No space left on device" in err
    assert ".png" in err  # the image write that found the disk full
    assert _snapshot(tmp_path) == before
    assert not [
        p
        for p in tmp_path.iterdir()
        if p.name.startswith(outputs.TEMP_PREFIX) and p.name != outputs.LOCK_NAME
    ]
