"""``vnav-demo show NAME``: a built-in scenario as a TOML file, every key of the schema
written (those at their defaults too) and commented, to start one's own from."""

from __future__ import annotations

import argparse

from scenarios.commands.common import EXIT_BAD_INPUT
from scenarios.commands.console import error, say
from scenarios.scenario import builtin, toml_out

__all__ = ["command", "show_name"]


def show_name(name: str) -> str:
    """The name ``vnav-demo show NAME`` gives its copy, so that running the copy writes
    ``my-NAME.rrd`` and leaves the built-in's files alone."""
    return f"my-{name}"


def command(args: argparse.Namespace) -> int:
    """Print the built-in ``args.name`` as a scenario file; exit status 0, or 2 for a name that
    is not a built-in (one line naming the valid ones)."""
    if args.name not in builtin.REGISTRY:
        error(f"unknown scenario {args.name!r}; valid names: {', '.join(builtin.names())}")
        return EXIT_BAD_INPUT
    scenario = {**builtin.REGISTRY[args.name](), "name": show_name(args.name)}
    header = toml_out.comment_lines(
        f"vnav-demo show {args.name}: the built-in as a scenario file. Save it as FILE.toml, "
        f"edit it, run it with `vnav-demo run FILE.toml`: it writes {scenario['name']}.rrd and "
        ".json."
    )
    say(
        "\n".join(header)
        + "\n"
        + toml_out.dumps(toml_out.complete(scenario), comments=True).rstrip("\n")
    )
    return 0
