"""A user's estimator judged beside the built-ins: ``vnav.plugin`` and ``vnav-demo run
--estimator``. Every run is frame-problem cut short, through the command line."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import signal
import sys
import textwrap
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest
from user_functions import SHARED

from scenarios import pipeline
from scenarios.cli import main
from scenarios.scenario import builtin
from vnav import quat, so3
from vnav.estimators import NoEstimate
from vnav.methods import METHOD_NAMES, METHODS, active_methods, extended
from vnav.plugin import (
    Failure,
    PluginEstimator,
    load_estimator,
    plugin_method,
    reference_estimate,
)

DURATION = ["--duration", "2"]

USER_FUNCTIONS = (
    textwrap.dedent("""\
    import math
    import time

    import numpy as np

    from vnav.plugin import reference_estimate


""")
    + SHARED
    + textwrap.dedent("""\


    def quits(obs):
        raise SystemExit(3)


    def flat(obs):
        return np.zeros((3, 1))


    def not_finite(obs):
        return [math.nan, 0.0, 0.0]


    def words(obs):
        return "here"


    def from_quaternion_and_euler(obs):
        # The chain again from the quaternion and from the angles (independent of T_w_b's R).
        x, y, z, w = obs.quat_w_b_xyzw
        R_q = np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ])
        roll, pitch, yaw = np.radians(obs.rpy_w_b_deg)
        c, s = math.cos, math.sin
        Rz = np.array([[c(yaw), -s(yaw), 0], [s(yaw), c(yaw), 0], [0, 0, 1]])
        Ry = np.array([[c(pitch), 0, s(pitch)], [0, 1, 0], [-s(pitch), 0, c(pitch)]])
        Rx = np.array([[1, 0, 0], [0, c(roll), -s(roll)], [0, s(roll), c(roll)]])
        assert np.allclose(R_q, Rz @ Ry @ Rx, atol=1e-12)
        assert np.allclose(obs.K @ obs.p_c / obs.depth_m, [*obs.uv, 1.0], atol=1e-9)
        p_b = obs.T_b_c[:3, :3] @ obs.p_c + obs.T_b_c[:3, 3]
        return R_q @ p_b + obs.T_w_b[:3, 3]


    def sleeps(obs):
        time.sleep(1.0)
        return reference_estimate(obs)


    def a_bit_slow(obs):
        time.sleep(0.03)
        return reference_estimate(obs)


    NOT_A_FUNCTION = 3
""")
)


@pytest.fixture
def user_file(tmp_path):
    path = tmp_path / "mine.py"
    path.write_text(USER_FUNCTIONS, encoding="utf-8")
    return path


def _run(tmp_path, *specs: str) -> tuple[int, dict]:
    out = tmp_path / "out"
    args = ["run", "frame-problem", "--out", str(out), "--quiet", *DURATION]
    for spec in specs:
        args += ["--estimator", spec]
    status = main(args)
    return status, json.loads((out / "frame-problem.json").read_text())


def _check(report: dict, method: str) -> dict:
    return next(c for c in report["checks"] if c["name"].startswith(f"{method} "))


def test_reference_solution_passes_with_depth_images_errors(tmp_path):
    """The reference solution (module spec) passes its check, with depth_image's statistics."""
    status, report = _run(tmp_path, "vnav.plugin:reference_estimate")
    assert status == 0
    user = report["methods"]["user:reference_estimate"]
    depth = report["methods"]["depth_image"]
    assert user["position_error_m"]["count"] > 0
    assert user["position_error_m"] == depth["position_error_m"]
    assert user["by_range"] == depth["by_range"]
    assert _check(report, "user:reference_estimate")["outcome"] == "passed"
    assert report["estimators"]["user:reference_estimate"]["failures"] == {}
    assert report["estimators"]["user:reference_estimate"]["diagnosis"]["verdict"] == "correct"
    assert active_methods() is METHODS  # the extension ends with the run


