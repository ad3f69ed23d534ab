"""What every exporter is: a ``TickObserver`` that writes one data format into a staging
directory, and what it reports.

An exporter (``Exporter``) is made with its staging directory, a hidden temporary name in
the output directory (``scenarios.record.outputs.staging_dir``). The run feeds it as it feeds
the recording (``scenarios.run.runner.FanOut``): ``start``, ``on_tick`` per camera tick,
then ``finish`` once the run is judged, or ``abort`` if anything fails. Every file it writes
is flushed to the disk (``write_flushed``) before ``finish`` returns, so that the commit
flushes only the directories. ``finish`` returns an ``ExportResult``: the final names it
staged (files or directories, named as they will be in the output directory) and those it
did not write this time (with the reason in ``note``). ``scenarios.pipeline`` commits them
with the recording and the report, all or none
(``scenarios.record.outputs.OutputPair.add``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from scenarios.run.records import RunResult, TickRecord
from vnav.camera import PinholeCamera

if TYPE_CHECKING:  # annotations only: importing sim.mesh loads MuJoCo before sim.gl
    from scenarios.scenario.spec import ScenarioSpec
    from sim.mesh import Scenery

__all__ = ["ExportResult", "Exporter", "listed_files", "stamp_ns", "write_flushed"]


@dataclass(frozen=True)
class ExportResult:
    """What one exporter staged.

    Attributes
    ----------
    format : str
        The format's name (``scenarios.export.FORMATS``).
    written : tuple of str
        Final names (in the output directory) of the files or directories staged, each under
        the same name in the staging directory.
    not_written : tuple of str
        Final names of the format that this run has nothing for: the commit removes a
        previous run's file there, so that none is left beside the new set.
    note : str or None
        One sentence: why something was not written, or what the files leave out.
    figures : dict
        More for the report (``tum``: the PnP trajectory's error statistics).
    """

    format: str
    written: tuple[str, ...]
    not_written: tuple[str, ...] = ()
    note: str | None = None
    figures: dict[str, Any] = field(default_factory=dict)


class Exporter(Protocol):
    """A data format written from a run (``scenarios.export.FORMATS``); made with its
    staging directory, which exists and is empty."""

    name: str

    def start(
        self, spec: ScenarioSpec, seed: int, camera: PinholeCamera, scenery: Scenery
    ) -> None: ...

    def on_tick(self, record: TickRecord, rgb: np.ndarray, depth_m: np.ndarray | None) -> None: ...

    def finish(self, result: RunResult) -> ExportResult: ...

    def abort(self) -> None: ...


def write_flushed(path: Path, data: bytes) -> None:
    """Write ``data`` to a new file at ``path`` and flush it to the disk (``fsync``).

    Raises
    ------
    OSError
        If it cannot be written (a full disk...).
    """
    with open(path, "xb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def stamp_ns(record: TickRecord) -> int:
    """The image's exposure stamp on the camera clock, integer nanoseconds (the simulated
    time for a tick with no stamps)."""
    t_s = record.t_s if record.timing is None else record.timing.stamp_cam_s
    return round(t_s * 1e9)


def listed_files(staging: Path, names: tuple[str, ...]) -> list[dict[str, Any]]:
    """Every file under the staged ``names`` (files or directories): ``{"path", "bytes"}``,
    the path relative to the output directory with ``/`` separators, sorted."""
    out = []
    for name in names:
        top = Path(staging) / name
        if not top.is_dir():
            out.append({"path": name, "bytes": top.stat().st_size})
            continue
        for root, dirs, files in os.walk(top):
            dirs.sort()
            for f in sorted(files):
                path = Path(root, f)
                rel = path.relative_to(staging).as_posix()
                out.append({"path": rel, "bytes": path.stat().st_size})
    return out
