"""Run one benchmark: ``python -m benchmarks NAME [--json]``.

Each benchmark is a module ``benchmarks/<NAME>.py`` with a function ``run(args) -> dict`` that
prints a table (unless ``--json``) and returns its figures, and ``add_arguments(parser)``.
"""

from __future__ import annotations

import argparse
import importlib
import json
import pkgutil
import sys

import benchmarks


def _available() -> list[str]:
    return sorted(
        m.name for m in pkgutil.iter_modules(benchmarks.__path__) if not m.name.startswith("_")
    )


def main(argv: list[str] | None = None) -> int:
    names = _available()
    parser = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__)
    sub = parser.add_subparsers(dest="name", metavar="NAME", required=True)
    for name in names:
        module = importlib.import_module(f"benchmarks.{name}")
        p = sub.add_parser(name, help=(module.__doc__ or "").strip().splitlines()[0])
        p.add_argument("--json", action="store_true", help="print one JSON object of figures")
        if hasattr(module, "add_arguments"):
            module.add_arguments(p)
    args = parser.parse_args(argv)
    module = importlib.import_module(f"benchmarks.{args.name}")
    figures = module.run(args)
    if args.json:
        json.dump(figures, sys.stdout, indent=2, sort_keys=True)
        sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