def test_reference_errors_equal_depth_image_errors_per_detection():
    """Detection by detection, to 1e-12 m: ``p_c`` is the depth_image estimate brought into
    the camera frame (``R_w_c^T (p_w - t_w_c)``) and the chain brings it back, so the two
    differ by rounding only (a few ulps of coordinates of tens of metres, ~1e-14 m)."""
    spec = builtin.load("frame-problem")
    spec = dataclasses.replace(spec, duration_s=2.0)
    user = plugin_method("vnav.plugin:reference_estimate")
    with extended([user]):
        result = pipeline.run(spec).result
    pairs = [
        (d.errors_m["depth_image"], d.errors_m[user.name])
        for t in result.ticks
        for d in t.detections
        if "depth_image" in d.errors_m
    ]
    assert pairs
    np.testing.assert_allclose(*np.array(pairs).T, rtol=0.0, atol=1e-12)


def test_quaternion_angles_and_pixel_agree_with_the_pose(tmp_path, user_file):
    """A function that rebuilds R_w_b from ``quat_w_b_xyzw`` and from ``rpy_w_b_deg``
    (Rz Ry Rx, written out here) and checks ``uv`` against ``K p_c``: passes, no failure."""
    status, report = _run(tmp_path, f"{user_file}:from_quaternion_and_euler")
    assert status == 0, report["estimators"]
    assert report["estimators"]["user:from_quaternion_and_euler"]["failures"] == {}


def test_transposed_rotation_fails_its_check(tmp_path, user_file, monkeypatch, capsys):
    """A function in a file with the rotation transposed: its check fails, exit 1."""
    monkeypatch.chdir(tmp_path)
    status = main(
        ["run", "frame-problem", "--out", "out", *DURATION, "--estimator", "mine.py:transposed"]
    )
    printed = capsys.readouterr().out
    assert status == 1
    assert "FAILED  user:transposed every error <= max(5 cm, 1% of range)" in printed
    report = json.loads((tmp_path / "out" / "frame-problem.json").read_text())
    check = _check(report, "user:transposed")
    assert check["outcome"] == "failed"
    # Independent of the check: the worst error is far beyond 1% of range.
    assert report["methods"]["user:transposed"]["position_error_m"]["max"] > 0.5
    assert _check(report, "depth_image")["outcome"] == "passed"  # the built-ins unaffected
    # The doctor (vnav.diagnose) names the mistake, in the report and under the table.
    diagnosis = report["estimators"]["user:transposed"]["diagnosis"]
    assert (diagnosis["verdict"], diagnosis["mistake"]) == ("mistake", "rotation transposed")
    assert diagnosis["residual_m"] < 1e-9 < 0.5 < diagnosis["correct_residual_m"]
    assert "user:transposed: " in printed and "rotation transposed" in printed


