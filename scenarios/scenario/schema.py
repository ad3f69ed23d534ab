"""The scenario file's schema, declared once: every key, its type, unit, default and meaning.

The parser (``scenarios.scenario.spec``) reads a file through ``read``, table by table;
``vnav-demo show`` annotates a built-in with each key's unit and meaning (``comment``); the
README's example is ``scenarios.scenario.toml_out.example_toml`` (a test keeps the two
identical). Units are in the key's name where it could be misread (``_m``, ``_deg``, ``_s``,
``_hz``, ``_grey``); degrees become radians once, in ``scenarios.scenario.spec`` (the noise
figures' in ``vnav.noise_model.NoiseModel``). Where a typed declaration already exists, its
keys are derived from it: ``[camera]`` from ``sim.config.CameraConfig``, ``[noise]`` from
``vnav.noise_model.NoiseModel``, ``[imu]``'s defaults from ``sim.config.ImuConfig``. A key
renamed since an earlier version (``RENAMED``) is refused with its new name.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

from scenarios.scenario.check_kinds import KINDS
from sim.config import (
    MAX_FOVY_DEG,
    MAX_IMU_POSITION_M,
    MAX_IMU_RATE_HZ,
    MAX_IMU_TIME_OFFSET_S,
    MIN_FOVY_DEG,
    CameraConfig,
    ImuConfig,
)
from vnav.diagnose import hypothesis_names
from vnav.imu import MAX_NOISE_DENSITY
from vnav.methods import METHOD_NAMES, PREFERENCE
from vnav.noise_model import FIGURES, NOISELESS

__all__ = [
    "CAMERA",
    "CHECK",
    "CONE",
    "ESTIMATE_MISTAKES",
    "FLIGHT_MODES",
    "IMU",
    "IMU_MOUNT_ERROR",
    "KEYFRAME",
    "NOISE",
    "RENAMED",
    "TIMING",
    "TOP",
    "WAYPOINT",
    "Key",
    "SchemaError",
    "comment",
    "read",
    "short",
]

VIEW_NAMES: tuple[str, ...] = ("errors", "coordinates", "attitude", "nees")
"""Values of the optional ``view`` key: which tab the recording shows first."""

CLOSE_UP_NAMES: tuple[str, ...] = ("drone", "cone")
"""Values of the optional ``close_up`` key: what the recording's second 3D view looks at,
the drone and its frames, or the first cone with its estimates and their ellipsoids."""

MAX_M = 1000.0
"""Largest distance from the origin of any position in a scenario, metres."""
MAX_S = 3600.0
"""Largest time in a scenario (and longest duration), seconds."""
MAX_DEG = 3600.0
"""Largest angle in a scenario, degrees (ten turns)."""
MAX_NAME_CHARS = 100
"""Longest scenario name: it names files, whose temporary names add about 20 characters."""
MAX_LIMIT = 1.0e6
"""Largest limit of a check."""

REQUIRED = object()
"""The default of a key that must be given."""

RENAMED: dict[str, tuple[str, str]] = {
    "noise.pixel_std_px": ("intensity_std_grey", "the same figure: 8-bit grey levels, not pixels"),
}
"""Keys of earlier versions of the file, by path: the new name and why it changed. A file that
still uses one is refused with the new name (the value means the same)."""


class SchemaError(ValueError):
    """A value that does not fit its key: ``key path: what is wrong`` (the caller adds where)."""


@dataclass(frozen=True)
class Key:
    """One key of a table of the scenario file.

    Attributes
    ----------
    name : str
    kind : {"number", "integer", "vector3", "string", "choice", "table", "tables", "any"}
        ``table`` is a TOML table, ``tables`` an array of tables (their keys are read by the
        caller, table by table); ``any`` keys are validated by whoever consumes them
        (``lesson``, checks' limits). Every other kind is checked for its type here, before any
        consumer compares or hashes the value.
    doc : str
        Meaning and unit, one line (shown by ``vnav-demo show`` and in the README).
    default : object
        Used when the key is absent; ``REQUIRED`` if it must be given, None if optional.
    lo, hi : float, optional
        Bounds of a number; ``lo_open`` makes the lower bound strict.
    choices : tuple of str
        Allowed values of a ``choice``.
    """

    name: str
    kind: str
    doc: str
    default: Any = REQUIRED
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    choices: tuple[str, ...] = ()

    def check(self, value: Any, path: str) -> Any:
        """``value`` validated (numbers as float, vectors as tuples); SchemaError otherwise."""
        if self.kind == "number":
            return number(value, path, self.lo, self.hi, self.lo_open)
        if self.kind == "integer":
            if isinstance(value, bool) or not isinstance(value, int):
                raise SchemaError(f"{path}: must be an integer, got {short(value)}")
            number(value, path, self.lo, self.hi, self.lo_open)  # bounds and size
            return value
        if self.kind == "vector3":
            if not isinstance(value, list) or len(value) != 3:
                raise SchemaError(f"{path}: must be a list of 3 numbers, got {short(value)}")
            return tuple(number(v, f"{path}[{i}]", self.lo, self.hi) for i, v in enumerate(value))
        if self.kind == "string":
            if not isinstance(value, str) or not value.strip():
                raise SchemaError(f"{path}: must be a non-empty string, got {value!r}")
            return value
        if self.kind == "choice":
            # A list or table is not a choice (and cannot be looked up in a dict of choices).
            if not isinstance(value, str) or value not in self.choices:
                raise SchemaError(
                    f"{path}: must be one of {list(self.choices)}, got {short(value)}"
                )
            return value
        if self.kind == "table" and not isinstance(value, dict):
            raise SchemaError(f"{path}: must be a table, got {_type_and_value(value)}")
        if self.kind == "tables":
            if not isinstance(value, list):
                raise SchemaError(
                    f"{path}: must be an array of tables, got {_type_and_value(value)}"
                )
            for i, entry in enumerate(value):
                if not isinstance(entry, dict):
                    raise SchemaError(f"{path}[{i}]: must be a table, got {_type_and_value(entry)}")
        return value


def number(
    value: Any, path: str, lo: float | None = None, hi: float | None = None, lo_open: bool = False
) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SchemaError(f"{path}: must be a number, got {short(value)}")
    try:
        x = float(value)
    except OverflowError:
        raise SchemaError(
            f"{path}: must be a finite number, got an integer of {value.bit_length()} bits"
        ) from None
    if not math.isfinite(x):
        raise SchemaError(f"{path}: must be finite, got {value!r}")
    if lo is not None and (x <= lo if lo_open else x < lo):
        raise SchemaError(f"{path}: must be {'>' if lo_open else '>='} {lo:g}, got {short(value)}")
    if hi is not None and x > hi:
        raise SchemaError(f"{path}: must be <= {hi:g}, got {short(value)}")
    return x


def short(value: Any) -> str:
    """``repr(value)``, cut to 60 characters: how a message shows a value it refuses."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _type_and_value(value: Any) -> str:
    return f"{type(value).__name__} {short(value)}"


def read(table: Any, keys: tuple[Key, ...], path: str) -> dict[str, Any]:
    """Every key of ``keys`` read from ``table``: validated values, defaults filled in.

    Raises
    ------
    SchemaError
        Naming the key path: not a table, an unknown key, a missing key or a bad value.
    """
    if not isinstance(table, dict):
        raise SchemaError(f"{path}: must be a table, got {type(table).__name__}")
    allowed = {k.name for k in keys}
    unknown = sorted(set(table) - allowed)
    prefix = f"{path}." if path else ""
    for name in unknown:
        if prefix + name in RENAMED:
            new, why = RENAMED[prefix + name]
            raise SchemaError(f"{prefix}{name}: renamed; write {prefix}{new} ({why})")
    if unknown:
        raise SchemaError(f"{prefix}{unknown[0]}: unknown key; expected one of {sorted(allowed)}")
    out = {}
    for key in keys:
        where = f"{path}.{key.name}" if path else key.name
        if key.name in table:
            out[key.name] = key.check(table[key.name], where)
        elif key.default is REQUIRED:
            raise SchemaError(f"{where}: missing")
        else:
            out[key.name] = key.default
    return out


# ------------------------------------------------------------------------------ the schema

TOP: tuple[Key, ...] = (
    Key("name", "string", "letters, digits, '-' and '_'; names the output files"),
    Key("description", "string", "shown by vnav-demo list and in the recording", None),
    Key("lesson", "any", "longer text shown beside the recording", ""),
    Key(
        "duration_s", "number", "optional; default: the flight's last time", None, 0.0, MAX_S, True
    ),
    Key("camera_rate_hz", "number", "camera ticks per second", 10.0, 0.0, 1000.0, True),
    Key(
        "view",
        "choice",
        "first tab below the images: errors, coordinates, attitude or nees",
        "errors",
        choices=VIEW_NAMES,
    ),
    Key(
        "close_up",
        "choice",
        "what the second 3D view looks at: the drone, or the first cone",
        "drone",
        choices=CLOSE_UP_NAMES,
    ),
    Key(
        "show_at_s",
        "number",
        "the recording's 3D views frame this instant, s (screenshots show it); default: the end",
        None,
        0.0,
        MAX_S,
    ),
    Key("camera", "table", "table: the onboard camera", None),
    Key("imu", "table", "table: an IMU on its own mount, its clock and noise (optional)", None),
    Key("cones", "tables", "array of tables: the cones", REQUIRED),
    Key("flight", "table", "table: how the drone flies", REQUIRED),
    Key("noise", "table", "table: sensor noise (pose, image, depth, camera mount)", None),
    Key("timing", "table", "table: sensor clocks, rates and latencies", None),
    Key("checks", "tables", "array of tables: pass/fail criteria", None),
)

_CAMERA_DOCS = {
    "position_b": "optical centre on the body (x forward, y left, z up), m",
    "pitch_down_deg": "optical axis below the body's x axis, deg",
    "fovy_deg": f"vertical field of view, {MIN_FOVY_DEG:g} to {MAX_FOVY_DEG:g} deg",
    "width": "image width, px",
    "height": "image height, px",
}
_MOUNT_ERROR_KEY = Key(
    "mount_error",
    "table",
    "table: the true mount = the declared one above, then this error (camera frame)",
    None,
)


def _camera_key(name: str) -> Key:
    """A ``[camera]`` key typed by its ``CameraConfig`` default (a string or a boolean where a
    number belongs is refused here, not coerced); the ranges are ``CameraConfig``'s."""
    default = getattr(CameraConfig(), name)
    if name == "position_b":
        return Key(name, "vector3", _CAMERA_DOCS[name], default, -10.0, 10.0)
    kind = "integer" if isinstance(default, int) else "number"
    return Key(name, kind, _CAMERA_DOCS[name], default)


CAMERA: tuple[Key, ...] = (
    *(_camera_key(f.name) for f in fields(CameraConfig) if f.name != "mount_error"),
    _MOUNT_ERROR_KEY,
)
"""Validated by ``sim.config.CameraConfig``, whose defaults these are (the mount within 10 m)."""

MOUNT_ERROR: tuple[Key, ...] = (
    Key(
        "position_m",
        "vector3",
        "translation in the camera frame (x right, y down, z fwd), m",
        (0.0, 0.0, 0.0),
        -1.0,
        1.0,
    ),
    Key(
        "rpy_deg",
        "vector3",
        "rotation about the camera's axes, " + "[roll, pitch, yaw], deg",
        (0.0, 0.0, 0.0),
        -45.0,
        45.0,
    ),
)
"""``[camera.mount_error]``: ``sim.config.MountError``."""

_IMU_DEFAULT = ImuConfig()
_IMU_NOISE_DOCS = {
    "accelerometer_noise_density": "accelerometer white noise density, m/s^2/sqrt(Hz)",
    "accelerometer_random_walk": "accelerometer bias random walk, m/s^3/sqrt(Hz)",
    "gyroscope_noise_density": "gyroscope white noise density, rad/s/sqrt(Hz)",
    "gyroscope_random_walk": "gyroscope bias random walk, rad/s^2/sqrt(Hz)",
}
IMU: tuple[Key, ...] = (
    Key(
        "rate_hz",
        "number",
        "readings per second, at most the physics rate, Hz",
        _IMU_DEFAULT.rate_hz,
        0.0,
        MAX_IMU_RATE_HZ,
        True,
    ),
    Key(
        "position_b",
        "vector3",
        "declared IMU origin on the body (x forward, y left, z up), m",
        _IMU_DEFAULT.position_b,
        -MAX_IMU_POSITION_M,
        MAX_IMU_POSITION_M,
    ),
    Key(
        "rpy_deg",
        "vector3",
        "declared IMU axes on the body, R_b_i = Rz(yaw) Ry(pitch) Rx(roll), "
        "[roll, pitch, yaw], deg",
        _IMU_DEFAULT.rpy_deg,
        -360.0,
        360.0,
    ),
    Key(
        "mount_error",
        "table",
        "table: the true mount = the declared one above, then this error (IMU frame)",
        None,
    ),
    Key(
        "time_offset_s",
        "number",
        "camera-IMU clock offset (Kalibr's timeshift_cam_imu): t_imu = t_cam + offset, s",
        _IMU_DEFAULT.time_offset_s,
        -MAX_IMU_TIME_OFFSET_S,
        MAX_IMU_TIME_OFFSET_S,
    ),
    *(
        Key(name, "number", doc, getattr(_IMU_DEFAULT, name), 0.0, MAX_NOISE_DENSITY)
        for name, doc in _IMU_NOISE_DOCS.items()
    ),
)
"""``[imu]``: ``sim.config.ImuConfig``, whose defaults these are (a perfect IMU at the body
origin, along the body's axes, at 200 Hz); the noise figures are Kalibr's, in its units."""

IMU_MOUNT_ERROR: tuple[Key, ...] = (
    Key(
        "position_m",
        "vector3",
        "translation in the IMU frame, m",
        (0.0, 0.0, 0.0),
        -1.0,
        1.0,
    ),
    Key(
        "rpy_deg",
        "vector3",
        "rotation about the IMU's axes, [roll, pitch, yaw], deg",
        (0.0, 0.0, 0.0),
        -45.0,
        45.0,
    ),
)
"""``[imu.mount_error]``: ``sim.config.MountError``, in the IMU's frame."""

CONE: tuple[Key, ...] = (
    Key("position_w", "vector3", "base centre in the world, z = 0, m", REQUIRED, -MAX_M, MAX_M),
)

_RPY_DOC = "[roll, pitch, yaw], R = Rz(yaw) Ry(pitch) Rx(roll), deg"
KEYFRAME: tuple[Key, ...] = (
    Key("t", "number", "time, s", REQUIRED, 0.0, MAX_S),
    Key("position_w", "vector3", "body origin in the world, m", REQUIRED, -MAX_M, MAX_M),
    Key("rpy_deg", "vector3", _RPY_DOC, REQUIRED, -MAX_DEG, MAX_DEG),
    Key("camera_position_b", "vector3", "slides the camera on the body, m", None, -10.0, 10.0),
)
WAYPOINT: tuple[Key, ...] = (
    Key("t", "number", "time, s", REQUIRED, 0.0, MAX_S),
    Key("position_w", "vector3", "body origin in the world, m", REQUIRED, -MAX_M, MAX_M),
    Key("yaw_deg", "number", "heading, deg", 0.0, -MAX_DEG, MAX_DEG),
)
_PERIOD_DOC = "one turn, s; < 0: clockwise; |period| >= 1"
MISTAKE_PREFIX = "mistake:"
ESTIMATE_MISTAKES: dict[str, str] = {
    MISTAKE_PREFIX + name.lower().replace(" ", "-"): name
    for name in hypothesis_names()
    if name != "correct"  # the chain itself is no mistake
}
"""A navigating flight's ``estimate`` that names a classic mistake of the frame chain
(``"mistake:body-rotation-dropped"``: the doctor's name, lower case, spaces as hyphens) -> that
name in ``vnav.diagnose.HYPOTHESES``: the depth image's estimates recomputed as that mistake
makes them (``scenarios.run.navigation``)."""
FLIGHT_MODES: dict[str, tuple[Key, ...]] = {
    "kinematic": (Key("keyframes", "tables", "timed poses: position linear, attitude slerp"),),
    "controlled": (
        Key("waypoints", "tables", "timed positions and headings flown by the controller"),
    ),
    "orbit": (
        Key("center_w", "vector3", "centre of the circle, m", REQUIRED, -MAX_M, MAX_M),
        Key("radius_m", "number", "radius, m", REQUIRED, 0.0, MAX_M, True),
        Key("height_m", "number", "height above the ground, m", REQUIRED, 0.0, MAX_M, True),
        Key("period_s", "number", _PERIOD_DOC, REQUIRED, -MAX_S, MAX_S),
        Key("turns", "number", "how many turns", 1.0, 0.0, 100.0, True),
        Key("start_angle_deg", "number", "start on the circle, deg", 180.0, -MAX_DEG, MAX_DEG),
        Key("ramp_s", "number", "speed-up time, s", 3.0, 0.0, 600.0),
    ),
    "navigate": (
        Key("start_w", "vector3", "where the flight starts, m", REQUIRED, -MAX_M, MAX_M),
        Key("goal_w", "vector3", "where the drone must go, m", REQUIRED, -MAX_M, MAX_M),
        Key("speed_mps", "number", "cruise speed along the plan, m/s", 2.0, 0.0, 10.0, True),
        Key(
            "clearance_m",
            "number",
            "distance to keep between the drone's centre and each estimated cone's axis, m",
            1.0,
            0.0,
            100.0,
            True,
        ),
        Key(
            "estimate",
            "choice",
            "whose cone estimates the planner avoids: a method of vnav.methods, or "
            '"mistake:<name>", depth_image\'s as a classic mistake (vnav.diagnose) makes them',
            PREFERENCE[0],
            choices=(*METHOD_NAMES, *ESTIMATE_MISTAKES),
        ),
    ),
}
"""The keys of ``[flight]`` per ``mode`` (besides ``mode`` itself)."""

NOISE: tuple[Key, ...] = tuple(
    Key(name, "number", figure.line, getattr(NOISELESS, name), figure.lo, figure.hi)
    for name, figure in FIGURES.items()
)
"""``[noise]``: one key per ``vnav.noise_model.NoiseModel`` field, its doc, unit, range and
default from the field's ``Figure``; validated here, then by ``NoiseModel``."""
MAX_LATENCY_S = 5.0
"""Largest latency, clock offset and jitter of ``[timing]``, seconds."""
TIMING: tuple[Key, ...] = (
    Key(
        "pose_rate_hz",
        "number",
        "pose samples per second sent to the estimator, Hz",
        200.0,
        0.0,
        1000.0,
        True,
    ),
    Key(
        "pose_latency_s",
        "number",
        "a pose stamped at t arrives at t + latency, s",
        0.0,
        0.0,
        MAX_LATENCY_S,
    ),
    Key(
        "image_latency_s",
        "number",
        "an image arrives this long after its exposure, s",
        0.0,
        0.0,
        MAX_LATENCY_S,
    ),
    Key(
        "camera_clock_offset_s",
        "number",
        "t_pose = t_cam + offset, s",
        0.0,
        -MAX_LATENCY_S,
        MAX_LATENCY_S,
    ),
    Key("jitter_s", "number", "standard deviation of each arrival's extra delay, s", 0.0, 0.0, 1.0),
)
CHECK: tuple[Key, ...] = (
    Key(
        "kind",
        "choice",
        "a check kind (scenarios.scenario.check_kinds.KINDS)",
        choices=tuple(KINDS),
    ),
    Key(
        "method",
        "choice",
        "a localisation method (vnav.methods)",
        PREFERENCE[0],
        choices=METHOD_NAMES,
    ),
    Key("limit", "any", "the limit (give limit or limit_m)", None),
    Key("limit_m", "any", "the limit in metres", None),
    Key("name", "string", "what the report calls it", None),
)


def comment(path: str, table: dict[str, Any] | None = None) -> str | None:
    """The schema's one-line doc of the key at ``path`` (``camera.fovy_deg``), or None.

    ``table``, the table holding the key, lets a check's ``kind`` and limit say what that kind
    asserts and in which unit its limit is (``scenarios.scenario.check_kinds.KINDS``).
    """
    if path == "flight.mode":
        return " | ".join(FLIGHT_MODES) + " (each mode has its own keys)"
    parent, _, name = path.rpartition(".")
    if parent == "checks" and table is not None and name in ("kind", "limit", "limit_m"):
        kind = KINDS.get(table.get("kind"))  # type: ignore[arg-type]
        if kind is not None:
            return kind.doc.replace("``", "") if name == "kind" else kind.limit_doc
    keys = {
        "": TOP,
        "camera": CAMERA,
        "camera.mount_error": MOUNT_ERROR,
        "imu": IMU,
        "imu.mount_error": IMU_MOUNT_ERROR,
        "noise": NOISE,
        "timing": TIMING,
        "flight": tuple(k for mode in FLIGHT_MODES.values() for k in mode),
        "flight.keyframes": KEYFRAME,
        "flight.waypoints": WAYPOINT,
        "cones": CONE,
        "checks": CHECK,
    }.get(parent, ())
    return next((k.doc for k in keys if k.name == name), None)
