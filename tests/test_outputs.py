"""scenarios.record.outputs: a run's recording and report are put in place together, complete, or
not at all, and the previous pair survives every failure."""

from __future__ import annotations

import errno
import json
import multiprocessing
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from rerun.chunk import RrdReader

from scenarios.record import outputs


@pytest.fixture(scope="module")
def two_pairs(tmp_path_factory) -> list[tuple[bytes, bytes]]:
    """The recording and report of two short built-in runs (seeds 1 and 2), byte for byte."""
    import dataclasses

    from scenarios import pipeline
    from scenarios.scenario import builtin

    spec = dataclasses.replace(builtin.load("frame-problem"), duration_s=0.5)
    pairs = []
    for seed in (1, 2):
        out = tmp_path_factory.mktemp(f"seed{seed}")
        done = pipeline.run(spec, seed=seed, out_dir=out)
        pairs.append((done.rrd_path.read_bytes(), done.json_path.read_bytes()))
    return pairs


@pytest.fixture(scope="module")
def good_rrd(two_pairs) -> bytes:
    """The bytes of a complete recording (a short built-in run)."""
    return two_pairs[0][0]


def _pair(tmp_path: Path, rrd: bytes, text: str = '{"new": true}\n') -> outputs.OutputPair:
    pair = outputs.OutputPair(tmp_path / "s.rrd", tmp_path / "s.json")
    pair.rrd_tmp.write_bytes(rrd)
    pair.write_json(text)
    return pair


def _old_pair(tmp_path: Path) -> None:
    (tmp_path / "s.rrd").write_bytes(b"old recording")
    (tmp_path / "s.json").write_text("old report")


def test_commit_puts_both_in_place_and_leaves_nothing_else(tmp_path, good_rrd):
    _old_pair(tmp_path)
    _pair(tmp_path, good_rrd).commit()
    assert (tmp_path / "s.rrd").read_bytes() == good_rrd
    assert (tmp_path / "s.json").read_text() == '{"new": true}\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.json", "s.rrd"]


