"""Write a scenario (the TOML schema as plain dicts) back out as a TOML file a person can read.

``vnav-demo show NAME`` prints a built-in scenario this way, so a user can start a scenario
file from one. Only what the schema uses is supported: strings, numbers, booleans, lists of
those, tables, arrays of tables, and lists of inline tables (keyframes, waypoints).

The text fits ``WIDTH`` columns: floats are rounded to ``SIGNIFICANT_DIGITS`` (the file parses
back to the same scenario within that rounding), a long string becomes a multi-line string
whose line-ending backslashes join it back exactly, a comment that does not fit after its key
goes on the line above, and a list of inline tables with a line too long (TOML 1.0 keeps an
inline table on one line) is written as an array of tables (``[[flight.keyframes]]``).
"""

from __future__ import annotations

import json
import math
import re
import textwrap
from contextvars import ContextVar
from typing import Any

from scenarios.scenario import schema

WIDTH = 80
"""Columns the text fits in, where a value allows (a single word longer cannot be split)."""

SIGNIFICANT_DIGITS = 6
"""Floats are written to this many significant digits: 33.690067525979785 -> 33.6901."""


_exact_floats: ContextVar[bool] = ContextVar("_exact_floats", default=False)
"""Set by ``dumps(exact=True)`` for the text it writes: floats in full."""


def _float(v: float) -> str:
    """``v`` rounded to ``SIGNIFICANT_DIGITS`` (in full under ``dumps(exact=True)``), in
    Python's shortest form (a valid TOML float: ``33.6901``, ``10.0``, ``1e-07``)."""
    if not math.isfinite(v):
        raise ValueError(f"TOML has no literal for {v!r} in this schema")
    if _exact_floats.get():
        return repr(float(v))  # the shortest text that parses back to the same double
    return repr(float(f"{v:.{SIGNIFICANT_DIGITS}g}"))


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return _float(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)  # a valid TOML basic string
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise ValueError(f"cannot write {type(v).__name__} as TOML: {v!r}")


def _is_table_array(v: Any) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, dict) for x in v)


def _string_lines(key: str, text: str) -> list[str]:
    """``key = "text"``, or, when longer than ``WIDTH``, a multi-line basic string broken after
    spaces: each line ends with ``\\``, which TOML drops with the newline and the next line's
    leading whitespace (there is none: every line starts with a word), so the value is
    ``text`` exactly."""
    one = f"{key} = {_value(text)}"
    if len(one) <= WIDTH or not text or text[0].isspace():
        return [one]
    lines, line = [f'{key} = """\\'], ""
    for chunk in re.findall(r"\S+\s*", text):  # a word and the spaces after it
        escaped = json.dumps(chunk, ensure_ascii=False)[1:-1]
        if line and len(line) + len(escaped) + 1 > WIDTH:
            lines.append(line + "\\")
            line = ""
        line += escaped
    return [*lines, line + '"""']


def _with_comment(lines: list[str], path: str, table: dict, comments: bool) -> list[str]:
    """``lines`` (a key's value) with the schema's comment after them, or above if too long."""
    doc = schema.comment(path, table) if comments else None
    if not doc:
        return lines
    after = f"{lines[0]}  # {doc}"
    if len(lines) == 1 and len(after) <= WIDTH:
        return [after]
    return [*comment_lines(doc), *lines]


def comment_lines(text: str) -> list[str]:
    """``text`` as TOML comment lines (``# ...``), wrapped to ``WIDTH``."""
    return textwrap.wrap(
        text, WIDTH, initial_indent="# ", subsequent_indent="# ", break_on_hyphens=False
    )


