"""The ``vnav-demo`` command: a user's TOML scenario end to end, and every bad-input path."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import read_rows
from rerun.chunk import RrdReader

import scenarios.run.runner
from scenarios import pipeline
from scenarios.cli import main
from scenarios.judge import checks
from scenarios.scenario import builtin, check_kinds

PITCH_90_TOML = textwrap.dedent("""\
    name = "pitch-ninety"
    description = "nose straight down over a cone"
    camera_rate_hz = 5.0

    [camera]
    position_b = [0.15, 0.0, 0.05]
    pitch_down_deg = 0.0
    fovy_deg = 60.0
    width = 640
    height = 480

    [[cones]]
    position_w = [1.5, 0.5, 0.0]

    [flight]
    mode = "kinematic"
    keyframes = [
      { t = 0.0, position_w = [0.0, 0.0, 4.0], rpy_deg = [0.0, 45.0, 0.0] },
      { t = 2.0, position_w = [0.0, 0.0, 4.0], rpy_deg = [0.0, 90.0, 0.0] },
      { t = 3.0, position_w = [0.0, 0.0, 4.0], rpy_deg = [0.0, 90.0, 0.0] },
    ]

    [[checks]]
    kind = "max_error"
    method = "depth_image"
    limit_m = 0.1

    [[checks]]
    kind = "detection_rate"
    limit = 0.95
