"""Write a scenario (the TOML schema as plain dicts) back out as a TOML file a person can read.

``vnav-demo show NAME`` prints a built-in scenario this way, so a user can start a scenario
file from one. Only what the schema uses is supported: strings, numbers, booleans, lists of
those, tables, arrays of tables, and lists of inline tables (keyframes, waypoints).

The text fits ``WIDTH`` columns: floats are rounded to ``SIGNIFICANT_DIGITS`` (the file parses
back to the same scenario within that rounding), a long string becomes a multi-line string
whose line-ending backslashes join it back exactly, a comment that does not fit after its key
goes on the line above, and a list of inline tables with a line too long (TOML 1.0 keeps an
inline table on one line) is written as an array of tables (``[[flight.keyframes]]``).
With comments, a table inside a table is written as a table of its own
(``[camera.mount_error]``), so that each of its keys has its comment too.

``complete`` fills a scenario in with every key the schema has for it, at its default, so
that ``vnav-demo show`` writes them all; an optional key without a value (``OMITTED``) is
written as a comment naming it.
"""

from __future__ import annotations

import json
import math
import re
import textwrap
from contextvars import ContextVar
from typing import Any

from scenarios.scenario import schema
from scenarios.scenario.check_kinds import KINDS

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


OMITTED = type("Omitted", (), {"__repr__": lambda self: "OMITTED"})()
"""The value ``complete`` gives an optional key the scenario leaves out (no default to
write): ``dumps`` writes a comment naming it instead of a value."""

_ENTRY_KEYS = {"flight.keyframes": schema.KEYFRAME, "flight.waypoints": schema.WAYPOINT}
"""The keys of the inline tables of a list, named in the list's comment (an inline table has
no room for comments)."""


def _filled(table: dict[str, Any], keys: tuple[schema.Key, ...]) -> dict[str, Any]:
    """``table``'s keys in the schema's order, each absent one at its default (``OMITTED``
    where it has none)."""
    out = {}
    for key in keys:
        if key.name in table:
            out[key.name] = table[key.name]
        elif key.default is None or key.default is schema.REQUIRED:
            out[key.name] = OMITTED
        else:
            out[key.name] = list(key.default) if isinstance(key.default, tuple) else key.default
    return out


def _check_keys(kind: str) -> tuple[schema.Key, ...]:
    """The ``[[checks]]`` keys that apply to a check of ``kind``: its kind, its method where
    the kind uses one, the limit in its unit, its name."""
    spec = KINDS.get(kind)
    keys = {k.name: k for k in schema.CHECK}
    names = ["kind"]
    if spec is None or spec.uses_method:
        names.append("method")
    names += [spec.limit_key if spec is not None else "limit", "name"]
    return tuple(keys[n] for n in names)


def complete(data: dict[str, Any]) -> dict[str, Any]:
    """A scenario with every key the schema has for it, in the schema's order: the given
    values, the defaults of the keys left out, and ``OMITTED`` for an optional key without a
    default. It parses to the same scenario as ``data``.

    Every table's keys (``[camera]`` and its ``mount_error``, ``[imu]`` and its
    ``mount_error`` if the scenario has an IMU, ``[flight]`` for its mode,
    ``[noise]``, ``[timing]``, each cone), and each check's that apply to its kind. The inline
    tables of ``flight.keyframes`` and ``flight.waypoints`` are kept as given (their keys are
    named in the list's comment).
    """
    out = _filled(data, schema.TOP)
    camera = data.get("camera") or {}
    out["camera"] = _filled(camera, schema.CAMERA)
    out["camera"]["mount_error"] = _filled(camera.get("mount_error") or {}, schema.MOUNT_ERROR)
    imu = data.get("imu")
    if isinstance(imu, dict):  # optional: a scenario without one has none
        out["imu"] = _filled(imu, schema.IMU)
        out["imu"]["mount_error"] = _filled(imu.get("mount_error") or {}, schema.IMU_MOUNT_ERROR)
    flight = data["flight"]
    mode_keys = schema.FLIGHT_MODES.get(flight.get("mode"), ())
    out["flight"] = {"mode": flight.get("mode"), **_filled(flight, mode_keys)}
    out["noise"] = _filled(data.get("noise") or {}, schema.NOISE)
    out["timing"] = _filled(data.get("timing") or {}, schema.TIMING)
    out["cones"] = [_filled(c, schema.CONE) for c in data["cones"]]
    if data.get("checks"):
        out["checks"] = [_filled(c, _check_keys(c.get("kind"))) for c in data["checks"]]
    return out


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
        if v is OMITTED:  # named, with its meaning, where a value would be
            doc = schema.comment(prefix + key, table) if comments else None
            lines += comment_lines(f"{key}: not set here" + (f"; {doc}" if doc else ""))
            continue
        if comments and isinstance(v, dict):  # a table of its own: a comment per key
            deferred.append((prefix + key, v))
            continue
        if _is_table_array(v):  # e.g. keyframes: one inline table per line
            rows = [f"  {_value(x)}," for x in v]
            if any(len(r) > WIDTH for r in rows):
                deferred.append((prefix + key, v))
                continue
            opening = f"{key} = ["
            doc = schema.comment(prefix + key, table) if comments else None
            if doc and prefix + key in _ENTRY_KEYS:
                doc += "; each " + _entry_keys(_ENTRY_KEYS[prefix + key])
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


def _entry_keys(keys: tuple[schema.Key, ...]) -> str:
    """``{ t, position_w, ... }``: the keys of an inline table, the optional ones marked."""
    names = [k.name if k.default is schema.REQUIRED else f"{k.name} (optional)" for k in keys]
    return "{ " + ", ".join(names) + " }"


def _section(header: str, table: dict[str, Any], path: str, comments: bool) -> list[str]:
    """``header`` and the table's keys, then its deferred tables and arrays of tables."""
    body, deferred = _table_body(table, path, comments)
    return ["", header, *body, *_deferred(deferred, comments)]


def _deferred(deferred: list[tuple[str, Any]], comments: bool) -> list[str]:
    """Tables (``[path]``) and lists of tables (``[[path]]``) written after their parent."""
    lines = []
    for sub_path, v in deferred:
        if isinstance(v, dict):  # its meaning under its header
            section = _section(f"[{sub_path}]", v, sub_path, comments)
            doc = schema.comment(sub_path) if comments else None
            lines += section[:2] + (comment_lines(doc) if doc else []) + section[2:]
            continue
        for entry in v:
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
    lines += _deferred(deferred, comments)  # top-level lists of inline tables (none in the schema)
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
