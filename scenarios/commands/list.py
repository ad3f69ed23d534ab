"""``vnav-demo list``: the built-in scenarios, a name and its description wrapped beside it."""

from __future__ import annotations

import argparse
import textwrap

from scenarios.commands.console import WIDTH, say
from scenarios.scenario import builtin

__all__ = ["command"]


def command(args: argparse.Namespace) -> int:
    """Print every built-in scenario in 80 columns; exit status 0."""
    width = max(len(n) for n in builtin.names()) + 2
    lines = []
    for name in builtin.names():
        lines += textwrap.wrap(
            builtin.REGISTRY[name]()["description"],
            WIDTH,
            initial_indent=f"{name:<{width}}",
            subsequent_indent=" " * width,
        )
    say("\n".join(lines))
    return 0
