"""The export process (``scenarios.export.process``): the image formats written in a child
process are the files one process writes, byte for byte, through a ring that reuses its
slots; the child runs nicer than the command, ignores Ctrl-C, dies with the command, is started by
worker processes too, and its failures (a refused tick, a full disk, being killed) end the run
as they would in one process, the previous files kept."""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from scenarios import export, pipeline
from scenarios.cli import main
from scenarios.export import base, process
from scenarios.record import outputs
from scenarios.scenario import builtin
from vnav.camera import PinholeCamera


def _files(directory: Path) -> dict[str, bytes]:
    return {
        p.relative_to(directory).as_posix(): p.read_bytes()
        for p in sorted(directory.rglob("*"))
        if p.is_file()
    }


def _exported(out: Path, name: str) -> dict[str, bytes]:
    """The exported files of scenario ``name`` under ``out`` (not the recording or report,
    whose ids and times differ from run to run)."""
    return {
        k: v for k, v in _files(out).items() if not k.startswith((f"{name}.rrd", f"{name}.json"))
    }


def test_the_export_process_writes_what_one_process_writes(tmp_path, monkeypatch, caplog):
    """``orbit`` for 1 s (images and depth, 31 ticks) with ``euroc,mcap``: in the export process
    through a ring of 3 slots (each reused about ten times), every file is byte for byte the
    one the same exporters write in the command's process; the child's log records reach the
    command's logging."""
    spec = dataclasses.replace(builtin.load("orbit"), duration_s=1.0, camera_rate_hz=30.0)
    slots = []
    real_slots = process.ring_slots
    monkeypatch.setattr(base, "QUEUED_BYTES_MAX", 1)
    monkeypatch.setattr(process, "ring_slots", lambda b: slots.append(real_slots(b)) or slots[-1])
    (tmp_path / "child").mkdir()
    (tmp_path / "here").mkdir()
    with caplog.at_level(logging.INFO):
        child = pipeline.run(spec, seed=1, out_dir=tmp_path / "child", exports=("euroc", "mcap"))
    assert slots == [process.SLOTS_MIN] and len(child.result.ticks) >= 10 * slots[0]
    assert any(
        r.name == "scenarios.export.mcap" and r.getMessage().startswith("wrote ")
        for r in caplog.records
    )
    for name in ("euroc", "mcap"):
        monkeypatch.setitem(
            export.FORMATS, name, dataclasses.replace(export.FORMATS[name], own_process=False)
        )
    pipeline.run(spec, seed=1, out_dir=tmp_path / "here", exports=("euroc", "mcap"))
    here, there = _exported(tmp_path / "here", "orbit"), _exported(tmp_path / "child", "orbit")
    assert "orbit.mcap" in here and any(k.endswith(".png") and "depth0" in k for k in here)
    assert there.keys() == here.keys()
    assert [k for k in here if here[k] != there[k]] == []


def test_the_child_is_nicer_ignores_ctrl_c_and_refuses_images_not_the_cameras():
    """The child runs ``EXPORTER_NICE`` nicer than the command (19 at most), outlives a
    SIGINT (a terminal's Ctrl-C reaches the whole process group; the command stops it), and an
    image larger than the camera's is a ValueError in the command, before anything is sent."""
    exports = process.ExportProcess([])
    camera = PinholeCamera.from_fovy(60.0, 64, 48)
    exports.start(None, 1, camera, None)
    mine = os.getpriority(os.PRIO_PROCESS, 0)
    assert os.getpriority(os.PRIO_PROCESS, exports.pid) == min(19, mine + base.EXPORTER_NICE)
    os.kill(exports.pid, signal.SIGINT)
    time.sleep(0.2)
    assert exports.exit_status is None
    with pytest.raises(ValueError, match="do not fit the camera's slot"):
        exports.on_tick(_Record(1), np.zeros((96, 128, 3), np.uint8), None)
    exports.abort()
    assert exports.exit_status == 0


@dataclasses.dataclass
class _Record:
    tick: int


