"""``vnav-demo run`` on worker processes (``--jobs``): the serial command's files, reports and
output, in the scenarios' order; bad ``--jobs``; signals stopping every worker."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from scenarios.cli import main
from scenarios.commands.workers import cost, default_jobs, start_order
from scenarios.scenario import builtin

TINY_TOML = textwrap.dedent("""\
    name = "tiny"
    description = "three camera ticks over a cone"
    camera_rate_hz = 5.0

    [[cones]]
    position_w = [3.0, 0.0, 0.0]

    [flight]
    mode = "kinematic"
    keyframes = [
      { t = 0.0, position_w = [0.0, 0.0, 1.5], rpy_deg = [0.0, 0.0, 0.0] },
      { t = 0.4, position_w = [0.2, 0.0, 1.5], rpy_deg = [0.0, 0.0, 0.0] },
    ]
""")
"""A scenario much shorter than any built-in: it finishes first when run second."""


def _run(where: Path, monkeypatch, capsys, *args: str) -> tuple[int, str, str]:
    """``vnav-demo run ARGS --out out`` in ``where``: status, stdout and stderr."""
    where.mkdir()
    monkeypatch.chdir(where)
    status = main(["run", *args, "--out", "out"])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def _without_durations(text: str) -> str:
    """``run``'s output with its wall and CPU seconds blanked (they differ run to run), the
    lines joined (a longer figure may wrap a line elsewhere)."""
    return re.sub(r"[\d.]+ s, [\d.]+ s CPU", "T", " ".join(text.split()))


def _report(path: Path) -> dict:
    """A report but for what differs between any two runs: the time taken and the
    recording's id."""
    rep = json.loads(path.read_text())
    del rep["timing_s"], rep["recording"]
    return rep


def test_two_workers_write_and_print_what_one_process_does(tmp_path, monkeypatch, capsys):
    """The same files, the same reports (but for timing_s and the recording's id), the same
    output in the scenarios' order, though the second scenario finishes first."""
    (tmp_path / "tiny.toml").write_text(TINY_TOML)
    # frame-problem's whole flight (51 images) against tiny's 3: with a shorter flight the
    # two finish within the workers' start-up and set-up of each other.
    args = ("frame-problem", str(tmp_path / "tiny.toml"))
    serial = _run(tmp_path / "serial", monkeypatch, capsys, *args, "--jobs", "1")
    parallel = _run(tmp_path / "parallel", monkeypatch, capsys, *args, "--jobs", "2")
    a, b = tmp_path / "serial" / "out", tmp_path / "parallel" / "out"
    # Worth testing: on two workers the second scenario was written before the first.
    assert (b / "tiny.json").stat().st_mtime < (b / "frame-problem.json").stat().st_mtime
    assert serial[0] == parallel[0]
    assert sorted(p.name for p in a.iterdir()) == sorted(p.name for p in b.iterdir())
    for name in ("frame-problem.json", "tiny.json"):
        assert _report(a / name) == _report(b / name)
    assert serial[2] == parallel[2] == ""
    assert _without_durations(serial[1]) == _without_durations(parallel[1])
    out = parallel[1]
    assert out.index("frame-problem: ") < out.index("tiny: ") < out.index("2 scenarios:")


def test_the_costliest_scenario_starts_first_then_the_others_in_order():
    """In ``run --all`` the calibration built-in (a third of the command's CPU time) starts
    first, not last alone on one core; the others keep their order."""
    specs = [builtin.load(name) for name in builtin.names()]
    order = start_order(specs)
    assert specs[order[0]].name == "calibration"
    assert all(cost(specs[order[0]]) >= cost(s) for s in specs)
    assert order[1:] == [i for i in range(len(specs)) if i != order[0]]


def test_two_workers_by_default_where_there_are_two_cores_and_two_scenarios(monkeypatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3})
    assert [default_jobs(n) for n in (1, 2, 14)] == [1, 2, 2]
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0})
    assert default_jobs(14) == 1


