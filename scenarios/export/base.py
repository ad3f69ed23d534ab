"""What every exporter is: a run observer that writes files under a staging directory.

An exporter is given each camera tick as the recording is (``scenarios.run.runner.TickObserver``:
``start``, ``on_tick``, ``abort``), then ``finish`` with the judged run; it writes only under the
staging directory it was given, and its owner moves what it wrote into place with the run's
other outputs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    import numpy as np

    from scenarios.run.records import RunResult, TickRecord
    from scenarios.scenario.spec import ScenarioSpec
    from sim.mesh import Scenery
    from vnav.camera import PinholeCamera

__all__ = ["ExportResult", "Exporter"]


@dataclass(frozen=True)
class ExportResult:
    """What one exporter staged.

    Attributes
    ----------
    format : str
        The format's name (the exporter's ``name``).
    written : tuple of str
        Final names of the files staged (each under the same name in the staging directory).
    not_written : tuple of str
        Final names of the format that this run has nothing for.
    note : str or None
        One sentence: why something was not written, or what the files leave out.
    figures : dict
        More for the report.
    """

    format: str
    written: tuple[str, ...]
    not_written: tuple[str, ...] = ()
    note: str | None = None
    figures: dict[str, Any] = field(default_factory=dict)


class Exporter(Protocol):
    """A run observer that writes one format (``name``) under its staging directory."""

    name: str

    def start(
        self, spec: ScenarioSpec, seed: int, camera: PinholeCamera, scenery: Scenery
    ) -> None: ...

    def on_tick(self, record: TickRecord, rgb: np.ndarray, depth_m: np.ndarray | None) -> None: ...

    def finish(self, result: RunResult) -> ExportResult: ...

    def abort(self) -> None: ...
