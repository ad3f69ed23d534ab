"""Write a scenario (the TOML schema as plain dicts) back out as a TOML file.

``vnav-demo show NAME`` prints a built-in scenario this way, so a user can start a scenario
file from one. Only what the schema uses is supported: strings, numbers, booleans, lists of
those, tables, arrays of tables, and lists of inline tables (keyframes, waypoints).
"""

from __future__ import annotations

import json
import math
from typing import Any

from scenarios import schema

_SCALARS = (str, int, float, bool)


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"TOML has no literal for {v!r} in this schema")
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)  # a valid TOML basic string
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise ValueError(f"cannot write {type(v).__name__} as TOML: {v!r}")


def _is_table_array(v: Any) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, dict) for x in v)


def _with_comment(line: str, path: str, comments: bool) -> str:
    doc = schema.comment(path) if comments else None
    commented = f"{line}  # {doc}"
    return commented if doc and len(commented) <= 100 else line


def _table_body(table: dict[str, Any], path: str = "", comments: bool = False) -> list[str]:
    lines = []
    prefix = f"{path}." if path else ""
    for key, v in table.items():
        if v is None:  # an optional key left out
            continue
        if _is_table_array(v):  # e.g. keyframes: one inline table per line
            lines.append(_with_comment(f"{key} = [", prefix + key, comments))
            lines += [f"  {_value(x)}," for x in v]
            lines.append("]")
        else:
            lines.append(_with_comment(f"{key} = {_value(v)}", prefix + key, comments))
    return lines


def dumps(data: dict[str, Any], *, comments: bool = False) -> str:
    """TOML text for a scenario dict (top-level keys, then tables, then arrays of tables).

    With ``comments``, each key the schema documents (``scenarios.schema``) is followed by its
    meaning and unit.
    """
    lines: list[str] = []
    tables = {k: v for k, v in data.items() if isinstance(v, dict)}
    arrays = {k: v for k, v in data.items() if _is_table_array(v)}
    top = {k: v for k, v in data.items() if k not in tables and k not in arrays}
    lines += _table_body(top, comments=comments)
    for key, table in tables.items():
        lines += ["", f"[{key}]", *_table_body(table, key, comments)]
    for key, entries in arrays.items():
        for entry in entries:
            lines += ["", f"[[{key}]]", *_table_body(entry, key, comments)]
    return "\n".join(lines) + "\n"
