"""Ending several run observers at once (a recording, exporters): each is aborted even if
one before it fails to, and the first failure is raised after all of them have been tried,
so that no file is left open because another observer's clean-up failed."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

__all__ = ["abort_all"]


def abort_all(observers: Iterable[Any]) -> None:
    """Call ``abort()`` on every one of ``observers``, in order, even if one raises; then
    raise the first exception raised."""
    first: BaseException | None = None
    for o in observers:
        try:
            o.abort()
        except BaseException as exc:
            first = first or exc
    if first is not None:
        raise first
