"""What a scenario is: a typed specification, read from TOML or built in Python.

A scenario file (TOML) holds, in user units (metres, degrees, seconds)::

    name = "my-scene"
    description = "one line"
    duration_s = 5.0          # optional; default: the flight's last time
    camera_rate_hz = 10.0

    [camera]                  # sim.config.CameraConfig fields
    position_b = [0.15, 0.0, 0.05]
    pitch_down_deg = 30.0

    [[cones]]
    position_w = [6.0, 1.0, 0.0]

    [flight]
    mode = "kinematic"        # keyframes: position linear, attitude slerp
    keyframes = [ { t = 0.0, position_w = [0, 0, 10], rpy_deg = [0, 0, 0] }, ... ]
    # a keyframe may also slide the camera on the body: camera_position_b = [0.3, 0.0, 0.05]
    # mode = "controlled"     # waypoints flown by the geometric controller
    # waypoints = [ { t = 0.0, position_w = [0, 0, 10], yaw_deg = 0.0 }, ... ]
    # mode = "orbit"          # a smooth circle, heading at the centre (controller)
    # center_w = [0, 0, 0]; radius_m = 6.0; height_m = 4.0; period_s = 20.0 (< 0: clockwise)
    # turns = 1.0; start_angle_deg = 180.0; ramp_s = 3.0

    [noise]                   # optional, drawn from the run's seed
    position_std_m = 0.0      # error added to the body position the estimator is given
    attitude_std_deg = 0.0    # error (random rotation vector) added to its attitude

    view = "coordinates"      # optional: first tab in the recording (errors, coordinates,
                              # attitude)

    [[checks]]                # optional; default: the accuracy bounds of every method
    kind = "max_error"
    method = "depth_image"
    limit_m = 0.1

Every mistake raises :class:`ScenarioError` (a ValueError) naming the file and the key.
Angles become radians and ``rpy_deg`` becomes a quaternion once, here, so a keyframe at
pitch = 90 deg is as good as any other.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from scenarios.checks import KINDS, Check
from sim.config import CameraConfig, SceneConfig
from vnav import quat, so3
from vnav.methods import METHOD_NAMES

VIEW_NAMES: tuple[str, ...] = ("errors", "coordinates", "attitude")
"""Values of the optional ``view`` key: which tab the recording shows first."""


class ScenarioError(ValueError):
    """A scenario file or specification that cannot be run; the message names the key."""


@dataclass(frozen=True)
class Keyframe:
    """A prescribed body pose at a time: ``T_w_b`` from ``position_w`` and ``quat_xyzw``.

    ``camera_position_b``, if given, slides the camera on the body to that offset (linearly
    between keyframes), the lecture's chapter 8 composer; None keeps the [camera] position.
    """

    t_s: float
    position_w: tuple[float, float, float]
    quat_xyzw: tuple[float, float, float, float]
    camera_position_b: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class Waypoint:
    """A position and heading the controller must pass at a time."""

    t_s: float
    position_w: tuple[float, float, float]
    yaw_rad: float


@dataclass(frozen=True)
class KinematicFlight:
    """Timed keyframes written straight into the free joint (no dynamics)."""

    keyframes: tuple[Keyframe, ...]
    mode: str = "kinematic"

    @property
    def moves_camera(self) -> bool:
        """True if any keyframe slides the camera on the body."""
        return any(k.camera_position_b is not None for k in self.keyframes)

    @property
    def end_s(self) -> float:
        return self.keyframes[-1].t_s


@dataclass(frozen=True)
class ControlledFlight:
    """Timed waypoints flown by the geometric controller."""

    waypoints: tuple[Waypoint, ...]
    mode: str = "controlled"
    moves_camera = False

    @property
    def end_s(self) -> float:
        return self.waypoints[-1].t_s


@dataclass(frozen=True)
class OrbitFlight:
    """A smooth circle around a point, flown by the controller, heading at the centre."""

    center_w: tuple[float, float, float]
    radius_m: float
    height_m: float
    period_s: float
    turns: float = 1.0
    start_angle_rad: float = math.pi
    ramp_s: float = 3.0
    mode: str = "orbit"
    moves_camera = False

    @property
    def end_s(self) -> float:
        # The ramp covers half the angle it would at full speed (sim.flight.OrbitTrajectory).
        return self.ramp_s / 2.0 + self.turns * abs(self.period_s)

    @property
    def start_position_w(self) -> tuple[float, float, float]:
        return (
            self.center_w[0] + self.radius_m * math.cos(self.start_angle_rad),
            self.center_w[1] + self.radius_m * math.sin(self.start_angle_rad),
            self.height_m,
        )


@dataclass(frozen=True)
class Noise:
    """Errors added to the body pose the estimator is given (the truth is untouched)."""

    position_std_m: float = 0.0
    attitude_std_deg: float = 0.0


@dataclass(frozen=True)
class ScenarioSpec:
    """Everything needed to run a scenario, in SI units and vnav conventions."""

    name: str
    description: str
    scene: SceneConfig
    flight: KinematicFlight | ControlledFlight | OrbitFlight
    camera_rate_hz: float = 10.0
    duration_s: float | None = None
    noise: Noise = field(default_factory=Noise)
    checks: tuple[Check, ...] = ()
    lesson: str = ""
    view: str = "errors"
    """The recording's first tab below the error plot: errors, coordinates or attitude."""

    @property
    def end_s(self) -> float:
        """Simulated time at which the run stops, seconds."""
        return self.duration_s if self.duration_s is not None else self.flight.end_s


