"""A run's data for other tools: one module per format, registered in ``FORMATS``.

``vnav-demo run NAME --export FORMAT[,FORMAT]`` writes each format's files beside the
recording and the report, committed with them, all or none (``scenarios.pipeline``). Each
format is one entry of ``FORMATS``: the module and class of its exporter
(``scenarios.export.base.Exporter``), imported only when the format is used, and the final
names it writes, so that the command can check them before running. A format whose module is
not installed is not offered.
"""

from __future__ import annotations

import importlib
import importlib.util
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from scenarios.run.observers import abort_all

if TYPE_CHECKING:
    import numpy as np

    from scenarios.export.base import ExportResult
    from scenarios.run.records import RunResult, TickRecord
    from scenarios.scenario.spec import ScenarioSpec
    from sim.mesh import Scenery
    from vnav.camera import PinholeCamera

__all__ = ["FORMATS", "ExportSet", "Format", "available", "create", "parse"]


@dataclass(frozen=True)
class Format:
    """One export format.

    Attributes
    ----------
    exporter : str
        ``module:Class`` of its exporter, made with its staging directory.
    files : tuple of str
        Its final names, ``{name}`` standing for the scenario's name: files, or directories
        where ``directory`` is true.
    directory : bool
        Whether ``files`` are directories.
    help : str
        What it writes, for ``vnav-demo run --help``.
    own_process : bool
        Whether its exporter runs in the export process (``scenarios.export.process``): the
        formats that encode every image, whose work would otherwise hold up the run's thread.
    """

    exporter: str
    files: tuple[str, ...]
    directory: bool
    help: str
    own_process: bool = False

    def final_names(self, scenario: str) -> tuple[str, ...]:
        """Its final names for the scenario ``scenario``."""
        return tuple(f.format(name=scenario) for f in self.files)


FORMATS: dict[str, Format] = {
    "tum": Format(
        "scenarios.export.tum:TumExporter",
        ("{name}.truth.tum", "{name}.pnp.tum"),
        False,
        "<name>.truth.tum and <name>.pnp.tum: the true camera trajectory and PnP's on the "
        "cones (for evo)",
    ),
    "euroc": Format(
        "scenarios.export.euroc:EurocExporter",
        ("{name}.euroc",),
        True,
        "<name>.euroc/mav0/: the images, depth, ground truth and, with an [imu], the IMU's "
        "readings in the EuRoC (ASL) layout",
        own_process=True,
    ),
    "mcap": Format(
        "scenarios.export.mcap:McapExporter",
        ("{name}.mcap",),
        False,
        "<name>.mcap: the run as ROS 2 messages, with an [imu] its readings on /imu "
        "(Foxglove, ros2 bag)",
        own_process=True,
    ),
}
"""Every export format by name: adding a format is one entry here and its module."""


def available() -> list[str]:
    """The formats whose module is installed, in ``FORMATS`` order."""
    return [n for n, f in FORMATS.items() if _module_exists(f.exporter.partition(":")[0])]


def _module_exists(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ImportError:
        return False


def parse(text: str) -> tuple[str, ...]:
    """The formats of ``--export``: names separated by commas, in order, each once.

    Raises
    ------
    ValueError
        Naming an unknown (or not installed) format and the formats there are.
    """
    names = [n.strip() for n in text.split(",")]
    offered = available()
    for n in names:
        if n not in offered:
            what = "an empty format name" if not n else f"unknown format {n!r}"
            raise ValueError(f"--export: {what}; the formats are {', '.join(offered)}")
    return tuple(dict.fromkeys(names))


def create(name: str, staging: Path):
    """The exporter of format ``name`` (``scenarios.export.base.Exporter``), writing into
    ``staging``."""
    module, _, cls = FORMATS[name].exporter.partition(":")
    return getattr(importlib.import_module(module), cls)(Path(staging))


class ExportSet:
    """A run's export formats as one ``TickObserver``: those with ``own_process`` in one
    export process (``scenarios.export.process.ExportProcess``), started here, the others in
    this one.

    Parameters
    ----------
    names : sequence of str
        Formats (``FORMATS``), in the order ``finish`` returns their results.
    stagings : sequence of Path
        Each format's staging directory (exists, empty).
    in_process : bool
        Every format in this process (no export process).

    Raises
    ------
    OSError
        If the export process cannot be started.
    """

    def __init__(
        self, names: Sequence[str], stagings: Sequence[Path], in_process: bool = False
    ) -> None:
        from scenarios.export.process import ExportProcess, HostedFormat

        self.names = tuple(names)
        hosted = [
            HostedFormat(n, FORMATS[n].exporter, Path(d))
            for n, d in zip(names, stagings, strict=True)
            if FORMATS[n].own_process and not in_process
        ]
        self._local = {
            n: create(n, d)
            for n, d in zip(names, stagings, strict=True)
            if n not in {h.name for h in hosted}
        }
        self._process = ExportProcess(hosted) if hosted else None
        # The export process first: its copies made, it encodes while this one's run.
        self._observers = [*([self._process] if self._process else []), *self._local.values()]

    def start(self, spec: ScenarioSpec, seed: int, camera: PinholeCamera, scenery: Scenery) -> None:
        for o in self._observers:
            o.start(spec, seed, camera, scenery)

    def on_tick(self, record: TickRecord, rgb: np.ndarray, depth_m: np.ndarray | None) -> None:
        for o in self._observers:
            o.on_tick(record, rgb, depth_m)

    def finish(self, result: RunResult) -> tuple[ExportResult, ...]:
        """Every format's ``ExportResult``, in ``names`` order."""
        done = {n: e.finish(result) for n, e in self._local.items()}
        if self._process is not None:
            names = [f.name for f in self._process.formats]
            done.update(zip(names, self._process.finish(result), strict=True))
        return tuple(done[n] for n in self.names)

    def abort(self) -> None:
        """Abort every format, even if one fails to; then raise the first failure."""
        abort_all(self._observers)
