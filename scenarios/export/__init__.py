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
from dataclasses import dataclass
from pathlib import Path

__all__ = ["FORMATS", "Format", "available", "create", "parse"]


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
    """

    exporter: str
    files: tuple[str, ...]
    directory: bool
    help: str

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
    ),
    "mcap": Format(
        "scenarios.export.mcap:McapExporter",
        ("{name}.mcap",),
        False,
        "<name>.mcap: the run as ROS 2 messages, with an [imu] its readings on /imu "
        "(Foxglove, ros2 bag)",
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