def _table_body(
    table: dict[str, Any], path: str = "", comments: bool = False
) -> tuple[list[str], list[tuple[str, list[dict]]]]:
    """The lines of a table's keys, and the lists of inline tables too long for their lines
    (written after it as arrays of tables, ``[[path.key]]``)."""
    lines: list[str] = []
    deferred: list[tuple[str, list[dict]]] = []
    prefix = f"{path}." if path else ""
    for key, v in table.items():
        if v is None:  # an optional key left out
            continue
        if _is_table_array(v):  # e.g. keyframes: one inline table per line
            rows = [f"  {_value(x)}," for x in v]
            if any(len(r) > WIDTH for r in rows):
                deferred.append((prefix + key, v))
                continue
            opening = f"{key} = ["
            doc = schema.comment(prefix + key, table) if comments else None
            if doc and len(f"{opening}  # {doc}") <= WIDTH:
                lines.append(f"{opening}  # {doc}")
            else:
                lines += comment_lines(doc) if doc else []
                lines.append(opening)
            lines += [*rows, "]"]
        elif isinstance(v, str):
            lines += _with_comment(_string_lines(key, v), prefix + key, table, comments)
        else:
            lines += _with_comment([f"{key} = {_value(v)}"], prefix + key, table, comments)
    return lines, deferred


def _section(header: str, table: dict[str, Any], path: str, comments: bool) -> list[str]:
    """``header`` and the table's keys, then its deferred lists as arrays of tables."""
    body, deferred = _table_body(table, path, comments)
    lines = ["", header, *body]
    for sub_path, entries in deferred:
        for entry in entries:
            lines += _section(f"[[{sub_path}]]", entry, sub_path, comments)
    return lines


def dumps(data: dict[str, Any], *, comments: bool = False, exact: bool = False) -> str:
    """TOML text for a scenario dict (top-level keys, then tables, then arrays of tables).

    With ``comments``, each key the schema documents (``scenarios.scenario.schema.comment``) is
    followed by its meaning and unit (on the line above where it does not fit ``WIDTH``).
    With ``exact``, floats are written in full: the text parses back to ``data`` exactly (a
    sweep's grid points, replayed by ``vnav-demo run``), at the cost of longer lines.
    """
    token = _exact_floats.set(exact)
    try:
        return _dumps(data, comments)
    finally:
        _exact_floats.reset(token)


def _dumps(data: dict[str, Any], comments: bool) -> str:
    tables = {k: v for k, v in data.items() if isinstance(v, dict)}
    arrays = {k: v for k, v in data.items() if _is_table_array(v)}
    top = {k: v for k, v in data.items() if k not in tables and k not in arrays}
    lines, deferred = _table_body(top, comments=comments)
    for path, entries in deferred:  # top-level lists of inline tables (none in the schema)
        for entry in entries:
            lines += _section(f"[[{path}]]", entry, path, comments)
    for key, table in tables.items():
        lines += _section(f"[{key}]", table, key, comments)
    for key, entries in arrays.items():
        for entry in entries:
            lines += _section(f"[[{key}]]", entry, key, comments)
    return "\n".join(lines) + "\n"


def example_toml() -> str:
    """The README's example scenario file, its comments from the schema
    (``scenarios.scenario.schema``).

    A cone 6 m ahead and 1 m left of a drone 4 m up, its camera pitched 30 deg down: the line
    of sight falls 33 deg below the horizontal, near the image's centre, and stays well inside
    the image while the drone yaws 20 deg towards the cone.
    """
    example = {
        "name": "my-scene",
        "description": "one line",
        "camera_rate_hz": 10.0,
        "camera": {k.name: k.default for k in schema.CAMERA if k.name != "mount_error"}
        | {"mount_error": {k.name: list(k.default) for k in schema.MOUNT_ERROR}},
        "cones": [{"position_w": [6.0, 1.0, 0.0]}],
        "flight": {
            "mode": "kinematic",
            "keyframes": [
                {"t": 0.0, "position_w": [0.0, 0.0, 4.0], "rpy_deg": [0.0, 0.0, 0.0]},
                {"t": 5.0, "position_w": [0.0, 0.0, 4.0], "rpy_deg": [0.0, 0.0, 20.0]},
            ],
        },
        "noise": {k.name: k.default for k in schema.NOISE},
        "timing": {k.name: k.default for k in schema.TIMING},
        "checks": [{"kind": "max_error", "method": "depth_image", "limit_m": 0.1}],
    }
    return dumps(example, comments=True)