def test_failing_functions_are_reported_and_the_run_goes_on(tmp_path, user_file, capsys):
    """Raising (an exit() too), wrong shape, NaN, not an array: failures of that function,
    counted with the first message and the ticks; its check fails; None always: no estimate,
    no data; exit 1; the built-ins' results as without them."""
    names = ["raises", "quits", "flat", "not_finite", "words", "nothing"]
    status, report = _run(tmp_path, *(f"{user_file}:{n}" for n in names))
    assert status == 1
    assert "Traceback" not in capsys.readouterr().err
    _, plain = _run(tmp_path / "plain")
    for m in METHOD_NAMES:
        assert report["methods"][m] == plain["methods"][m]
    called = report["estimators"]["user:raises"]["calls"]
    assert called == report["methods"]["depth_image"]["position_error_m"]["count"] > 0
    expected = {
        "raises": ("raised", "RuntimeError: no idea at t = "),
        "quits": ("raised", "SystemExit: 3"),
        "flat": ("wrong_shape", "returned shape (3, 1), not (3,)"),
        "not_finite": ("not_finite", "returned [nan, 0.0, 0.0]"),
        "words": ("not_array", "returned a str, not an array"),
    }
    for name, (kind, message) in expected.items():
        entry = report["estimators"][f"user:{name}"]
        assert list(entry["failures"]) == [kind]
        failure = entry["failures"][kind]
        assert failure["count"] == called
        assert failure["first_message"].startswith(message)
        assert failure["ticks"] == list(range(report["camera_ticks"]))
        assert _check(report, f"user:{name}")["outcome"] == "failed"
        assert report["methods"][f"user:{name}"]["no_estimate"] == {"function_error": called}
    first = report["estimators"]["user:raises"]["failures"]["raised"]["first_message"]
    assert first == "RuntimeError: no idea at t = 0.000"  # the first, not the last
    none = report["estimators"]["user:nothing"]
    assert none["returned_none"] == called and none["failures"] == {}
    check = _check(report, "user:nothing")
    assert check["outcome"] == "no data"
    assert "the user's function returned None" in check["reason"]


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("no_such_module_here:fn", r"no_such_module_here does not import: No module named"),
        ("vnav.plugin:no_such_function", r"vnav\.plugin has no attribute 'no_such_function'"),
        ("vnav.plugin:USER_PREFIX", r"vnav\.plugin\.USER_PREFIX is not callable"),
        ("{dir}/missing.py:fn", r"missing\.py does not import: no such file"),
        ("{dir}/broken.py:fn", r"broken\.py does not import: invalid syntax"),
        ("{dir}/fails.py:fn", r"fails\.py does not import: no camera on this machine"),
        ("{dir}/mine.py:NOT_A_FUNCTION", r"NOT_A_FUNCTION is not callable"),
        ("vnav.plugin", r"expected package\.module:function or path/to/file\.py:function"),
    ],
)
def test_bad_spec_exit_2_one_line_nothing_written(tmp_path, user_file, capsys, spec, message):
    (tmp_path / "broken.py").write_text("def fn(:\n", encoding="utf-8")
    fails = "raise RuntimeError('no camera on this machine')\ndef fn(obs):\n    return None\n"
    (tmp_path / "fails.py").write_text(fails, encoding="utf-8")
    out = tmp_path / "out"
    args = ["run", "frame-problem", "--out", str(out), "--estimator", spec.format(dir=tmp_path)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert "--estimator" in err
    assert re.search(message, err), err
    assert not out.exists() or not any(out.iterdir())


def test_load_estimator_raises_value_error_naming_the_problem():
    assert load_estimator("vnav.plugin:reference_estimate") is reference_estimate
    with pytest.raises(ValueError, match="has no attribute 'nope'"):
        load_estimator("vnav.plugin:nope")


def test_observation_arrays_are_read_only_and_consistent(tmp_path):
    """What the function is given, checked against vnav's own quaternion and angle code."""
    seen = []
    user = plugin_method("vnav.plugin:reference_estimate")
    user.estimator.fn = lambda obs: seen.append(obs) or reference_estimate(obs)
    spec = builtin.load("frame-problem")
    spec = dataclasses.replace(spec, duration_s=0.5)
    with extended([user]):
        pipeline.run(spec)
    assert seen
    obs = seen[-1]
    for name in ("p_c", "uv", "K", "T_w_b", "quat_w_b_xyzw", "rpy_w_b_deg", "T_b_c"):
        with pytest.raises(ValueError, match="read-only"):
            getattr(obs, name)[0] = 0.0
    np.testing.assert_allclose(quat.to_matrix(obs.quat_w_b_xyzw), obs.T_w_b[:3, :3], atol=1e-12)
    np.testing.assert_allclose(
        so3.from_rpy(*np.radians(obs.rpy_w_b_deg)), obs.T_w_b[:3, :3], atol=1e-12
    )
    assert obs.depth_m == obs.p_c[2] > 0.0


def test_the_conventions_worked_example_and_its_code_agree():
    """docs/CONVENTIONS.md's worked example, through its own code block and the reference."""
    from pathlib import Path

    from vnav import se3
    from vnav.frames import R_FLU_RDF
    from vnav.plugin import PluginObservation

    text = (Path(__file__).resolve().parents[1] / "docs/CONVENTIONS.md").read_text()
    section = text.split("## Your own estimator", 1)[1].split("\n## ", 1)[0]
    (code,) = re.findall(r"```python\n(.*?)```", section, re.S)
    namespace: dict = {}
    exec(code, namespace)
    R_w_b = so3.rot_z(np.pi / 2)
    obs = PluginObservation(
        p_c=np.array([1.0, 0.5, 6.0]),
        uv=np.zeros(2),
        depth_m=6.0,
        K=np.eye(3),
        T_w_b=se3.make(R_w_b, [5.0, 0.0, 4.0]),
        quat_w_b_xyzw=quat.from_matrix(R_w_b),
        rpy_w_b_deg=np.degrees(so3.to_rpy(R_w_b)),
        T_b_c=se3.make(R_FLU_RDF, [0.1, 0.0, 0.0]),
        t_s=0.0,
    )
    np.testing.assert_allclose(R_FLU_RDF, [[0, 0, 1], [-1, 0, 0], [0, -1, 0]])
    np.testing.assert_allclose(obs.quat_w_b_xyzw, [0, 0, 0.5**0.5, 0.5**0.5], atol=1e-12)
    np.testing.assert_allclose(obs.rpy_w_b_deg, [0, 0, 90], atol=1e-12)
    expected = [6.0, 6.1, 3.5]
    np.testing.assert_allclose(namespace["my_estimate"](obs), expected, atol=1e-12)
    np.testing.assert_allclose(reference_estimate(obs), expected, atol=1e-12)


def test_recording_draws_the_users_estimates_and_errors(tmp_path, user_file):
    """The recording has the user's estimates, error segments and error plot, as a built-in's:
    the reference's estimates on depth_image's (float32 in the file), the transposed one's
    error per tick as its mean over the tick's detections in the report's run."""
    from helpers import read_rows

    out = tmp_path / "out"
    specs = ["vnav.plugin:reference_estimate", f"{user_file}:transposed"]
    args = ["run", "frame-problem", "--out", str(out), "--quiet", *DURATION]
    assert main([*args, *(a for s in specs for a in ("--estimator", s))]) == 1
    rrd = out / "frame-problem.rrd"

    def points(entity: str) -> dict[int, np.ndarray]:
        return {
            r["tick"]: np.array(r["Points3D:positions"]).reshape(-1, 3)
            for r in read_rows(rrd, entity)
            if "tick" in r
        }

    depth = points("world/cones/estimate/depth_image")
    reference = points("world/cones/estimate/user_reference_estimate")
    assert reference.keys() == depth.keys() and any(p.size for p in depth.values())
    for tick, p_w in depth.items():
        np.testing.assert_allclose(reference[tick], p_w, atol=1e-5)
    assert read_rows(rrd, "world/cones/error/user_transposed")
    report = json.loads((out / "frame-problem.json").read_text())
    worst = max(
        r["Scalars:scalars"][0]
        for r in read_rows(rrd, "metrics/error/user_transposed")
        if "tick" in r and np.isfinite(r["Scalars:scalars"][0])
    )
    # One detection per tick here: the per-tick mean is the detection's error.
    assert report["detections"] == report["camera_ticks"]
    assert worst == pytest.approx(report["methods"]["user:transposed"]["position_error_m"]["max"])
    assert not read_rows(rrd, "metrics/nees/user_transposed")  # no covariance claimed


def test_extended_adds_for_the_block_only_and_refuses_a_name_twice():
    user = plugin_method("vnav.plugin:reference_estimate")
    with pytest.raises(RuntimeError), extended([user]) as methods:
        assert methods == (*METHODS, user) and active_methods() is methods
        raise RuntimeError("a run that fails")
    assert active_methods() is METHODS
    with pytest.raises(ValueError, match="two methods are named 'user:reference_estimate'"):
        with extended([user, user]):
            pass
    assert active_methods() is METHODS


def test_two_functions_of_one_name_exit_2(tmp_path, user_file, capsys):
    other = tmp_path / "other"
    other.mkdir()
    (other / "mine.py").write_text(USER_FUNCTIONS, encoding="utf-8")
    out = tmp_path / "out"
    specs = [f"{user_file}:raises", f"{other / 'mine.py'}:raises"]
    args = ["run", "frame-problem", "--out", str(out)]
    assert main([*args, *(a for s in specs for a in ("--estimator", s))]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "are both user:raises" in err
    assert not out.exists() or not any(out.iterdir())


def test_a_module_in_the_current_directory_is_found(tmp_path, monkeypatch):
    """``module:function`` from the directory the user runs in, as ``python -m`` finds it."""
    (tmp_path / "chain_in_cwd_for_vnav_test.py").write_text(USER_FUNCTIONS, encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "path", [p for p in sys.path if p not in ("", ".")])
    monkeypatch.delitem(sys.modules, "chain_in_cwd_for_vnav_test", raising=False)
    fn = load_estimator("chain_in_cwd_for_vnav_test:transposed")
    assert fn.__name__ == "transposed" and fn.__module__ == "chain_in_cwd_for_vnav_test"


def test_extending_the_methods_holds_for_its_own_thread_only():
    """Inside one thread's ``extended`` block another thread still sees the built-ins, and a
    block of its own there adds only its method."""
    import threading

    mine = plugin_method("vnav.plugin:reference_estimate")
    inside, outside = threading.Event(), threading.Event()
    seen = {}

    def other() -> None:
        inside.wait(timeout=30)
        seen["plain"] = active_methods()
        other_method = dataclasses.replace(mine, name="user:other")
        with extended([other_method]) as methods:
            seen["own"] = [m.name for m in methods]
        outside.set()

    thread = threading.Thread(target=other)
    thread.start()
    with extended([mine]):
        inside.set()
        assert outside.wait(timeout=30)
        assert [m.name for m in active_methods()][-1] == mine.name
    thread.join(timeout=30)
    assert seen["plain"] is METHODS
    assert seen["own"] == [*(m.name for m in METHODS), "user:other"]
    assert active_methods() is METHODS


# ------------------------------------------------------------------ time


def test_a_function_that_never_estimates_fails_its_check(tmp_path, user_file, capsys):
    """None at every detection: nothing to judge, so its check has no data, which fails the
    run (exit 1), as a built-in without estimates would."""
    status, report = _run(tmp_path, f"{user_file}:nothing")
    assert status == 1
    entry = report["estimators"]["user:nothing"]
    assert entry["calls"] == entry["returned_none"] > 0 and entry["failures"] == {}
    assert entry["diagnosis"] is None
    check = _check(report, "user:nothing")
    assert check["outcome"] == "no data" and not report["passed"]
    assert "Traceback" not in capsys.readouterr().err


def test_a_slow_function_is_stopped_at_its_time_limit(tmp_path, user_file, capsys):
    """A function sleeping 1 s a call, limited to 0.05 s: its first call is stopped, it is not
    called again, and the run ends in about the time it takes without it (20 calls would take
    20 s); exit 1, no traceback; the alarm is disarmed and SIGALRM's handler put back."""
    handler = signal.getsignal(signal.SIGALRM)
    out = tmp_path / "out"
    args = ["run", "frame-problem", "--out", str(out), *DURATION]
    started_s = time.perf_counter()
    status = main([*args, "--estimator", f"{user_file}:sleeps", "--estimator-timeout-s", "0.05"])
    wall_s = time.perf_counter() - started_s
    captured = capsys.readouterr()
    assert status == 1 and "Traceback" not in captured.err
    assert signal.getsignal(signal.SIGALRM) is handler
    assert signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)
    report = json.loads((out / "frame-problem.json").read_text())
    n = report["methods"]["depth_image"]["position_error_m"]["count"]
    assert n == report["camera_ticks"] > 2
    assert wall_s < 0.4 * n  # each call would sleep 1 s
    entry = report["estimators"]["user:sleeps"]
    assert entry["timeout_s"] == 0.05
    assert entry["calls"] == 1 and entry["skipped"] == n - 1
    assert list(entry["failures"]) == ["timed_out"]
    failure = entry["failures"]["timed_out"]
    assert failure["count"] == 1 and failure["ticks"] == [0]
    assert failure["first_message"].startswith("took longer than the 0.05 s limit at t = 0.000 s")
    assert entry["time_s"]["calls"] == 1
    assert 0.05 <= entry["time_s"]["max"] < 0.5  # stopped, not slept through
    assert report["methods"]["user:sleeps"]["no_estimate"] == {
        "function_error": 1,
        "function_stopped": n - 1,
    }
    check = _check(report, "user:sleeps")
    assert check["outcome"] == "failed"
    assert f"failed on 1 of {n} detections, and was not called on {n - 1}" in check["shown"]
    printed = " ".join(captured.out.split())
    assert "user:sleeps failed 1x (timed out), first at tick 0: took longer than the 0.05 s" in (
        printed
    )
    assert f"user:sleeps was not called on the {n - 1} later detections" in printed


def test_a_function_that_swallows_the_alarm_still_times_out():
    """``except BaseException: pass`` around a sleep catches the limit's alarm and returns an
    estimate: the call still took longer than the limit, and is a timeout all the same."""

    def swallows(obs):
        try:
            time.sleep(1.0)
        except BaseException:  # a student's catch-all, the alarm included
            pass
        return reference_estimate(obs)

    estimator = PluginEstimator(swallows, timeout_s=0.05)
    started_s = time.perf_counter()
    assert estimator.estimate(_fake_observation(), np.zeros(3), 0.0) is NoEstimate.FUNCTION_ERROR
    assert time.perf_counter() - started_s < 0.5
    assert estimator.failures.count == {Failure.TIMED_OUT: 1} and estimator.stopped
    assert signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)