""")


def test_toml_scenario_with_pitch_90_keyframe(tmp_path, capsys):
    scenario = tmp_path / "pitch.toml"
    scenario.write_text(PITCH_90_TOML)
    out = tmp_path / "out"
    assert main(["run", str(scenario), "--out", str(out), "--quiet"]) == 0
    rep = json.loads((out / "pitch-ninety.json").read_text())
    assert rep["passed"] and rep["camera_ticks"] == 16 and rep["detections"] == 16

    # At t >= 2 s the body's x axis points straight down: the camera looks along world -z.
    body = [r for r in read_rows(out / "pitch-ninety.rrd", "world/body") if "tick" in r]
    _x_w, y_w, _z_w, w = body[-1]["Transform3D:quaternion"][0]
    assert abs(y_w) == pytest.approx(np.sqrt(0.5), abs=1e-6) and abs(w) == pytest.approx(
        np.sqrt(0.5), abs=1e-6
    )

    # The estimates in the file sit on the cone the file declares.
    rows = [
        r
        for r in read_rows(out / "pitch-ninety.rrd", "world/cones/estimate/depth_image")
        if r.get("Points3D:positions")
    ]
    p_w = np.array([p for r in rows for p in r["Points3D:positions"]])
    assert len(p_w) == 16
    assert np.max(np.linalg.norm(p_w[:, :2] - [1.5, 0.5], axis=1)) < 0.05


def recording_ids(rrd: Path) -> list[str]:
    """The Rerun recording ids stored in an .rrd file."""
    return [e.recording_id for e in RrdReader(str(rrd)).recordings()]


def test_same_seed_same_json(tmp_path):
    scenario = tmp_path / "s.toml"
    scenario.write_text(
        PITCH_90_TOML.replace("[[checks]]", "[noise]\nposition_std_m = 0.05\n\n[[checks]]", 1)
    )
    reports, ids = [], []
    for run in ("a", "b", "c"):
        seed = "7" if run != "c" else "8"
        assert main(
            [
                "run",
                str(scenario),
                "--out",
                str(tmp_path / run),
                "--seed",
                seed,
                "--quiet",
                "--duration",
                "1",
            ]
        ) in (0, 1)
        rep = json.loads((tmp_path / run / "pitch-ninety.json").read_text())
        rep.pop("timing_s")
        # The report names the recording it was written with: the id inside the .rrd.
        recording = rep.pop("recording")
        assert recording["file"] == "pitch-ninety.rrd"
        assert recording_ids(tmp_path / run / recording["file"]) == [recording["id"]]
        reports.append(rep)
        ids.append(recording["id"])
    assert len(set(ids)) == 3  # unique per run, so a pair from different runs shows
    assert reports[0] == reports[1]
    assert reports[0]["methods"] != reports[2]["methods"]  # the seed does drive the noise


def test_list_names_every_builtin(capsys):
    """One entry per built-in: its name, then its description (wrapped, indented)."""
    assert main(["list"]) == 0
    entries = re.split(r"\n(?=\S)", capsys.readouterr().out.strip())
    assert [e.split()[0] for e in entries] == builtin.names()
    for name, entry in zip(builtin.names(), entries, strict=True):
        description = builtin.REGISTRY[name]()["description"]
        assert " ".join(entry.split()[1:]) == " ".join(description.split())


@pytest.mark.parametrize(
    "args",
    [["list"], ["lecture"], *(["show", name] for name in builtin.names())],
    ids=lambda a: " ".join(a),
)
def test_output_fits_80_columns(capsys, args):
    main(args)
    out = capsys.readouterr().out
    assert out.strip()
    too_wide = [line for line in out.splitlines() if len(line) > 80]
    assert not too_wide, too_wide


def _run_in(tmp_path, monkeypatch, capsys, *args) -> tuple[int, str]:
    """``vnav-demo run ARGS --out out`` in ``tmp_path`` (short relative paths in the output);
    its status and stdout, every line of which fits 80 columns."""
    monkeypatch.chdir(tmp_path)
    status = main(["run", *args, "--out", "out"])
    out = capsys.readouterr().out
    too_wide = [line for line in out.splitlines() if len(line) > 80]
    assert not too_wide, too_wide
    return status, out


def test_a_check_with_no_data_says_why_and_fails(tmp_path, monkeypatch, capsys):
    """Cut at 0.5 s, frame-problem ends before its yaw: its "constant while yawing" check has
    nothing to judge. It says so and why, in the table and the report, and fails the run."""
    status, out = _run_in(tmp_path, monkeypatch, capsys, "frame-problem", "--duration", "0.5")
    assert status == 1
    rep = json.loads((tmp_path / "out" / "frame-problem.json").read_text())
    (yaw,) = [c for c in rep["checks"] if c["kind"] == "world_estimate_spread"]
    assert yaw["outcome"] == "no data" and not yaw["passed"] and yaw["value"] is None
    assert "camera coordinates moved 0 m" in yaw["reason"]
    assert not rep["passed"]
    assert re.search(r"^  NO DATA +depth_image world estimate constant while yawing", out, re.M)
    assert "camera coordinates moved 0 m" in " ".join(out.split())
    # Values carry units next to their limits; counts are integers.
    assert "% (must be >= 95%)" in out and "x (must be >= 10x)" in out
    assert re.search(r"6 camera ticks, 6 detections, 6 matched", out)
    assert "detections: cones found in the images; matched: estimated within 3 m" in out


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_run_prints_each_scenarios_duration_and_their_total(tmp_path, monkeypatch, capsys, jobs):
    """Each scenario's first line ends with its duration, wall and CPU seconds: its report's
    ``timing_s`` ``total`` and ``total_cpu`` (the whole run, stages, calibration, judging and
    recording included); with several, the summary gives the total: one after the other
    (``--jobs 1``) no less than their sum, two at a time no less than the longest, and no
    more than the command took; its CPU time no less than theirs (the workers' counted)."""
    started = time.perf_counter()
    args = ("frame-problem", "yaw-sweep", "--duration", "1", "--jobs", jobs)
    _, out = _run_in(tmp_path, monkeypatch, capsys, *args)
    took_s = time.perf_counter() - started
    flat = " ".join(out.split())
    totals, cpu_totals = [], []
    for name in ("frame-problem", "yaw-sweep"):
        timing = json.loads((tmp_path / "out" / f"{name}.json").read_text())["timing_s"]
        said = re.search(
            rf"{name}: (PASSED|FAILED) \(.*? matched, ([\d.]+) s, ([\d.]+) s CPU\)", flat
        )
        assert said, flat
        assert said[2] == f"{timing['total']:.1f}" and said[3] == f"{timing['total_cpu']:.1f}"
        # The stages on the run's thread add up; render_gl, the OpenGL thread's, overlaps them.
        parts = sum(v for k, v in timing.items() if not k.startswith("total") and k != "render_gl")
        assert parts <= timing["total"] + 1e-3 and timing["total_cpu"] > 0.0
        assert 0.0 < timing["render_gl"] <= timing["total"]
        totals.append(timing["total"])
        cpu_totals.append(timing["total_cpu"])
    said = re.search(r"2 scenarios: [^.]*? in ([\d.]+) s, ([\d.]+) s CPU", flat)
    assert said, flat
    least_s = sum(totals) if jobs == "1" else max(totals)
    assert least_s - 0.1 <= float(said[1]) <= took_s + 0.05
    assert float(said[2]) >= sum(cpu_totals) - 0.1


def test_copy_of_a_builtin_without_checks_passes_and_says_what_it_skipped(
    tmp_path, monkeypatch, capsys
):
    """A user's copy of frame-problem with its [[checks]] removed is held to the default
    checks; known_height cannot measure a cone seen from almost straight above, nor can
    triangulated a cone seen from a drone that only yaws in place (no parallax), so their
    bounds are skipped, with the reasons, in the table and the report, and the run passes. Run
    beside another scenario, the command ends with a summary."""
    assert main(["show", "frame-problem"]) == 0
    text = capsys.readouterr().out
    (tmp_path / "mine.toml").write_text(text[: text.index("[[checks]]")])
    status, out = _run_in(tmp_path, monkeypatch, capsys, "./mine.toml", "yaw-sweep")
    assert status == 0, out
    rep = json.loads((tmp_path / "out" / "my-frame-problem.json").read_text())
    outcomes = {c["name"]: c for c in rep["checks"]}
    assert {c.label for c in check_kinds.default_checks()} == set(outcomes)
    skipped = outcomes["known_height median <= 5% of range"]
    assert skipped["outcome"] == "skipped" and "seen steeper than 69 deg" in skipped["reason"]
    assert rep["passed"] and rep["methods"]["known_height"]["no_estimate"] == {"steep": 51}
    parallax = outcomes["triangulated median <= max(5 cm, 1% of range)"]
    assert parallax["outcome"] == "skipped" and "cross widely enough" in parallax["reason"]
    assert all(
        c["outcome"] == "passed" for c in rep["checks"] if c is not skipped and c is not parallax
    )
    assert re.search(r"^  skipped +known_height median <= 5% of range", out, re.M)
    # The summary: counts, where the files are, how to open one (a file that exists).
    assert "2 scenarios: 2 passed" in out
    assert "files: out/<name>.rrd (recording), out/<name>.json (report)" in out
    (open_line,) = [line for line in out.splitlines() if line.startswith("open: ")]
    viewer, rrd = open_line.split()[1:]
    assert (tmp_path / rrd).is_file() and viewer.endswith("rerun")
    assert not (tmp_path / "out" / "frame-problem.rrd").exists()  # the built-in's untouched


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            ["run", "no-such-scenario"],
            r"unknown scenario 'no-such-scenario'; valid names: "
            r"frame-problem, yaw-sweep",
        ),
        (["run"], r"no scenario given"),
        (["run", "frame-problem", "--duration", "0"], r"--duration must be a positive"),
        (["run", "frame-problem", "--seed", "x"], r"invalid int value: 'x'"),
        (["frobnicate"], r"invalid choice: 'frobnicate'"),
    ],
)
def test_bad_usage_exit_2_one_line(tmp_path, capsys, args, message):
    out = tmp_path / "out"
    assert main([*args, "--out", str(out)] if args[0] == "run" else args) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert re.search(message, err)
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ('name = "x"\n[camera\n', r"bad\.toml: invalid TOML: .*line 2"),
        (
            PITCH_90_TOML.replace("fovy_deg = 60.0", "fovy_deg = 200.0"),
            r"bad\.toml: camera: CameraConfig.fovy_deg must be in \[1, 170\] degrees",
        ),
        (
            PITCH_90_TOML.replace("fovy_deg = 60.0", 'fovy_deg = "60"'),
            r"bad\.toml: camera\.fovy_deg: must be a number, got '60'",
        ),
        (
            PITCH_90_TOML.replace("fovy_deg = 60.0", "fovy_deg = true"),
            r"bad\.toml: camera\.fovy_deg: must be a number, got True",
        ),
        (
            PITCH_90_TOML.replace("width = 640", "width = 640.5"),
            r"bad\.toml: camera\.width: must be an integer, got 640\.5",
        ),
        (
            PITCH_90_TOML.replace("[0.0, 45.0, 0.0]", "[0.0, 45.0]"),
            r"bad\.toml: flight\.keyframes\[0\]\.rpy_deg: must be a list of 3 numbers",
        ),
        (
            PITCH_90_TOML.replace("position_w = [1.5, 0.5, 0.0]", "position_w = [1.5, 0.5, -1.0]"),
            r"bad\.toml: cones: .*under the ground",
        ),
        (
            PITCH_90_TOML.replace('mode = "kinematic"', 'mode = "teleport"'),
            r"bad\.toml: flight\.mode: must be \"kinematic\", \"controlled\", \"orbit\" or "
            r"\"navigate\"",
        ),
        (
            PITCH_90_TOML.replace("camera_rate_hz", "camera_rate"),
            r"bad\.toml: camera_rate: unknown key",
        ),
        (
            PITCH_90_TOML.replace("{ t = 2.0", "{ t = 0.0"),
            r"bad\.toml: flight\.keyframes\[1\]\.t: times must increase",
        ),
    ],
)
def test_bad_scenario_file_exit_2(tmp_path, capsys, content, message):
    bad = tmp_path / "bad.toml"
    bad.write_text(content)
    out = tmp_path / "out"
    assert main(["run", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert re.search(message, err), err
    assert not out.exists() or not any(out.iterdir())


def test_missing_file_and_unwritable_out_dir(tmp_path, capsys):
    assert main(["run", str(tmp_path / "nope.toml"), "--out", str(tmp_path / "o")]) == 2
    assert "nope.toml: no such scenario file" in capsys.readouterr().err
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    assert main(["run", "frame-problem", "--out", str(blocker / "sub")]) == 2
    assert "cannot be written" in capsys.readouterr().err


def test_command_line_process_has_no_traceback(tmp_path):
    """The real console entry point: exit status 2 and one line, no Python traceback."""
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    proc = subprocess.run(
        [sys.executable, "-m", "scenarios", "run", "nope"],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stderr.count("\n") == 1


def test_interrupted_run_leaves_no_partial_file_and_keeps_the_old_one(tmp_path, monkeypatch):
    spec = builtin.load("frame-problem")
    rrd = tmp_path / "frame-problem.rrd"
    rrd.write_bytes(b"an earlier recording")
    calls = {"n": 0}
    real_detect = scenarios.run.runner.detect_cones

    def detect_then_fail(rgb):
        calls["n"] += 1
        if calls["n"] == 4:
            raise KeyboardInterrupt
        return real_detect(rgb)

    monkeypatch.setattr(scenarios.run.runner, "detect_cones", detect_then_fail)
    with pytest.raises(KeyboardInterrupt):
        pipeline.run(spec, out_dir=tmp_path)
    assert rrd.read_bytes() == b"an earlier recording"
    assert [p.name for p in tmp_path.iterdir()] == [rrd.name]


def test_lecture_command_prints_every_example_agreeing(capsys):
    from scenarios.commands import lecture

    assert main(["lecture"]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.rstrip().endswith(("yes", "NO"))]
    assert len(rows) == len(lecture.EXAMPLES)
    assert all(line.rstrip().endswith("yes") for line in rows)


@pytest.mark.parametrize(
    "flight",
    [
        'mode = "controlled"\nwaypoints = [{ t = 0.0, position_w = [0.0, 0.0, 4.0] }]',
        'mode = "kinematic"\nkeyframes = [{ t = 0.0, position_w = [0.0, 0.0, 4.0], '
        "rpy_deg = [0.0, 0.0, 0.0] }]",
    ],
)
def test_one_waypoint_or_keyframe_holds_the_pose(tmp_path, flight):
    """A single waypoint hovers there (controller), a single keyframe holds still; the default
    checks (accuracy bounds, detection rate) pass on the cone ahead."""
    scenario = tmp_path / "one.toml"
    scenario.write_text(
        'name = "one"\nduration_s = 2.0\ncamera_rate_hz = 5.0\n[camera]\npitch_down_deg = 45.0\n'
        f"[[cones]]\nposition_w = [5.0, 0.0, 0.0]\n[flight]\n{flight}\n"
    )
    assert main(["run", str(scenario), "--out", str(tmp_path), "--quiet"]) == 0
    rep = json.loads((tmp_path / "one.json").read_text())
    assert rep["detections"] == rep["camera_ticks"] == 11
    body = [r for r in read_rows(tmp_path / "one.rrd", "world/body") if "tick" in r]
    positions_w = np.array([r["Transform3D:translation"][0] for r in body])
    assert np.max(np.linalg.norm(positions_w - [0.0, 0.0, 4.0], axis=1)) < 0.02


def test_progress_bar_only_on_a_terminal(tmp_path):
    """On a terminal (a pseudo-terminal here) stderr shows a progress bar; piped, nothing."""
    import pty

    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    args = [sys.executable, "-m", "scenarios", "run", "frame-problem", "--duration", "1.5"]
    controller, terminal = pty.openpty()
    try:
        proc = subprocess.run(
            [*args, "--out", str(tmp_path / "tty")],
            env=env,
            timeout=120,
            stdout=subprocess.PIPE,
            stderr=terminal,
        )
        os.close(terminal)
        shown = b""
        while True:
            try:
                chunk = os.read(controller, 4096)
            except OSError:  # the terminal side is closed and drained
                break
            if not chunk:
                break
            shown += chunk
    finally:
        os.close(controller)
    assert proc.returncode == 0
    assert b"frame-problem" in shown and b"16/16" in shown and b"#" in shown
    piped = subprocess.run(
        [*args, "--out", str(tmp_path / "pipe")],
        env=env,
        timeout=120,
        capture_output=True,
        text=True,
    )
    assert piped.returncode == 0 and piped.stderr == ""


# ---------------------------------------------------------------- outputs that never lie


def _files(directory: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(directory.iterdir()) if p.is_file()}


@pytest.fixture(scope="session")  # once per test process: this module's tests are spread
def first_pair(tmp_path_factory) -> dict[str, bytes]:
    """frame-problem cut at 0.5 s, before its yaw: its yaw check has no data (exit status 1),
    and the pair is written all the same (and nothing printed: ``--quiet``)."""
    out = tmp_path_factory.mktemp("first-pair")
    assert main(["run", "frame-problem", "--out", str(out), "--quiet", "--duration", "0.5"]) == 1
    return {k: v for k, v in _files(out).items() if not k.startswith(".")}


def _first_pair(out: Path, pair: dict[str, bytes]) -> dict[str, bytes]:
    """The ``first_pair`` run's files in ``out``, byte for byte: a previous run's pair."""
    for name, data in pair.items():
        (out / name).write_bytes(data)
    return pair


def test_disk_full_on_a_small_filesystem_exits_3_and_keeps_the_previous_pair(
    tmp_path, capsys, first_pair
):
    out = tmp_path / "small"
    out.mkdir()
    try:
        mounted = (
            subprocess.run(
                ["mount", "-t", "tmpfs", "-o", "size=1000k", "tmpfs", str(out)], capture_output=True
            ).returncode
            == 0
        )
    except FileNotFoundError:  # no mount command
        mounted = False
    if not mounted:
        pytest.skip(
            "cannot mount a small tmpfs here (needs root and CAP_SYS_ADMIN); "
            "test_injected_short_recording covers the same path"
        )
    try:
        before = _first_pair(out, first_pair)  # about 800 KB: fits once, not twice
        status = main(["run", "frame-problem", "--out", str(out), "--quiet", "--seed", "2"])
        err = capsys.readouterr().err
        assert status == 3
        assert err.count("\n") == 1 and "could not complete" in err and "kept" in err
        after = {k: v for k, v in _files(out).items() if not k.startswith(".")}
        assert after == before
        assert not [p for p in out.iterdir() if p.name.endswith((".partial", ".old"))]
    finally:
        subprocess.run(["umount", str(out)], check=True)


def test_injected_short_recording_exits_3_and_keeps_the_previous_pair(
    tmp_path, capsys, monkeypatch, first_pair
):
    """What the Rerun file sink leaves on a full disk (it only logs the error): a file that
    stops short. Injected by cutting the finished file in half."""
    from scenarios.record.recording import Recording

    before = _first_pair(tmp_path, first_pair)
    real_finish = Recording.finish

    def finish_short(self, result, judged):
        real_finish(self, result, judged)
        data = self.path.read_bytes()
        self.path.write_bytes(data[: len(data) // 2])

    monkeypatch.setattr(Recording, "finish", finish_short)
    assert main(["run", "frame-problem", "--out", str(tmp_path), "--quiet", "--seed", "2"]) == 3
    assert "frame-problem.rrd" in capsys.readouterr().err
    assert {k: v for k, v in _files(tmp_path).items() if not k.startswith(".")} == before
    assert not [p for p in tmp_path.iterdir() if p.name.endswith((".partial", ".old"))]


@pytest.mark.parametrize("fail", [KeyboardInterrupt, RuntimeError])
def test_failure_while_judging_keeps_the_previous_pair(
    tmp_path, capsys, monkeypatch, fail, first_pair
):
    """No new .rrd beside the previous run's .json: a pair is never from two runs."""

    before = _first_pair(tmp_path, first_pair)

    def judge(check, run):
        raise fail("injected")

    monkeypatch.setattr(checks, "judge", judge)
    status = main(["run", "frame-problem", "--out", str(tmp_path), "--quiet", "--seed", "5"])
    assert status == (130 if fail is KeyboardInterrupt else 3)
    assert capsys.readouterr().err.count("\n") == 1
    assert {k: v for k, v in _files(tmp_path).items() if not k.startswith(".")} == before


@pytest.mark.parametrize("which", ["rrd", "json"])
def test_output_name_taken_by_a_directory_is_refused_before_running(tmp_path, capsys, which):
    (tmp_path / f"frame-problem.{which}").mkdir()
    assert main(["run", "frame-problem", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is a directory" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"frame-problem.{which}"]


def test_diverging_simulation_exits_3(tmp_path, capsys, monkeypatch):
    from sim.world import SimulationError

    def diverge(*args, **kwargs):
        raise SimulationError("t = 0.0100 s: qpos is not finite (injected)")

    monkeypatch.setattr(scenarios.run.runner, "evaluate_tick", diverge)
    assert main(["run", "frame-problem", "--out", str(tmp_path), "--quiet"]) == 3
    assert "diverged" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == [".vnav-demo.lock"]


def test_a_signal_turned_into_another_error_still_ends_as_the_signal(tmp_path, capsys, monkeypatch):
    """A library that catches the signal's exception and raises its own error (or swallows it
    and then fails) must not turn SIGHUP into "internal error", exit 3."""
    import signal

    def caught_then_failed(*args, **kwargs):
        try:  # the handler records the signal and raises; a library swallows that
            os.kill(os.getpid(), signal.SIGHUP)
        except BaseException:
            pass
        raise RuntimeError("a library's own error after the signal")

    monkeypatch.setattr(scenarios.pipeline, "run", caught_then_failed)
    assert main(["run", "orbit", "--out", str(tmp_path), "--quiet"]) == 128 + signal.SIGHUP
    assert capsys.readouterr().err.strip().splitlines() == [
        "vnav-demo: error: stopped by SIGHUP; no partial file was kept"
    ]


@pytest.mark.parametrize("signame", ["SIGTERM", "SIGHUP"])
def test_sigterm_and_sighup_end_the_run_like_ctrl_c(tmp_path, signame, first_pair):
    """A signal mid-run: exit 128 + N, nothing partial kept, the previous pair untouched."""
    import signal
    import time

    signum = getattr(signal, signame)
    before = _first_pair(tmp_path, first_pair)
    proc = subprocess.Popen(
        [sys.executable, "-m", "scenarios.cli", "run", "orbit", "--out", str(tmp_path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    from scenarios.record import outputs

    writing = outputs.temp_path(tmp_path / "orbit.rrd", pid=proc.pid)
    deadline = time.monotonic() + 60
    while not writing.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert writing.exists(), "the run never started writing"
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signum, err
    assert err.strip().splitlines() == [
        f"vnav-demo: error: stopped by {signame}; no partial file was kept"
    ]
    assert {k: v for k, v in _files(tmp_path).items() if not k.startswith(".")} == before


def test_closed_pipe_ends_quietly_and_the_runs_still_write(tmp_path):
    cmd = f"{sys.executable} -m scenarios.cli"
    listing = subprocess.run(
        f"{cmd} list | head -1", shell=True, capture_output=True, text=True, timeout=60
    )
    assert listing.stdout.startswith("frame-problem") and listing.stderr == ""
    run = subprocess.run(
        f"{cmd} run frame-problem yaw-sweep --duration 1.5 --out {tmp_path} | head -1; "
        "exit ${PIPESTATUS[0]}",
        shell=True,
        executable="/bin/bash",
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0 and run.stderr == "", run.stderr
    assert {"yaw-sweep.rrd", "yaw-sweep.json"} <= {p.name for p in tmp_path.iterdir()}


# ---------------------------------------------------------------- bad input, refused first


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--seed", "-5"], r"--seed must be in \[0, 2\*\*63 - 1\], got -5"),
        (["--max-ticks", "10"], r"frame-problem: 51 camera ticks .* more than --max-ticks 10"),
    ],
)
def test_bad_run_options_exit_2_before_anything_is_made(tmp_path, capsys, args, message):
    out = tmp_path / "not-made"
    assert main(["run", "frame-problem", "--out", str(out), *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and re.search(message, err), err
    assert not out.exists()


def _file_with(tmp_path: Path, old: str, new: str) -> Path:
    assert old in PITCH_90_TOML
    path = tmp_path / "s.toml"
    path.write_text(PITCH_90_TOML.replace(old, new, 1))
    return path


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (
            "camera_rate_hz = 5.0",
            "camera_rate_hz = 1" + "0" * 400,
            r"camera_rate_hz: must be a finite number",
        ),
        (
            "pitch_down_deg = 0.0",
            "pitch_down_deg = 1" + "0" * 400,
            r"camera\.pitch_down_deg: must be a finite number, got an integer of \d+ bits",
        ),
        (
            "camera_rate_hz = 5.0",
            "camera_rate_hz = 250.0",
            r"camera_rate_hz: must be at most the physics rate, 200 Hz",
        ),
        (
            "[[checks]]",
            "[timing]\npose_rate_hz = 400.0\n\n[[checks]]",
            r"timing\.pose_rate_hz: must be at most the physics rate, 200 Hz",
        ),
        (
            "[[checks]]",
            "[timing]\nimage_latency_s = -0.01\n\n[[checks]]",
            r"timing\.image_latency_s: must be >= 0",
        ),
        (
            "[[checks]]",
            "[timing]\ncamera_clock_offset_s = 1e300\n\n[[checks]]",
            r"timing\.camera_clock_offset_s: must be <= 5",
        ),
        (
            "[[checks]]",
            "[timing]\nlatency_s = 0.1\n\n[[checks]]",
            r"timing\.latency_s: unknown key",
        ),
        (
            "[[checks]]",
            "[noise]\nattitude_std_deg = 1e160\n\n[[checks]]",
            r"noise\.attitude_std_deg: must be <= 180",
        ),
        (
            "[[checks]]",
            "[noise]\nposition_std_m = 1e200\n\n[[checks]]",
            r"noise\.position_std_m: must be <= 100",
        ),
        (
            "[[checks]]",
            "[noise]\npixel_std_px = 4.0\n\n[[checks]]",
            r"noise\.pixel_std_px: renamed; write noise\.intensity_std_grey \(the same figure: "
            r"8-bit grey levels, not pixels\)$",
        ),
        (
            "position_w = [1.5, 0.5, 0.0]",
            "position_w = [1e300, 0.5, 0.0]",
            r"cones\[0\]\.position_w\[0\]: must be <= 1000",
        ),
        (
            "[0.0, 0.0, 4.0], rpy_deg = [0.0, 45.0, 0.0]",
            "[0.0, 0.0, 4e300], rpy_deg = [0.0, 45.0, 0.0]",
            r"keyframes\[0\]\.position_w\[2\]: must be <= 1000",
        ),
        (
            'name = "pitch-ninety"',
            f'name = "{"n" * 236}"',
            r"name: must be at most 100 characters, got 236",
        ),
        (
            'kind = "detection_rate"\nlimit = 0.95',
            'kind = "detection_rate"\nlimit_m = 0.95',
            r"checks\[1\]\.limit_m: detection_rate's limit is a fraction, not metres; give it",
        ),
    ],
)
def test_absurd_numbers_and_names_exit_2_one_line(tmp_path, capsys, old, new, message):
    out = tmp_path / "out"
    assert main(["run", str(_file_with(tmp_path, old, new)), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and re.search(message, err), err
    assert not out.exists()


def test_error_bound_on_a_method_without_a_bound_is_refused(tmp_path, capsys):
    path = _file_with(
        tmp_path,
        'kind = "max_error"\nmethod = "depth_image"',
        'kind = "error_bound"\nmethod = "naive"',
    )
    assert main(["run", str(path), "--out", str(tmp_path / "out")]) == 2
    assert "naive has no accuracy bound to check" in capsys.readouterr().err


def test_scenario_files_that_are_not_regular_files_are_refused(tmp_path, capsys):
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)
    for path, message in ((fifo, "not a regular file"), ("/dev/zero", "not a regular file")):
        assert main(["run", str(path), "--out", str(tmp_path / "out")]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
    big = tmp_path / "big.toml"
    big.write_text("# " + "x" * 1_000_001 + "\n")
    assert main(["run", str(big), "--out", str(tmp_path / "out")]) == 2
    assert "larger than 1000000 bytes" in capsys.readouterr().err


def test_a_bare_name_is_the_builtin_even_beside_a_file_of_that_name(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    Path("frame-problem").write_text("not toml at all [")
    assert main(["run", "frame-problem", "--out", "out", "--quiet", "--duration", "1.5"]) == 0
    assert main(["run", "./frame-problem", "--out", "out"]) == 2
    assert "invalid TOML" in capsys.readouterr().err


def test_a_second_run_into_the_same_directory_is_refused(tmp_path, capsys):
    from scenarios.record import outputs

    with outputs.directory_lock(tmp_path):  # another run holds it (flock is per open file)
        assert main(["run", "frame-problem", "--out", str(tmp_path), "--duration", "0.5"]) == 2
    assert "another vnav-demo command is writing into" in capsys.readouterr().err


DEEP = "[" * 3000 + "]" * 3000


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (
            'mode = "kinematic"',
            'mode = ["kinematic"]',
            r"flight\.mode: must be \"kinematic\", .* or \"navigate\", got \['kinematic'\]",
        ),
        ('mode = "kinematic"', "mode = { a = 1 }", r"flight\.mode: must be .*, got \{'a': 1\}"),
        (
            'kind = "detection_rate"',
            'kind = ["detection_rate"]',
            r"checks\[1\]\.kind: must be one of \['max_error', .*got \['detection_rate'\]",
        ),
        ('kind = "detection_rate"', "kind = { x = 1 }", r"checks\[1\]\.kind: must be one of"),
        (
            'method = "depth_image"',
            'method = ["depth_image"]',
            r"checks\[0\]\.method: must be one of \['depth_image', .*got \['depth_image'\]",
        ),
        # An empty array where a table belongs was read as the empty table.
        ("camera_rate_hz = 5.0", "camera_rate_hz = 5.0\nnoise = []", r"noise: must be a table"),
        ("camera_rate_hz = 5.0", "camera_rate_hz = 5.0\ntiming = 0", r"timing: must be a table"),
        (
            'description = "nose straight down over a cone"',
            f"description = {DEEP}",
            r"s\.toml: line 2: description: tables and arrays nested more than 16 deep$",
        ),
        (
            "limit = 0.95",
            "limit = 0.95\nx = " + "{ a = " * 400 + "1" + " }" * 400,
            r"s\.toml: line \d+: checks\.x: tables and arrays nested more than 16 deep$",
        ),
        (
            'description = "nose straight down over a cone"',
            "description = " + "[" * 20 + "]" * 20,
            r"s\.toml: description(\[0\]){16}: tables and arrays nested more than 16 deep$",
        ),
        (
            "fovy_deg = 60.0",
            "fovy_deg = 1e-300",
            r"camera: CameraConfig\.fovy_deg must be in \[1, 170\] degrees, got 1e-300$",
        ),
        ("fovy_deg = 60.0", "fovy_deg = 179.9999", r"CameraConfig\.fovy_deg must be in \[1, 170\]"),
    ],
)
def test_wrong_types_and_deep_nesting_exit_2_naming_the_key_in_run_and_sweep(
    tmp_path, capsys, old, new, message
):
    """The same scenario file through ``run`` and as a sweep's scenario: one line, exit 2."""
    path = _file_with(tmp_path, old, new)
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and re.search(message, err.rstrip("\n")), err
    assert not out.exists()
    sweep = tmp_path / "sweep.toml"
    sweep.write_text('scenario = "s.toml"\n')
    assert main(["sweep", str(sweep), "--out", str(out), "--workers", "0"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and re.search(message, err.rstrip("\n")), err
    assert "sweep.toml: scenario: " in err and not out.exists()


@pytest.mark.parametrize(
    ("grid", "message"),
    [
        (
            '"flight.keyframes.1.t" = [1979-05-27]',
            r"grid\.flight\.keyframes\.1\.t\[0\]: a TOML date",
        ),
        ('"duration_s" = [2.0, 07:32:00]', r"grid\.duration_s\[1\]: a TOML time is not"),
        (
            '"flight.keyframes.².t" = [1.0]',
            r"flight\.keyframes\.²\.t: flight\.keyframes is a list of 3; index it with a number",
        ),
        (f'"duration_s" = {DEEP}', r"line 3: grid\.\"duration_s\": tables and arrays nested"),
        (f'"noise.{".a" * 3000}" = [1.0]', r"a path of 3002 parts; a scenario nests at most 16"),
    ],
)
def test_bad_sweep_grids_exit_2_in_one_line(tmp_path, capsys, grid, message):
    (tmp_path / "s.toml").write_text(PITCH_90_TOML)
    sweep = tmp_path / "sweep.toml"
    sweep.write_text(f'scenario = "s.toml"\n[grid]\n{grid}\n')
    out = tmp_path / "out"
    assert main(["sweep", str(sweep), "--out", str(out), "--workers", "0"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and re.search(message, err), err
    assert not out.exists()


def test_a_lock_file_taken_by_a_directory_is_one_line_exit_2(tmp_path):
    """The directory's lock name taken by a directory: no run can lock it; said in one line."""
    from scenarios.record import outputs

    (tmp_path / outputs.LOCK_NAME).mkdir()
    proc = subprocess.run(
        [sys.executable, "-m", "scenarios.cli", "run", "frame-problem", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert outputs.LOCK_NAME in proc.stderr and "is a directory" in proc.stderr.lower()
    assert [p.name for p in tmp_path.iterdir()] == [outputs.LOCK_NAME]


@pytest.mark.parametrize("which", ["truth", "pnp"])
def test_export_name_taken_by_a_directory_is_refused_before_running(tmp_path, capsys, which):
    (tmp_path / f"frame-problem.{which}.tum").mkdir()
    args = ["run", "frame-problem", "--export", "tum", "--out", str(tmp_path), "--quiet"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is a directory" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"frame-problem.{which}.tum"]


def test_a_dead_runs_commit_that_cannot_be_ended_stops_the_run(tmp_path, capsys, monkeypatch):
    """Writing over a pair whose killed commit is not ended could bring the dead run's files
    back later: the run stops first (one line, exit 3, nothing written)."""
    import errno

    from scenarios.record import outputs

    def cannot(out_dir):
        raise PermissionError(errno.EACCES, "Permission denied", str(out_dir / "x"))

    monkeypatch.setattr(outputs, "remove_stale_partials", cannot)
    assert main(["run", "frame-problem", "--out", str(tmp_path), "--duration", "0.5"]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot end a dead run's work" in err
    assert [p.name for p in tmp_path.iterdir()] == [outputs.LOCK_NAME]