def test_an_exporters_error_in_the_child_is_raised_by_the_run(tmp_path, monkeypatch):
    """An exporter that refuses a tick in the export process (``export_faults.RefusingMcap``,
    a ValueError at its third): the run raises that ValueError, and neither the recording nor
    any export is left behind."""
    refusing = dataclasses.replace(export.FORMATS["mcap"], exporter="export_faults:RefusingMcap")
    monkeypatch.setitem(export.FORMATS, "mcap", refusing)
    spec = dataclasses.replace(builtin.load("orbit"), duration_s=1.0)
    with pytest.raises(ValueError, match="refuses tick 3"):
        pipeline.run(spec, seed=1, out_dir=tmp_path, exports=("mcap",))
    assert list(tmp_path.iterdir()) == []


def test_a_killed_export_process_ends_the_run_and_keeps_the_previous_files(
    tmp_path, capsys, monkeypatch
):
    """The export process killed outright at the third tick of a second run
    (``export_faults.KilledEuroc``): exit 3 in one line saying so, and the first run's files
    are all as they were, with no temporary file left."""
    args = ["run", "frame-problem", "--duration", "1", "--export", "euroc", "--quiet"]
    assert main([*args, "--out", str(tmp_path)]) in (0, 1)
    before = _files(tmp_path)
    killed = dataclasses.replace(export.FORMATS["euroc"], exporter="export_faults:KilledEuroc")
    monkeypatch.setitem(export.FORMATS, "euroc", killed)
    capsys.readouterr()
    assert main([*args, "--seed", "2", "--out", str(tmp_path)]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "the export process ended unexpectedly (killed by SIGKILL)" in err
    assert _files(tmp_path) == before
    assert not [
        p
        for p in tmp_path.iterdir()
        if p.name.startswith(outputs.TEMP_PREFIX) and p.name != outputs.LOCK_NAME
    ]


def _children(pid: int) -> list[int]:
    """The processes whose parent is ``pid`` (Linux's /proc)."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                found.append(int(entry.name))
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG and /proc are Linux's"
)
def test_the_command_killed_outright_takes_its_export_process_with_it(tmp_path):
    """SIGKILL of ``vnav-demo run orbit --export euroc,mcap`` while its export process writes:
    the export process ends with it, and the next run into the directory leaves no temporary
    file of either behind."""
    command = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys; from scenarios.cli import main; sys.exit(main())",
            "run",
            "orbit",
            "--duration",
            "20",
            "--export",
            "euroc,mcap",
            "--quiet",
            "--out",
            str(tmp_path),
        ],
    )
    try:
        deadline = time.monotonic() + 120
        while not list(tmp_path.glob(f"{outputs.TEMP_PREFIX}*euroc*/**/*.png")):
            assert command.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
        (child,) = _children(command.pid)
        assert b"scenarios.export.process" in Path(f"/proc/{child}/cmdline").read_bytes()
    finally:
        command.kill()
        command.wait()
    deadline = time.monotonic() + 10
    while _alive(child):
        assert time.monotonic() < deadline, "the export process outlived its command"
        time.sleep(0.05)
    assert main(
        ["run", "frame-problem", "--duration", "0.5", "--quiet", "--out", str(tmp_path)]
    ) in (0, 1)
    assert not [
        p.name
        for p in tmp_path.iterdir()
        if p.name.startswith(outputs.TEMP_PREFIX) and p.name != outputs.LOCK_NAME
    ]


def test_worker_processes_start_export_processes_of_their_own(tmp_path):
    """``--jobs 2``: each worker (a daemonic multiprocessing child, which multiprocessing lets
    start no process of its own) starts its scenario's export process, and both scenarios'
    EuRoC folders and bags are committed, every file the report lists there at its size."""
    names = ("orbit", "frame-problem")
    args = ["run", *names, "--jobs", "2", "--duration", "1", "--export", "euroc,mcap"]
    assert main([*args, "--out", str(tmp_path), "--quiet"]) in (0, 1)
    for name in names:
        report = json.loads((tmp_path / f"{name}.json").read_text())
        listed = [f for entry in report["exports"].values() for f in entry["files"]]
        assert f"{name}.mcap" in {f["path"] for f in listed}
        assert any(f["path"].startswith(f"{name}.euroc/mav0/cam0/data/") for f in listed)
        for f in listed:
            assert (tmp_path / f["path"]).stat().st_size == f["bytes"]