# --------------------------------------------------------------------------------------------
# Parsing. Each helper takes the key path so that a message can say where the problem is.


def _err(where: str, key: str, message: str) -> ScenarioError:
    return ScenarioError(f"{where}: {key}: {message}")


def _table(value: Any, where: str, key: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise _err(where, key, f"must be a table, got {type(value).__name__}")
    return value


def _allowed(table: dict[str, Any], allowed: set[str], where: str, key: str) -> None:
    unknown = sorted(set(table) - allowed)
    if unknown:
        prefix = f"{key}." if key else ""
        raise _err(where, prefix + unknown[0], f"unknown key; expected one of {sorted(allowed)}")


def _number(
    value: Any,
    where: str,
    key: str,
    *,
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _err(where, key, f"must be a number, got {value!r}")
    x = float(value)
    if not math.isfinite(x):
        raise _err(where, key, f"must be finite, got {value!r}")
    if lo is not None and (x <= lo if lo_open else x < lo):
        raise _err(where, key, f"must be {'>' if lo_open else '>='} {lo}, got {value!r}")
    if hi is not None and x > hi:
        raise _err(where, key, f"must be <= {hi}, got {value!r}")
    return x


def _vector(value: Any, n: int, where: str, key: str) -> tuple[float, ...]:
    if not isinstance(value, list) or len(value) != n:
        raise _err(where, key, f"must be a list of {n} numbers, got {value!r}")
    return tuple(_number(v, where, f"{key}[{i}]") for i, v in enumerate(value))


def _string(value: Any, where: str, key: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise _err(where, key, f"must be a non-empty string, got {value!r}")
    return value


def _times_increasing(times: list[float], where: str, key: str) -> None:
    if times[0] != 0.0:
        raise _err(where, f"{key}[0].t", f"the first entry must be at t = 0, got {times[0]}")
    for i in range(1, len(times)):
        if times[i] <= times[i - 1]:
            raise _err(
                where, f"{key}[{i}].t", f"times must increase, got {times[i]} after {times[i - 1]}"
            )


def keyframe_from_rpy_deg(
    t_s: float, position_w: Any, rpy_deg: Any, camera_position_b: Any = None
) -> Keyframe:
    """A keyframe from roll/pitch/yaw in degrees (R = Rz(yaw) Ry(pitch) Rx(roll))."""
    roll, pitch, yaw = np.radians(np.asarray(rpy_deg, dtype=float))
    quat_xyzw = quat.from_matrix(so3.from_rpy(roll, pitch, yaw))
    camera = None if camera_position_b is None else tuple(map(float, camera_position_b))
    return Keyframe(float(t_s), tuple(map(float, position_w)), tuple(map(float, quat_xyzw)), camera)


def _flight(table: dict[str, Any], where: str) -> KinematicFlight | ControlledFlight:
    mode = table.get("mode")
    if mode == "kinematic":
        _allowed(table, {"mode", "keyframes"}, where, "flight")
        raw = table.get("keyframes")
        if not isinstance(raw, list) or not raw:
            raise _err(where, "flight.keyframes", "must be a non-empty list of tables")
        keyframes = []
        for i, entry in enumerate(raw):
            key = f"flight.keyframes[{i}]"
            entry = _table(entry, where, key)
            _allowed(entry, {"t", "position_w", "rpy_deg", "camera_position_b"}, where, key)
            for needed in ("t", "position_w", "rpy_deg"):
                if needed not in entry:
                    raise _err(where, f"{key}.{needed}", "missing")
            camera_b = entry.get("camera_position_b")
            keyframes.append(
                keyframe_from_rpy_deg(
                    _number(entry["t"], where, f"{key}.t", lo=0.0),
                    _vector(entry["position_w"], 3, where, f"{key}.position_w"),
                    _vector(entry["rpy_deg"], 3, where, f"{key}.rpy_deg"),
                    None
                    if camera_b is None
                    else _vector(camera_b, 3, where, f"{key}.camera_position_b"),
                )
            )
        _times_increasing([k.t_s for k in keyframes], where, "flight.keyframes")
        return KinematicFlight(tuple(keyframes))
    if mode == "controlled":
        _allowed(table, {"mode", "waypoints"}, where, "flight")
        raw = table.get("waypoints")
        if not isinstance(raw, list) or not raw:
            raise _err(where, "flight.waypoints", "must be a non-empty list of tables")
        waypoints = []
        for i, entry in enumerate(raw):
            key = f"flight.waypoints[{i}]"
            entry = _table(entry, where, key)
            _allowed(entry, {"t", "position_w", "yaw_deg"}, where, key)
            for needed in ("t", "position_w"):
                if needed not in entry:
                    raise _err(where, f"{key}.{needed}", "missing")
            waypoints.append(
                Waypoint(
                    _number(entry["t"], where, f"{key}.t", lo=0.0),
                    _vector(entry["position_w"], 3, where, f"{key}.position_w"),
                    math.radians(_number(entry.get("yaw_deg", 0.0), where, f"{key}.yaw_deg")),
                )
            )
        _times_increasing([w.t_s for w in waypoints], where, "flight.waypoints")
        return ControlledFlight(tuple(waypoints))
    if mode == "orbit":
        keys = {
            "mode",
            "center_w",
            "radius_m",
            "height_m",
            "period_s",
            "turns",
            "start_angle_deg",
            "ramp_s",
        }
        _allowed(table, keys, where, "flight")
        for needed in ("center_w", "radius_m", "height_m", "period_s"):
            if needed not in table:
                raise _err(where, f"flight.{needed}", "missing")
        period = _number(table["period_s"], where, "flight.period_s")
        if abs(period) < 1.0:
            raise _err(
                where,
                "flight.period_s",
                f"must be at least 1 s in magnitude (negative: clockwise), got {period}",
            )
        return OrbitFlight(
            center_w=_vector(table["center_w"], 3, where, "flight.center_w"),
            radius_m=_number(table["radius_m"], where, "flight.radius_m", lo=0.0, lo_open=True),
            height_m=_number(table["height_m"], where, "flight.height_m", lo=0.0, lo_open=True),
            period_s=period,
            turns=_number(table.get("turns", 1.0), where, "flight.turns", lo=0.0, lo_open=True),
            start_angle_rad=math.radians(
                _number(table.get("start_angle_deg", 180.0), where, "flight.start_angle_deg")
            ),
            ramp_s=_number(table.get("ramp_s", 3.0), where, "flight.ramp_s", lo=0.0),
        )
    raise _err(where, "flight.mode", f'must be "kinematic", "controlled" or "orbit", got {mode!r}')


def _checks(raw: Any, where: str) -> tuple[Check, ...]:
    if not isinstance(raw, list):
        raise _err(where, "checks", "must be an array of tables ([[checks]])")
    out = []
    for i, entry in enumerate(raw):
        key = f"checks[{i}]"
        entry = _table(entry, where, key)
        _allowed(entry, {"kind", "method", "limit", "limit_m", "name"}, where, key)
        kind = entry.get("kind")
        if kind not in KINDS:
            raise _err(where, f"{key}.kind", f"unknown check {kind!r}; valid: {sorted(KINDS)}")
        method = entry.get("method", "depth_image")
        if method not in METHOD_NAMES:
            raise _err(
                where, f"{key}.method", f"unknown method {method!r}; valid: {list(METHOD_NAMES)}"
            )
        if ("limit" in entry) == ("limit_m" in entry):
            raise _err(where, key, "give exactly one of limit or limit_m")
        limit_key = "limit" if "limit" in entry else "limit_m"
        limit = _number(entry[limit_key], where, f"{key}.{limit_key}", lo=0.0)
        name = _string(entry["name"], where, f"{key}.name") if "name" in entry else ""
        out.append(Check(kind=kind, limit=limit, method=method, name=name))
    return tuple(out)


def from_dict(data: dict[str, Any], where: str = "<scenario>") -> ScenarioSpec:
    """Build a :class:`ScenarioSpec` from parsed TOML (user units).

    Parameters
    ----------
    data : dict
        The parsed file.
    where : str
        What to call the source in error messages (usually the file name).

    Raises
    ------
    ScenarioError
        Naming ``where`` and the offending key.
    """
    _allowed(
        data,
        {
            "name",
            "description",
            "duration_s",
            "camera_rate_hz",
            "camera",
            "cones",
            "flight",
            "noise",
            "checks",
            "lesson",
            "view",
        },
        where,
        "",
    )
    for needed in ("name", "flight", "cones"):
        if needed not in data:
            raise _err(where, needed, "missing")
    name = _string(data["name"], where, "name")
    if not all(c.isalnum() or c in "-_" for c in name):
        raise _err(where, "name", f"may hold letters, digits, '-' and '_' only, got {name!r}")
    description = _string(data.get("description", name), where, "description")

    camera_table = _table(data.get("camera", {}), where, "camera")
    try:
        camera = CameraConfig.from_dict(camera_table)
    except ValueError as exc:
        raise _err(where, "camera", str(exc)) from None

    cones_raw = data["cones"]
    if not isinstance(cones_raw, list) or not cones_raw:
        raise _err(where, "cones", "must be a non-empty array of tables ([[cones]])")
    cones_w = []
    for i, entry in enumerate(cones_raw):
        entry = _table(entry, where, f"cones[{i}]")
        _allowed(entry, {"position_w"}, where, f"cones[{i}]")
        if "position_w" not in entry:
            raise _err(where, f"cones[{i}].position_w", "missing")
        cones_w.append(_vector(entry["position_w"], 3, where, f"cones[{i}].position_w"))

    flight = _flight(_table(data["flight"], where, "flight"), where)
    if isinstance(flight, KinematicFlight):
        start_position_w = flight.keyframes[0].position_w
        start_quat_xyzw = flight.keyframes[0].quat_xyzw
    else:
        if isinstance(flight, ControlledFlight):
            start_position_w = flight.waypoints[0].position_w
            start_yaw_rad = flight.waypoints[0].yaw_rad
        else:
            start_position_w = flight.start_position_w
            start_yaw_rad = flight.start_angle_rad + math.pi  # heading at the centre
        start_quat_xyzw = tuple(map(float, quat.from_axis_angle([0.0, 0.0, 1.0], start_yaw_rad)))
    try:
        scene = SceneConfig(
            camera=camera,
            cones_w=tuple(cones_w),
            start_position_w=start_position_w,
            start_quat_xyzw=start_quat_xyzw,
        )
    except ValueError as exc:
        raise _err(where, "cones", str(exc)) from None

    rate = _number(
        data.get("camera_rate_hz", 10.0), where, "camera_rate_hz", lo=0.0, lo_open=True, hi=1000.0
    )
    duration = None
    if "duration_s" in data:
        duration = _number(data["duration_s"], where, "duration_s", lo=0.0, lo_open=True)

    noise_table = _table(data.get("noise", {}), where, "noise")
    _allowed(noise_table, {"position_std_m", "attitude_std_deg"}, where, "noise")
    noise = Noise(
        _number(noise_table.get("position_std_m", 0.0), where, "noise.position_std_m", lo=0.0),
        _number(noise_table.get("attitude_std_deg", 0.0), where, "noise.attitude_std_deg", lo=0.0),
    )
    checks = _checks(data["checks"], where) if "checks" in data else ()
    lesson = data.get("lesson", "")
    if not isinstance(lesson, str):
        raise _err(where, "lesson", f"must be a string, got {type(lesson).__name__}")
    view = data.get("view", "errors")
    if view not in VIEW_NAMES:
        raise _err(where, "view", f"must be one of {list(VIEW_NAMES)}, got {view!r}")
    return ScenarioSpec(
        view=view,
        name=name,
        description=description,
        scene=scene,
        flight=flight,
        camera_rate_hz=rate,
        duration_s=duration,
        noise=noise,
        checks=checks,
        lesson=lesson,
    )


def load_toml(path: str | Path) -> ScenarioSpec:
    """Read a scenario file.

    Raises
    ------
    ScenarioError
        If the file is missing or unreadable, is not valid TOML (the message gives the line and
        column), or holds an invalid value (the message gives the key).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ScenarioError(f"{path}: no such scenario file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"{path}: cannot read: {exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: invalid TOML: {exc}") from None
    return from_dict(data, where=str(path))
