"""Exporters that fail as a full disk or a killed process does, for the fault tests.

The image formats' exporters run in the export process (``scenarios.export.process``), where
a test's monkeypatches do not reach: a test points a format at one of these instead
(``export.FORMATS``, whose ``module:Class`` the export process imports), and the fault
happens there.
"""

from __future__ import annotations

import errno
import os
import signal

from scenarios.export import euroc
from scenarios.export.euroc import EurocExporter
from scenarios.export.mcap import McapExporter

FULL_AT = 5
"""The file write (counted from 1) that finds the disk full."""
KILLED_AT = 3
"""The camera tick (counted from 1) at which ``KilledEuroc`` kills its process."""


class FullDiskEuroc(EurocExporter):
    """EuRoC's exporter whose ``FULL_AT``-th file write (and every later one) raises ENOSPC,
    as a full disk's does."""

    def __init__(self, staging) -> None:
        super().__init__(staging)
        real, calls = euroc._write_file, [0]

        def full(path, data):
            calls[0] += 1
            if calls[0] >= FULL_AT:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
            real(path, data)

        euroc._write_file = full  # in this process only: the export process


class KilledEuroc(EurocExporter):
    """EuRoC's exporter whose process is killed outright (SIGKILL) at camera tick
    ``KILLED_AT``, as the out-of-memory killer would."""

    def __init__(self, staging) -> None:
        super().__init__(staging)
        self._ticks = 0

    def on_tick(self, record, rgb, depth_m) -> None:
        self._ticks += 1
        if self._ticks == KILLED_AT:
            os.kill(os.getpid(), signal.SIGKILL)
        super().on_tick(record, rgb, depth_m)


class RefusingMcap(McapExporter):
    """The bag's exporter refusing the third camera tick with a ValueError, as it refuses an
    image that is not the camera's."""

    def on_tick(self, record, rgb, depth_m) -> None:
        if record.tick == 3:
            raise ValueError(f"refuses tick {record.tick}")
        super().on_tick(record, rgb, depth_m)
