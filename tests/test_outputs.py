"""scenarios.record.outputs: a run's recording and report are put in place together, complete, or
not at all, and the previous pair survives every failure."""

from __future__ import annotations

import errno
import multiprocessing
import os
from pathlib import Path

import pytest

from scenarios.record import outputs


@pytest.fixture(scope="module")
def good_rrd(tmp_path_factory) -> bytes:
    """The bytes of a complete recording (a short built-in run)."""
    import dataclasses

    from scenarios import pipeline
    from scenarios.scenario import builtin

    out = tmp_path_factory.mktemp("good")
    spec = dataclasses.replace(builtin.load("frame-problem"), duration_s=0.5)
    return pipeline.run(spec, out_dir=out).rrd_path.read_bytes()


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
    dead = tmp_path / f".s.rrd.{proc.pid}.partial"
    dead_old = tmp_path / f".s.json.{proc.pid}.old"
    mine = tmp_path / f".t.rrd.{os.getpid()}.partial"
    live = tmp_path / f".u.rrd.{os.getppid()}.partial"
    keep = tmp_path / "s.rrd"
    for p in (dead, dead_old, mine, live, keep):
        p.write_bytes(b"x")
    assert sorted(outputs.remove_stale_partials(tmp_path)) == sorted([dead, dead_old])
    assert all(p.exists() for p in (mine, live, keep))


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
