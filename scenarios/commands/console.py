"""What ``vnav-demo`` prints: results on stdout, errors as one line on stderr.

A reader that goes away (``vnav-demo list | head -1``) ends the printing quietly, not the
command: runs still write their files and the exit status still says how they went.
"""

from __future__ import annotations

import os
import sys

__all__ = ["WIDTH", "error", "say"]

WIDTH = 80
"""Columns every line of ``vnav-demo``'s output fits in (a test checks each command)."""


def say(text: str) -> None:
    """Print ``text`` to stdout, or nothing once stdout's reader has gone away."""
    if sys.stdout is None:
        return
    try:
        print(text, flush=True)
    except BrokenPipeError:
        # Point stdout at /dev/null so that the interpreter's final flush does not fail too.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        sys.stdout = None


def error(message: str) -> None:
    """One line on stderr: ``vnav-demo: error: message``."""
    print(f"vnav-demo: error: {message}", file=sys.stderr, flush=True)