def test_slow_functions_say_their_time(tmp_path, user_file, capsys):
    """Each call is timed: a function of 30 ms a call is said to be slow under the table, the
    reference (microseconds) is not; both have ``time_s`` in the report."""
    out = tmp_path / "out"
    args = ["run", "frame-problem", "--out", str(out), *DURATION]
    specs = [f"{user_file}:a_bit_slow", "vnav.plugin:reference_estimate"]
    status = main([*args, *(a for s in specs for a in ("--estimator", s))])
    printed = " ".join(capsys.readouterr().out.split())
    assert status == 0
    report = json.loads((out / "frame-problem.json").read_text())
    slow = report["estimators"]["user:a_bit_slow"]["time_s"]
    fast = report["estimators"]["user:reference_estimate"]["time_s"]
    n = report["methods"]["depth_image"]["position_error_m"]["count"]
    assert slow["calls"] == fast["calls"] == n > 0
    assert 0.03 <= slow["mean"] <= slow["max"] and slow["total"] >= 0.03 * n
    assert slow["mean"] == pytest.approx(slow["total"] / n, abs=1e-6)
    assert fast["max"] < 0.01
    said = re.search(
        r"user:a_bit_slow took ([\d.]+) ms per call \((\d+) calls, ([\d.]+) (m?s)", printed
    )
    assert said, printed
    assert float(said[1]) == pytest.approx(1e3 * slow["mean"], abs=0.05) and int(said[2]) == n
    assert "user:reference_estimate took" not in printed


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ("0", "--estimator-timeout-s must be a positive number of seconds, got 0.0"),
        ("-1", "--estimator-timeout-s must be a positive number of seconds, got -1.0"),
        ("nan", "--estimator-timeout-s must be a positive number of seconds, got nan"),
        ("inf", "--estimator-timeout-s must be a positive number of seconds, got inf"),
        ("soon", "invalid float value: 'soon'"),
        (None, "--estimator-timeout-s limits an --estimator function: give one"),
    ],
)
def test_bad_timeout_exit_2_one_line(tmp_path, capsys, value, message):
    out = tmp_path / "out"
    args = ["run", "frame-problem", "--out", str(out), "--estimator-timeout-s", value or "1"]
    if value is not None:
        args += ["--estimator", "vnav.plugin:reference_estimate"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and message in err, err
    assert not out.exists() or not any(out.iterdir())


def _fake_observation() -> SimpleNamespace:
    """What ``PluginEstimator.estimate`` reads of a ``vnav.observation.Observation``."""
    exposure = SimpleNamespace(
        T_w_b=np.eye(4), T_b_c=np.eye(4), camera=SimpleNamespace(K=np.eye(3))
    )
    view = SimpleNamespace(camera_coordinates=lambda p_w: np.array([0.0, 0.0, 5.0]))
    return SimpleNamespace(exposure=exposure, view=view)


def _sleeper(seconds: float):
    def fn(obs):
        time.sleep(seconds)
        return reference_estimate(obs)

    return fn


def test_off_the_main_thread_a_slow_call_is_counted_once_it_returns():
    """Python cannot interrupt a call on another thread: it runs to its end, then is a
    timeout (its estimate thrown away), and the function is not called again."""
    estimator = PluginEstimator(_sleeper(0.2), timeout_s=0.05)
    results = []

    def work() -> None:
        obs = _fake_observation()
        results.extend(estimator.estimate(obs, np.zeros(3), float(t)) for t in range(3))

    thread = threading.Thread(target=work)
    thread.start()
    thread.join(timeout=30)
    assert results == [
        NoEstimate.FUNCTION_ERROR,
        NoEstimate.FUNCTION_STOPPED,
        NoEstimate.FUNCTION_STOPPED,
    ]
    f = estimator.failures
    assert f.count == {Failure.TIMED_OUT: 1} and f.calls == 1 and f.skipped == 2
    assert "returned after it" in f.first_message[Failure.TIMED_OUT]
    assert estimator.times.calls == 1 and estimator.times.max_s >= 0.2  # not interrupted
    # A second pass (a calibrated run's) of a stopped function does not call it either.
    again = estimator.second_pass()
    assert again.estimate(_fake_observation(), np.zeros(3), 0.0) is NoEstimate.FUNCTION_STOPPED
    assert estimator.again is again and again.failures.skipped == 1


def test_the_alarm_puts_back_the_previous_handler_and_timer():
    """On the main thread the limit borrows SIGALRM: whoever had it gets it back, with what
    was left of their timer; a fast call leaves no alarm armed either."""
    fired = []

    def mine(signum, frame):
        fired.append(signum)

    previous = signal.signal(signal.SIGALRM, mine)
    try:
        signal.setitimer(signal.ITIMER_REAL, 100.0)
        estimator = PluginEstimator(_sleeper(1.0), timeout_s=0.05)
        started_s = time.perf_counter()
        assert estimator.estimate(_fake_observation(), np.zeros(3), 1.5) is (
            NoEstimate.FUNCTION_ERROR
        )
        assert time.perf_counter() - started_s < 0.5
        assert estimator.failures.count == {Failure.TIMED_OUT: 1}
        assert "at t = 1.500 s (stopped" in estimator.failures.first_message[Failure.TIMED_OUT]
        assert signal.getsignal(signal.SIGALRM) is mine
        left_s, _ = signal.getitimer(signal.ITIMER_REAL)
        assert 98.0 < left_s < 100.0 and not fired
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        fast = PluginEstimator(reference_estimate, timeout_s=0.05)
        p_w = fast.estimate(_fake_observation(), np.zeros(3), 0.0)
        np.testing.assert_allclose(p_w, [0.0, 0.0, 5.0])
        assert signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)
        time.sleep(0.1)
        assert not fired and fast.failures.total == 0
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous)


@pytest.mark.parametrize("timeout_s", [0.0, -1.0, math.nan, math.inf, "1", True])
def test_a_bad_time_limit_is_a_value_error(timeout_s):
    with pytest.raises(ValueError, match="timeout_s"):
        PluginEstimator(reference_estimate, timeout_s=timeout_s)
    with pytest.raises(ValueError, match="timeout_s"):
        plugin_method("vnav.plugin:reference_estimate", timeout_s=timeout_s)