@pytest.mark.parametrize("value", ["0", "-3"])
def test_jobs_below_one_is_refused_before_anything_is_made(tmp_path, capsys, value):
    out = tmp_path / "not-made"
    assert main(["run", "frame-problem", "--jobs", value, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err == f"vnav-demo: error: --jobs must be a positive number of processes, got {value}\n"
    assert not out.exists()


def test_jobs_not_a_number_is_one_line(tmp_path, capsys):
    assert main(["run", "frame-problem", "--jobs", "two", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "invalid int value: 'two'" in err
    assert not (tmp_path / "o").exists()


def _partials(out: Path) -> dict[str, int]:
    """The recordings being written in ``out``: each scenario's name and its writer's id."""
    found = {}
    for p in out.glob(".vnav-demo.*.rrd.partial"):
        _, _, pid, name = p.name.split(".", 3)
        found[name.removesuffix(".rrd.partial")] = int(pid)
    return found


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # A zombie (ended, not yet reaped by its parent) has stopped all the same.
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


def _command(args: list[str]) -> subprocess.Popen:
    """``vnav-demo ARGS`` in a process of its own, its output read as text."""
    return subprocess.Popen(
        [sys.executable, "-m", "scenarios.cli", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _start_two(out: Path, *more: str) -> tuple[subprocess.Popen, dict[str, int]]:
    """``run orbit calibration`` on two workers, once both are writing."""
    proc = _command(["run", "orbit", "calibration", "--jobs", "2", "--out", str(out), *more])
    deadline = time.monotonic() + 120
    while len(_partials(out)) < 2 and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    writers = _partials(out)
    assert set(writers) == {"orbit", "calibration"}, "the two runs never started writing"
    assert proc.pid not in writers.values() and len(set(writers.values())) == 2
    return proc, writers


def _wait_gone(pids, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while any(_alive(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(_alive(p) for p in pids), "a worker outlived its command"


@pytest.mark.parametrize("signame", ["SIGTERM", "SIGINT"])
def test_a_signal_while_two_workers_run_stops_both_and_keeps_no_partial_file(tmp_path, signame):
    """The command's exit status and one line as on one process; both workers gone, no file
    of theirs left, not even a hidden temporary one."""
    signum = getattr(signal, signame)
    proc, writers = _start_two(tmp_path)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=120)
    said = "interrupted" if signame == "SIGINT" else f"stopped by {signame}"
    assert proc.returncode == 128 + signum, err
    assert err.strip().splitlines() == [f"vnav-demo: error: {said}; no partial file was kept"]
    _wait_gone(writers.values())
    assert sorted(p.name for p in tmp_path.iterdir()) == [".vnav-demo.lock"]


def test_a_signal_after_a_later_scenario_finished_still_prints_its_summary(tmp_path):
    """``run calibration orbit --jobs 2``: orbit, second in order, finishes while calibration
    runs; Ctrl-C then: orbit's summary is printed (its files are committed, as the serial
    command prints each scenario it finished before a signal), calibration leaves nothing."""
    proc = _command(["run", "calibration", "orbit", "--jobs", "2", "--out", str(tmp_path)])
    deadline = time.monotonic() + 120
    while not (tmp_path / "orbit.json").exists():
        assert proc.poll() is None and time.monotonic() < deadline, "orbit never finished"
        time.sleep(0.05)
    # The commit's last steps and the worker's word that it finished take milliseconds; a
    # signal inside them ends the worker before it tells (the serial command says nothing
    # then either: its files are whole, its summary unprinted).
    time.sleep(1.0)
    assert not (tmp_path / "calibration.json").exists(), "calibration finished first"
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signal.SIGINT, err
    assert out.startswith("orbit: ") and f"wrote {tmp_path}/orbit.rrd" in " ".join(out.split())
    assert "calibration:" not in out
    assert err.strip().splitlines() == ["vnav-demo: error: interrupted; no partial file was kept"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        ".vnav-demo.lock",
        "orbit.json",
        "orbit.rrd",
    ]


def test_a_killed_command_takes_its_workers_and_the_next_run_clears_their_files(tmp_path):
    """SIGKILL of the command: its workers stop (SIGTERM when their parent ends), no file
    but hidden temporary ones is left, and the next run in the directory removes those."""
    proc, writers = _start_two(tmp_path)
    proc.kill()
    proc.communicate(timeout=120)  # its workers (and the fork server) hold its stdout too
    _wait_gone(writers.values())
    assert [p.name for p in tmp_path.iterdir() if not p.name.startswith(".")] == []
    args = ["run", str(tmp_path / "tiny.toml"), "--out", str(tmp_path), "--quiet"]
    (tmp_path / "tiny.toml").write_text(TINY_TOML)
    main(args)
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        ".vnav-demo.lock",
        "tiny.json",
        "tiny.rrd",
        "tiny.toml",
    ]


def test_a_worker_killed_outright_leaves_its_scenario_incomplete_and_the_other_runs(tmp_path):
    """SIGKILL of one worker (the out-of-memory killer...): its scenario could not complete
    (exit status 3, one line saying why), the other's files and summary as usual."""
    proc, writers = _start_two(tmp_path, "--duration", "8")
    os.kill(writers["orbit"], signal.SIGKILL)
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == 3, err
    assert err.splitlines() == [
        "vnav-demo: error: orbit: could not complete: its worker process was killed by SIGKILL"
    ]
    assert out.startswith("calibration: ") and "1 incomplete (orbit)" in " ".join(out.split())
    visible = sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith("."))
    assert visible == ["calibration.json", "calibration.rrd"]


def test_a_worker_stopped_by_sigterm_stops_the_command_as_its_own_sigterm(tmp_path):
    """SIGTERM to one worker (a service manager stopping the process group does so too): the
    command stops every worker and ends as on its own SIGTERM."""
    proc, writers = _start_two(tmp_path)
    os.kill(writers["orbit"], signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert err.strip().splitlines() == [
        "vnav-demo: error: stopped by SIGTERM; no partial file was kept"
    ]
    _wait_gone(writers.values())
    assert sorted(p.name for p in tmp_path.iterdir()) == [".vnav-demo.lock"]