@pytest.mark.parametrize("cut", ["footer", "half", "empty"])
def test_truncated_recording_is_refused_and_the_old_pair_kept(tmp_path, good_rrd, cut):
    """What a full disk leaves: the file stops short (no footer)."""
    size = {"footer": len(good_rrd) - 10, "half": len(good_rrd) // 2, "empty": 0}[cut]
    _old_pair(tmp_path)
    pair = _pair(tmp_path, good_rrd[:size])
    with pytest.raises(outputs.OutputError, match=r"s\.rrd.*(incomplete|does not read back)"):
        pair.commit()
    assert (tmp_path / "s.rrd").read_bytes() == b"old recording"
    assert (tmp_path / "s.json").read_text() == "old report"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.json", "s.rrd"]


def test_a_failed_move_puts_the_old_pair_back(tmp_path, good_rrd, monkeypatch):
    _old_pair(tmp_path)
    pair = _pair(tmp_path, good_rrd)
    real_replace = os.replace

    def replace(src, dst):
        if Path(src) == pair.json_tmp:  # the second file's move fails
            raise OSError(errno.EIO, "injected", str(dst))
        real_replace(src, dst)

    monkeypatch.setattr(outputs.os, "replace", replace)
    with pytest.raises(outputs.OutputError):
        pair.commit()
    monkeypatch.undo()
    assert (tmp_path / "s.rrd").read_bytes() == b"old recording"
    assert (tmp_path / "s.json").read_text() == "old report"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.json", "s.rrd"]


def test_an_interrupt_mid_swap_puts_the_old_pair_back(tmp_path, good_rrd, monkeypatch):
    """SIGTERM and Ctrl-C raise in the main thread between any two renames of the swap."""
    _old_pair(tmp_path)
    pair = _pair(tmp_path, good_rrd)
    real_replace = os.replace

    def replace(src, dst):
        if Path(src) == pair.json_tmp:  # the recording is in place, its report not yet
            raise KeyboardInterrupt
        real_replace(src, dst)

    monkeypatch.setattr(outputs.os, "replace", replace)
    with pytest.raises(KeyboardInterrupt):
        pair.commit()
    monkeypatch.undo()
    assert (tmp_path / "s.rrd").read_bytes() == b"old recording"
    assert (tmp_path / "s.json").read_text() == "old report"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.json", "s.rrd"]


def test_json_write_error_is_an_output_error(tmp_path, monkeypatch):
    pair = outputs.OutputPair(tmp_path / "s.rrd", tmp_path / "s.json")

    def no_space(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(outputs.os, "fsync", no_space)
    with pytest.raises(outputs.OutputError, match=r"s\.json: No space left on device"):
        pair.write_json("{}")


def _exit_at_once() -> None:
    os._exit(0)


def test_stale_partials_of_dead_runs_are_removed_live_ones_kept(tmp_path):
    proc = multiprocessing.get_context("spawn").Process(target=_exit_at_once)
    proc.start()
    proc.join()
    dead = outputs.temp_path(tmp_path / "s.rrd", pid=proc.pid)
    live = outputs.temp_path(tmp_path / "u.rrd", pid=os.getppid())
    keep = tmp_path / "s.rrd"
    for p in (dead, live, keep):
        p.write_bytes(b"x")
    with outputs.temporary(tmp_path / "t.rrd") as mine:  # this process's, in use
        mine.write_bytes(b"x")
        pair = outputs.OutputPair(tmp_path / "v.rrd", tmp_path / "v.json")
        pair.write_json("{}")
        assert outputs.remove_stale_partials(tmp_path) == [dead]
        assert all(p.exists() for p in (mine, live, keep, pair.json_tmp))
    pair.discard()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([live.name, keep.name])


def test_a_dead_runs_export_directories_are_removed_whole(tmp_path):
    """An export's staging directory and a new export directory at its temporary name, left
    by a killed run, go with what they hold; a live run's stay."""
    proc = multiprocessing.get_context("spawn").Process(target=_exit_at_once)
    proc.start()
    proc.join()
    staging = outputs.temp_path(tmp_path / "s.export-euroc", pid=proc.pid)
    new = outputs.temp_path(tmp_path / "s.euroc", pid=proc.pid)
    for top in (staging, new):
        (top / "s.euroc" / "mav0" / "cam0").mkdir(parents=True)
        (top / "s.euroc" / "mav0" / "cam0" / "data.csv").write_text("#timestamp [ns],filename\n")
    with outputs.staging_dir(tmp_path / "t.export-euroc") as mine:
        (mine / "t.euroc").mkdir()
        assert sorted(outputs.remove_stale_partials(tmp_path)) == sorted([staging, new])
        assert (mine / "t.euroc").is_dir()
    assert list(tmp_path.iterdir()) == []


def test_temporary_names_carry_the_program_and_the_file(tmp_path):
    name = outputs.temp_path(tmp_path / "s.rrd", "old", pid=42).name
    assert name == ".vnav-demo.42.s.rrd.old"
    with pytest.raises(ValueError, match="kind must be one of"):
        outputs.temp_path(tmp_path / "s.rrd", "tmp")


def _hold_lock(out_dir: str, ready, release) -> None:
    with outputs.directory_lock(Path(out_dir)):
        ready.set()
        release.wait(30)


def test_a_second_writer_is_refused_while_the_first_holds_the_directory(tmp_path):
    ctx = multiprocessing.get_context("spawn")
    ready, release = ctx.Event(), ctx.Event()
    holder = ctx.Process(target=_hold_lock, args=(str(tmp_path), ready, release))
    holder.start()
    try:
        assert ready.wait(30)
        with pytest.raises(BlockingIOError), outputs.directory_lock(tmp_path):
            pass
    finally:
        release.set()
        holder.join(30)
    with outputs.directory_lock(tmp_path):  # free again
        pass


# ------------------------------------------------- killed at any instant, recovered by the next run

_KILLED_AT = textwrap.dedent("""\
    import json, os, shutil, signal, sys
    from pathlib import Path
    from rerun.chunk import RrdReader  # imported once, before the forks
    from scenarios.record import outputs

    OPERATIONS = ("open", "write", "fsync", "replace", "rename", "unlink", "rmdir")

    def job(stage, out, k, files):
        if stage == "commit":
            pair = outputs.OutputPair(out / "s.rrd", out / "s.json")
            pair.rrd_tmp.write_bytes(Path(files[0]).read_bytes())
            pair.write_json(Path(files[1]).read_text())
            for extra in map(Path, files[2:]):  # an export's file or directory, staged
                staged = out / f"staged-{extra.name}"
                if extra.is_dir():
                    shutil.copytree(extra, staged)
                else:
                    shutil.copyfile(extra, staged)
                pair.add(out / extra.name, staged)
        calls = [0]

        def killing(real):
            def call(*args, **kwargs):
                result = real(*args, **kwargs)
                calls[0] += 1
                if calls[0] == k:
                    os.kill(os.getpid(), signal.SIGKILL)
                return result
            return call

        for name in OPERATIONS:
            setattr(os, name, killing(getattr(os, name)))
        if k == 0:
            os.kill(os.getpid(), signal.SIGKILL)
        if stage == "commit":
            pair.commit()
        else:
            outputs.remove_stale_partials(out)
        return calls[0]

    results = []
    for stage, out, k, files in json.loads(sys.argv[1]):
        pid = os.fork()
        if pid == 0:
            os._exit(min(job(stage, Path(out), k, files), 255))
        status = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])
        results.append(None if status == -signal.SIGKILL else status)
    print(json.dumps(results))
""")
"""Run jobs ``(stage, OUT, K, files)``, each in a process of its own that commits a set into
OUT (``commit``, from ``files``: a recording, its report, then exports: files or directories
added to the commit under their names) or recovers OUT (``recover``),
killed by SIGKILL right after its K-th call of a file operation (K = 0: before the first);
print for each job None if it was killed, else how many such calls it made."""


def _killed_at(jobs: list[tuple[str, Path, int, list[Path]]]) -> list[int | None]:
    """Run ``_KILLED_AT`` on ``jobs``; for each, None if it was killed, else its number of
    file operations."""
    arg = json.dumps([(stage, str(out), k, list(map(str, files))) for stage, out, k, files in jobs])
    proc = subprocess.run(
        [sys.executable, "-c", _KILLED_AT, arg], capture_output=True, text=True, timeout=600
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


EXPORTS = ("s.truth.tum", "s.euroc")
"""The exports committed with each pair: a file and a directory (``_exports``)."""


def _exports(directory: Path, index: int) -> list[Path]:
    """Write run ``index``'s exports into ``directory``: a TUM-like file and a small
    EuRoC-like directory tree, their content naming the run."""
    tum = directory / EXPORTS[0]
    tum.write_text(f"{index}.0 0 0 {index} 0 0 0 1\n")
    mav0 = directory / EXPORTS[1] / "mav0"
    (mav0 / "cam0" / "data").mkdir(parents=True)
    (mav0 / "cam0" / "data.csv").write_text(f"#timestamp [ns],filename\n{index},{index}.png\n")
    (mav0 / "cam0" / "data" / f"{index}.png").write_bytes(bytes([index]) * (100 + index))
    return [tum, directory / EXPORTS[1]]


def _tree(path: Path) -> dict[str, bytes]:
    """A file's bytes, or every file of a directory by its relative path."""
    if path.is_file():
        return {"": path.read_bytes()}
    return {p.relative_to(path).as_posix(): p.read_bytes() for p in path.rglob("*") if p.is_file()}


def _held(out: Path, pairs: list[tuple[bytes, bytes]], exports: bool = False) -> int | None:
    """Which of ``pairs`` ``out`` holds (None: no pair), asserting the files are one whole
    pair (the report names the recording's id), with that run's exports if ``exports``,
    beside the lock and nothing else."""
    names = sorted(p.name for p in out.iterdir())
    if names == [outputs.LOCK_NAME]:
        return None
    assert names == sorted([outputs.LOCK_NAME, "s.json", "s.rrd", *(EXPORTS if exports else ())])
    report = json.loads((out / "s.json").read_text())
    ids = [r.recording_id for r in RrdReader(str(out / "s.rrd")).recordings()]
    assert ids == [report["recording"]["id"]]
    held = ((out / "s.rrd").read_bytes(), (out / "s.json").read_bytes())
    assert held in pairs
    index = pairs.index(held)
    if exports:
        expected = out.parent / f"exports-{index}"
        if not expected.exists():
            expected.mkdir()
            _exports(expected, index)
        for name in EXPORTS:
            assert _tree(out / name) == _tree(expected / name), name
    return index


def _next_run(out: Path) -> None:
    with outputs.directory_lock(out):  # what every run does first
        pass


def _killed_commits(
    tmp_path: Path, pairs, with_old: bool, exports: bool = False
) -> list[tuple[Path, bool]]:
    """A commit of ``pairs[1]`` over ``pairs[0]`` (or into an empty directory), with each
    one's exports if ``exports``, killed at each instant it can be: the directory it leaves,
    and whether the commit ran to its end (the last one does)."""
    src = tmp_path / "new"
    src.mkdir()
    files = [src / "s.rrd", src / "s.json"]
    files[0].write_bytes(pairs[1][0])
    files[1].write_bytes(pairs[1][1])
    if exports:
        files += _exports(src, 1)

    def outs(n: int) -> list[Path]:
        made = []
        for k in range(n):
            made.append(tmp_path / f"killed-{k}-{with_old}")
            made[-1].mkdir()
            if with_old:
                (made[-1] / "s.rrd").write_bytes(pairs[0][0])
                (made[-1] / "s.json").write_bytes(pairs[0][1])
                if exports:
                    _exports(made[-1], 0)
        return made

    (n_calls,) = _killed_at([("commit", outs(1)[0], 1000, files)])
    shutil.rmtree(tmp_path / f"killed-0-{with_old}")
    dirs = outs(n_calls + 2)  # killed before the first call, after each, and not at all
    ends = _killed_at([("commit", out, k, files) for k, out in enumerate(dirs)])
    assert ends == [None] * (n_calls + 1) + [n_calls]
    return [(out, end is not None) for out, end in zip(dirs, ends, strict=True)]


@pytest.mark.parametrize("with_old", [True, False], ids=["over-a-set", "first-set"])
def test_a_commit_killed_at_any_instant_leaves_one_whole_set(tmp_path, two_pairs, with_old):
    """SIGKILL after each file operation of the commit of a pair and its exports (a TUM file
    and a EuRoC directory tree): the next run into the directory finds the previous set or
    the new one, whole, and no temporary file."""
    held = []
    for out, finished in _killed_commits(tmp_path, two_pairs, with_old, exports=True):
        _next_run(out)
        held.append(_held(out, two_pairs, exports=True))
        assert held[-1] == 1 or not finished
    assert len(held) >= 10  # the commit's file operations, each a kill point
    assert held[0] == (0 if with_old else None)  # killed before its first
    assert held[-1] == 1


def test_a_recovery_killed_at_any_instant_is_finished_by_the_next_run(tmp_path, two_pairs):
    """The recovery itself killed after each of its file operations, for every state a
    killed commit of a pair and its exports leaves: the run after it finds the same whole set
    as an uncut recovery."""
    states = [out for out, _ in _killed_commits(tmp_path, two_pairs, True, exports=True)]
    uncut = [out.with_name(f"{out.name}-recovered") for out in states]
    for out, first in zip(states, uncut, strict=True):
        shutil.copytree(out, first)
    counts = _killed_at([("recover", first, 1000, []) for first in uncut])
    jobs = []
    for out, n_calls in zip(states, counts, strict=True):
        for j in range(n_calls + 2):  # before the first call, after each, and not at all
            jobs.append(("recover", out.with_name(f"{out.name}-recovery-{j}"), j, []))
            shutil.copytree(out, jobs[-1][1])
    ends = iter(_killed_at(jobs))
    copies = iter(job[1] for job in jobs)
    for first, n_calls in zip(uncut, counts, strict=True):
        _next_run(first)
        expected = _files(first)
        assert _held(first, two_pairs, exports=True) is not None
        assert [next(ends) for _ in range(n_calls + 2)] == [None] * (n_calls + 1) + [n_calls]
        for _ in range(n_calls + 2):
            copy = next(copies)
            _next_run(copy)
            assert _files(copy) == expected, copy.name


def _files(directory: Path) -> dict[str, bytes]:
    """Every file under ``directory`` by its relative path."""
    return {
        p.relative_to(directory).as_posix(): p.read_bytes()
        for p in sorted(directory.rglob("*"))
        if p.is_file()
    }


def test_a_dead_run_with_this_process_id_is_recovered(tmp_path, two_pairs):
    """In a container every command may get the same process id: a dead run's files named
    with this process's id are still recovered (they are not this process's own)."""
    states = _killed_commits(tmp_path, two_pairs, with_old=True)
    out = next(o for o, _ in states if list(o.glob("*.old")) and not (o / "s.rrd").exists())
    dead = [p for p in out.iterdir() if p.name.startswith(outputs.TEMP_PREFIX)]
    pid = int(dead[0].name.split(".")[2])
    for path in dead:
        path.rename(out / path.name.replace(f".{pid}.", f".{os.getpid()}.", 1))
    _next_run(out)
    assert _held(out, two_pairs) == 1


USER_FILES = (".notes.txt.4000000.old", ".thesis.tex.31337.old", ".config.99999.partial")
"""A user's hidden files named like a run's temporary files once were."""


def test_a_run_removes_only_its_own_temporary_files(tmp_path, two_pairs):
    out = _killed_commits(tmp_path, two_pairs, with_old=True)[0][0]  # killed before it began
    ours = sorted(p.name for p in out.iterdir() if p.name.startswith("."))
    assert ours  # the killed run's temporary files
    for name in USER_FILES:
        (out / name).write_text(f"{name}: the user's, not the program's\n")
    removed = outputs.remove_stale_partials(out)
    assert sorted(p.name for p in removed) == ours
    for name in USER_FILES:
        assert (out / name).read_text() == f"{name}: the user's, not the program's\n"
    _next_run(out)
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [outputs.LOCK_NAME, "s.json", "s.rrd", *USER_FILES]
    )


def test_signals_held_deliver_a_signal_after_the_block_to_the_handler_it_was_for():
    """A SIGTERM sent inside ``signals_held`` reaches the handler installed before the block,
    once, after the block's last statement ran; the handler is back in place afterwards."""
    import signal as signal_module

    from scenarios.record.outputs import signals_held

    events: list[str] = []

    def handler(signum, frame):
        events.append(f"handled {signal_module.Signals(signum).name}")

    previous = signal_module.signal(signal_module.SIGTERM, handler)
    try:
        with signals_held():
            os.kill(os.getpid(), signal_module.SIGTERM)
            for _ in range(1000):  # bytecodes enough for a handler to have run, were it free
                pass
            events.append("block done")
        events.append("after")
        assert events == ["block done", "handled SIGTERM", "after"]
        assert signal_module.getsignal(signal_module.SIGTERM) is handler
    finally:
        signal_module.signal(signal_module.SIGTERM, previous)
