"""What a scenario is: a typed specification, read from TOML or built in Python.

A scenario file (TOML) holds, in user units (metres, degrees, seconds), the keys that
``scenarios.scenario.schema`` declares (each with its type, unit, default and meaning; the README's
example is generated from it). ``from_dict`` reads a parsed file table by table through the
schema and builds the typed ``ScenarioSpec`` below.

Every mistake raises ``ScenarioError`` (a ValueError) naming the file and the key.
Angles become radians and ``rpy_deg`` becomes a quaternion once, here, so a keyframe at
pitch = 90 deg is as good as any other.
"""

from __future__ import annotations

import math
import os
import re
import stat
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from scenarios.scenario import schema
from scenarios.scenario.check_kinds import KINDS, Check, Unit
from sim.config import CameraConfig, ImuConfig, SceneConfig
from vnav import quat, so3
from vnav.methods import METHODS, method
from vnav.noise_model import NOISELESS, NoiseModel

MAX_FILE_BYTES = 1_000_000
"""Largest scenario file read, bytes."""
MAX_SEED = 2**63 - 1
"""The largest seed a run takes (``--seed``, a sweep's seeds): numpy's generators take any
non-negative int, the reports write it as a 64-bit integer."""
MAX_NESTING = 16
"""Deepest nesting of tables and arrays a file may hold: a scenario needs 4
(``flight.keyframes[0].position_w[2]``); every reader after the parser (copies, the writer
of grid points, JSON) recurses once per level, and must never meet Python's recursion limit."""


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


GOAL_RADIUS_M = 0.3
"""A navigating flight has reached its goal when its body origin is this close to it, m."""


@dataclass(frozen=True)
class NavigateFlight:
    """Closed loop: the drone flies to a goal around the cones its estimator has mapped.

    At every camera tick the cones estimated by ``estimate`` (a method of ``vnav.methods``, or
    ``"mistake:<name>"``: depth_image's estimates as a classic mistake of ``vnav.diagnose``
    makes them, ``scenarios.scenario.schema.ESTIMATE_MISTAKES``) update the map, and the path
    from the drone's estimated position to the goal is planned again to keep ``clearance_m``
    from each mapped cone (``vnav.navigate``); the controller flies it at ``speed_mps``. The
    flight ends at the goal (within ``GOAL_RADIUS_M``), at the first contact with a cone, or at
    the run's end.
    """

    start_w: tuple[float, float, float]
    goal_w: tuple[float, float, float]
    speed_mps: float = 2.0
    clearance_m: float = 1.0
    estimate: str = "depth_image"
    mode: str = "navigate"
    moves_camera = False

    @property
    def straight_m(self) -> float:
        """The straight line's length from start to goal, m."""
        return math.dist(self.start_w, self.goal_w)

    @property
    def end_s(self) -> float:
        # Time for a detour of twice the straight line, and 5 s to take off and settle.
        return 2.0 * self.straight_m / self.speed_mps + 5.0

    @property
    def start_yaw_rad(self) -> float:
        """Heading at the start: at the goal."""
        return math.atan2(self.goal_w[1] - self.start_w[1], self.goal_w[0] - self.start_w[0])


@dataclass(frozen=True)
class Timing:
    """The sensors' clocks and links (``scenarios.run.streams``; docs/CONVENTIONS.md, "Time").

    Attributes
    ----------
    pose_rate_hz : float
        Pose samples per second the estimator receives (at most the physics rate: a sample
        is the state after a physics step).
    pose_latency_s : float
        A pose stamped at ``t`` arrives at ``t + pose_latency_s``.
    image_latency_s : float
        An image arrives this long after its exposure.
    camera_clock_offset_s : float
        ``t_pose = t_cam + camera_clock_offset_s``: how a camera stamp reads on the pose clock.
    jitter_s : float
        Standard deviation of each arrival's extra delay (drawn from the run's seed).
    """

    pose_rate_hz: float = 200.0
    pose_latency_s: float = 0.0
    image_latency_s: float = 0.0
    camera_clock_offset_s: float = 0.0
    jitter_s: float = 0.0

    @property
    def delivers_late(self) -> bool:
        """A pose or an image can arrive after its stamp (a latency or jitter): the newest
        pose at an image's arrival can then differ from its exposure pose. (A clock offset
        alone changes the stamps, not the arrivals.)"""
        return self.pose_latency_s > 0.0 or self.image_latency_s > 0.0 or self.jitter_s > 0.0

    @property
    def synchronous(self) -> bool:
        """No latency, offset or jitter: each image is processed the moment it is taken."""
        return (
            self.pose_latency_s == 0.0
            and self.image_latency_s == 0.0
            and self.camera_clock_offset_s == 0.0
            and self.jitter_s == 0.0
        )


@dataclass(frozen=True)
class ScenarioSpec:
    """Everything needed to run a scenario, in SI units and vnav conventions."""

    name: str
    description: str
    scene: SceneConfig
    flight: KinematicFlight | ControlledFlight | OrbitFlight | NavigateFlight
    camera_rate_hz: float = 10.0
    duration_s: float | None = None
    noise: NoiseModel = NOISELESS
    """The sensors' noise (``[noise]``): what the simulator draws and the estimator is told."""
    timing: Timing = field(default_factory=Timing)
    checks: tuple[Check, ...] = ()
    lesson: str = ""
    view: str = "errors"
    """The recording's first tab below the error plot: errors, coordinates, attitude or nees."""
    close_up: str = "drone"
    """What the recording's second 3D view looks at: the drone, or the first cone."""
    show_at_s: float | None = None
    """The instant the recording's 3D views are framed for and its screenshot shows, simulated
    seconds (the camera tick at or before it); None: the last tick."""

    @property
    def end_s(self) -> float:
        """Simulated time at which the run stops, seconds."""
        return self.duration_s if self.duration_s is not None else self.flight.end_s

    @property
    def n_ticks(self) -> int:
        """Camera ticks of the run: at t = 0, 1 / rate, ... up to ``end_s``."""
        return math.floor(self.end_s * self.camera_rate_hz + 1e-9) + 1

    @property
    def checks_calibration(self) -> bool:
        """Whether a check judges the camera's calibration (a ``calibration_*`` kind): the
        mount and clock offset are then recovered from the run (``scenarios.pipeline``) and
        the recording shows them."""
        return any(
            c.kind.startswith("calibration_") and not c.kind.startswith("calibration_imu_")
            for c in self.checks
        )

    @property
    def checks_imu_calibration(self) -> bool:
        """Whether a check judges the camera-IMU calibration (a ``calibration_imu_*`` kind):
        ``T_i_c`` and the camera-IMU clock offset are then recovered from the run's images and
        IMU readings (``scenarios.pipeline``)."""
        return any(c.kind.startswith("calibration_imu_") for c in self.checks)


# --------------------------------------------------------------------------------------------
# Parsing: ``scenarios.scenario.schema`` reads and checks each table; here values become typed
# specs.


def _read(table: Any, keys: tuple[schema.Key, ...], where: str, path: str) -> dict[str, Any]:
    try:
        return schema.read(table, keys, path)
    except schema.SchemaError as exc:
        raise ScenarioError(f"{where}: {exc}") from None


def _err(where: str, key: str, message: str) -> ScenarioError:
    return ScenarioError(f"{where}: {key}: {message}")


def _or_empty(table: dict[str, Any] | None) -> dict[str, Any]:
    """An optional table: absent reads as empty (``or {}`` would also take ``[]`` or ``0``)."""
    return {} if table is None else table


def _entries(value: Any, where: str, path: str) -> list[Any]:
    if not isinstance(value, list) or not value:
        raise _err(where, path, "must be a non-empty list of tables")
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


def _flight(
    table: dict[str, Any], where: str
) -> KinematicFlight | ControlledFlight | OrbitFlight | NavigateFlight:
    mode = table.get("mode")  # a table: the schema's TOP says so
    # A list or table is no mode (and cannot be looked up among the modes).
    if not isinstance(mode, str) or mode not in schema.FLIGHT_MODES:
        modes = list(schema.FLIGHT_MODES)
        quoted = ", ".join(f'"{m}"' for m in modes[:-1]) + f' or "{modes[-1]}"'
        raise _err(where, "flight.mode", f"must be {quoted}, got {schema.short(mode)}")
    body = {k: v for k, v in table.items() if k != "mode"}
    values = _read(body, schema.FLIGHT_MODES[mode], where, "flight")
    if mode == "kinematic":
        raw = _entries(values["keyframes"], where, "flight.keyframes")
        keyframes = []
        for i, entry in enumerate(raw):
            k = _read(entry, schema.KEYFRAME, where, f"flight.keyframes[{i}]")
            keyframes.append(
                keyframe_from_rpy_deg(k["t"], k["position_w"], k["rpy_deg"], k["camera_position_b"])
            )
        _times_increasing([k.t_s for k in keyframes], where, "flight.keyframes")
        return KinematicFlight(tuple(keyframes))
    if mode == "controlled":
        raw = _entries(values["waypoints"], where, "flight.waypoints")
        waypoints = []
        for i, entry in enumerate(raw):
            w = _read(entry, schema.WAYPOINT, where, f"flight.waypoints[{i}]")
            waypoints.append(Waypoint(w["t"], w["position_w"], math.radians(w["yaw_deg"])))
        _times_increasing([w.t_s for w in waypoints], where, "flight.waypoints")
        return ControlledFlight(tuple(waypoints))
    if mode == "navigate":
        return _navigate(values, where)
    if abs(values["period_s"]) < 1.0:
        raise _err(
            where,
            "flight.period_s",
            f"must be at least 1 s in magnitude (negative: clockwise), got {values['period_s']}",
        )
    start_angle_rad = math.radians(values.pop("start_angle_deg"))
    return OrbitFlight(**values, start_angle_rad=start_angle_rad)


def _navigate(values: dict[str, Any], where: str) -> NavigateFlight:
    """``[flight]`` of mode ``navigate``: a start and a goal above the ground, apart."""
    for key in ("start_w", "goal_w"):
        if values[key][2] <= 0.0:
            z_m = values[key][2]
            raise _err(where, f"flight.{key}", f"must be above the ground (z > 0), got z = {z_m:g}")
    flight = NavigateFlight(**values)
    if flight.straight_m <= GOAL_RADIUS_M:
        raise _err(
            where,
            "flight.goal_w",
            f"must be more than {GOAL_RADIUS_M:g} m (the goal's radius) from start_w, "
            f"got {flight.straight_m:.3g} m",
        )
    return flight


def _checks(raw: Any, where: str) -> tuple[Check, ...]:
    if not isinstance(raw, list):
        raise _err(where, "checks", "must be an array of tables ([[checks]])")
    out = []
    for i, entry in enumerate(raw):
        key = f"checks[{i}]"
        c = _read(entry, schema.CHECK, where, key)  # kind and method: names of KINDS, METHODS
        if c["kind"] == "error_bound" and method(c["method"]).bound is None:
            bounded = [m.name for m in METHODS if m.bound is not None]
            raise _err(
                where,
                f"{key}.method",
                f"{c['method']} has no accuracy bound to check; error_bound takes one of {bounded}",
            )
        if (c["limit"] is None) == (c["limit_m"] is None):
            raise _err(where, key, "give exactly one of limit or limit_m")
        unit = KINDS[c["kind"]].unit
        if c["limit_m"] is not None and unit is not Unit.METRES:
            raise _err(
                where,
                f"{key}.limit_m",
                f"{c['kind']}'s limit is a {unit.value}, not metres; give it as limit",
            )
        limit_key = "limit" if c["limit"] is not None else "limit_m"
        try:
            limit = schema.number(c[limit_key], f"{key}.{limit_key}", 0.0, schema.MAX_LIMIT)
        except schema.SchemaError as exc:
            raise ScenarioError(f"{where}: {exc}") from None
        out.append(Check(kind=c["kind"], limit=limit, method=c["method"], name=c["name"] or ""))
    return tuple(out)


def _cones(raw: Any, where: str) -> list[tuple[float, ...]]:
    if not isinstance(raw, list) or not raw:
        raise _err(where, "cones", "must be a non-empty array of tables ([[cones]])")
    return [
        _read(entry, schema.CONE, where, f"cones[{i}]")["position_w"] for i, entry in enumerate(raw)
    ]


def _start_pose(flight) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The drone's start position and attitude (quaternion xyzw) for a flight."""
    if isinstance(flight, KinematicFlight):
        return flight.keyframes[0].position_w, flight.keyframes[0].quat_xyzw
    if isinstance(flight, ControlledFlight):
        position_w, yaw_rad = flight.waypoints[0].position_w, flight.waypoints[0].yaw_rad
    elif isinstance(flight, NavigateFlight):
        position_w, yaw_rad = flight.start_w, flight.start_yaw_rad
    else:
        position_w = flight.start_position_w
        yaw_rad = flight.start_angle_rad + math.pi  # heading at the centre
    return position_w, tuple(map(float, quat.from_axis_angle([0.0, 0.0, 1.0], yaw_rad)))


def _camera(table: Any, where: str) -> CameraConfig:
    """``[camera]`` and its optional ``[camera.mount_error]``."""
    camera_table = _read(_or_empty(table), schema.CAMERA, where, "camera")
    if camera_table["mount_error"] is None:
        del camera_table["mount_error"]
    else:
        camera_table["mount_error"] = _read(
            camera_table["mount_error"], schema.MOUNT_ERROR, where, "camera.mount_error"
        )
    try:
        return CameraConfig.from_dict(camera_table)
    except ValueError as exc:
        raise _err(where, "camera", str(exc)) from None


def _imu(table: Any, flight: Any, where: str) -> ImuConfig | None:
    """``[imu]`` and its optional ``[imu.mount_error]``; None without ``[imu]``.

    A kinematic flight is refused: it places the body pose by pose, with no accelerations for
    an accelerometer to read."""
    if table is None:
        return None
    imu_table = _read(table, schema.IMU, where, "imu")
    if imu_table["mount_error"] is None:
        del imu_table["mount_error"]
    else:
        imu_table["mount_error"] = _read(
            imu_table["mount_error"], schema.IMU_MOUNT_ERROR, where, "imu.mount_error"
        )
    if isinstance(flight, KinematicFlight):
        raise _err(
            where,
            "imu",
            'needs a flight with dynamics ("controlled", "orbit" or "navigate"): a kinematic '
            "flight is placed pose by pose, with no accelerations to read",
        )
    physics_hz = 1.0 / SceneConfig.timestep_s
    if imu_table["rate_hz"] > physics_hz + 1e-9:
        raise _err(
            where,
            "imu.rate_hz",
            f"must be at most the physics rate, {physics_hz:g} Hz (one reading per physics "
            f"step), got {imu_table['rate_hz']:g}",
        )
    try:
        return ImuConfig.from_dict(imu_table)
    except ValueError as exc:
        raise _err(where, "imu", str(exc)) from None


def _at_most_physics_rate(
    physics_hz: float, camera_rate_hz: float, timing: Timing, where: str
) -> None:
    """One image, and one pose, per physics step at most."""
    if camera_rate_hz > physics_hz + 1e-9:
        raise _err(
            where,
            "camera_rate_hz",
            f"must be at most the physics rate, {physics_hz:g} Hz (one image per physics step), "
            f"got {camera_rate_hz:g}",
        )
    if timing.pose_rate_hz > physics_hz + 1e-9:
        raise _err(
            where,
            "timing.pose_rate_hz",
            f"must be at most the physics rate, {physics_hz:g} Hz (one pose per physics step), "
            f"got {timing.pose_rate_hz:g}",
        )


def _name(top: dict[str, Any], where: str) -> str:
    """The scenario's ``name``, checked: it names files and recordings.

    Parameters
    ----------
    top : dict
        The top-level table, as ``schema.TOP`` reads it.
    where : str
        What to call the source in error messages.

    Returns
    -------
    str
        The name: ASCII letters, digits, ``-`` and ``_``, at most ``schema.MAX_NAME_CHARS``.

    Raises
    ------
    ScenarioError
        If the name holds another character or is too long.
    """
    name = top["name"]
    if not all(c.isascii() and (c.isalnum() or c in "-_") for c in name):
        raise _err(where, "name", f"may hold letters, digits, '-' and '_' only, got {name!r}")
    if len(name) > schema.MAX_NAME_CHARS:
        raise _err(
            where, "name", f"must be at most {schema.MAX_NAME_CHARS} characters, got {len(name)}"
        )
    return name


def _scene_and_flight(
    top: dict[str, Any], where: str
) -> tuple[SceneConfig, KinematicFlight | ControlledFlight | OrbitFlight | NavigateFlight]:
    """The world (``[camera]``, ``[[cones]]``, ``[imu]``, the drone's start pose) and the
    ``[flight]`` it starts from, read in that order (camera, cones, flight, imu), so that
    the first bad table is the one reported.

    Parameters
    ----------
    top : dict
        The top-level table, as ``schema.TOP`` reads it.
    where : str
        What to call the source in error messages.

    Returns
    -------
    scene : SceneConfig
    flight : KinematicFlight | ControlledFlight | OrbitFlight | NavigateFlight

    Raises
    ------
    ScenarioError
        Naming the offending table; ``cones`` where ``SceneConfig`` refuses the cones.
    """
    camera = _camera(top["camera"], where)
    cones_w = _cones(top["cones"], where)
    flight = _flight(top["flight"], where)
    imu = _imu(top["imu"], flight, where)
    start_position_w, start_quat_xyzw = _start_pose(flight)
    try:
        scene = SceneConfig(
            camera=camera,
            cones_w=tuple(cones_w),
            start_position_w=start_position_w,
            start_quat_xyzw=start_quat_xyzw,
            imu=imu,
        )
    except ValueError as exc:
        raise _err(where, "cones", str(exc)) from None
    return scene, flight


def _show_at_within_run(spec: ScenarioSpec, where: str) -> None:
    """Refuse a ``show_at_s`` (the instant the recording's 3D views are framed for) after the
    run's end.

    Raises
    ------
    ScenarioError
        If ``spec.show_at_s`` is later than ``spec.end_s``.
    """
    if spec.show_at_s is not None and spec.show_at_s > spec.end_s:
        raise _err(
            where,
            "show_at_s",
            f"must be at most the run's end, {spec.end_s:g} s, got {spec.show_at_s:g}",
        )


def from_dict(data: dict[str, Any], where: str = "<scenario>") -> ScenarioSpec:
    """Build a ``ScenarioSpec`` from parsed TOML (user units), as ``scenarios.scenario.schema``
    declares.

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
    top = _read(data, schema.TOP, where, "")
    name = _name(top, where)
    scene, flight = _scene_and_flight(top, where)
    noise = NoiseModel(**_read(_or_empty(top["noise"]), schema.NOISE, where, "noise"))
    timing = Timing(**_read(_or_empty(top["timing"]), schema.TIMING, where, "timing"))
    _at_most_physics_rate(1.0 / scene.timestep_s, top["camera_rate_hz"], timing, where)
    if not isinstance(top["lesson"], str):
        raise _err(where, "lesson", f"must be a string, got {type(top['lesson']).__name__}")
    spec = ScenarioSpec(
        name=name,
        description=top["description"] or name,
        scene=scene,
        flight=flight,
        camera_rate_hz=top["camera_rate_hz"],
        duration_s=top["duration_s"],
        noise=noise,
        timing=timing,
        checks=_checks(top["checks"], where) if top["checks"] is not None else (),
        lesson=top["lesson"],
        view=top["view"],
        close_up=top["close_up"],
        show_at_s=top["show_at_s"],
    )
    _show_at_within_run(spec, where)
    return spec


def load_toml(path: str | Path) -> ScenarioSpec:
    """Read a scenario file (a regular file of at most ``MAX_FILE_BYTES``).

    Raises
    ------
    ScenarioError
        If the file is missing, not a regular file (a FIFO, a device, a directory), too large
        or unreadable, is not valid TOML (the message gives the line and column), or holds an
        invalid value (the message gives the key).
    """
    return from_dict(read_toml(path), where=str(path))


def read_toml(path: str | Path, what: str = "scenario file") -> dict[str, Any]:
    """The parsed TOML of a file (a regular file of at most ``MAX_FILE_BYTES``), unchecked;
    ``what`` names the kind of file in the messages.

    Raises
    ------
    ScenarioError
        If the file is missing, not a regular file, too large, unreadable or not valid TOML.
    """
    path = Path(path)
    try:
        # Opened without blocking and checked before reading: a FIFO would wait for a writer,
        # /dev/zero would never end.
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
        with os.fdopen(fd, "rb") as f:
            if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
                raise ScenarioError(f"{path}: not a regular file")
            raw = f.read(MAX_FILE_BYTES + 1)
    except FileNotFoundError:
        raise ScenarioError(f"{path}: no such {what}") from None
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read: {exc.strerror}") from None
    if len(raw) > MAX_FILE_BYTES:
        raise ScenarioError(f"{path}: larger than {MAX_FILE_BYTES} bytes; not a {what}")
    try:
        text = raw.decode("utf-8")
        data = tomllib.loads(text)
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{path}: cannot read: not UTF-8 text ({exc.reason})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: invalid TOML: {exc}") from None
    except ValueError as exc:  # e.g. an integer beyond Python's digit limit
        raise ScenarioError(f"{path}: invalid TOML: {exc}") from None
    except RecursionError:  # tomllib recurses once per level of nested arrays or tables
        raise ScenarioError(f"{path}: {_too_deep_in_text(text)}") from None
    too_deep = _too_deep(data)
    if too_deep is not None:
        raise ScenarioError(f"{path}: {too_deep}: {_NESTING_MESSAGE}")
    return data


_NESTING_MESSAGE = f"tables and arrays nested more than {MAX_NESTING} deep"

# What the nesting scan of a file steps over: strings (which may hold brackets) and comments.
_TOKEN = re.compile(
    r'"""(?:\\.|[^\\])*?"""|\'\'\'[\s\S]*?\'\'\'|"(?:\\.|[^"\\\n])*"|\'[^\'\n]*\''
    r"|#[^\n]*|[\[\]{}\n]"
)


def _too_deep(data: dict[str, Any]) -> str | None:
    """The path of the first value nested deeper than ``MAX_NESTING`` (``a.b[0][0]``), or
    None. Walked with a stack, not recursion: this is the guard against it."""
    stack: list[tuple[Any, str, int]] = [(data, "", 0)]
    while stack:
        value, path, depth = stack.pop()
        if depth > MAX_NESTING:
            return path
        if isinstance(value, dict):
            stack.extend(
                (v, f"{path}.{k}" if path else str(k), depth + 1) for k, v in value.items()
            )
        elif isinstance(value, list):
            stack.extend((v, f"{path}[{i}]", depth + 1) for i, v in enumerate(value))
    return None


def _too_deep_in_text(text: str) -> str:
    """Where a file too deep for the parser first nests deeper than ``MAX_NESTING``: ``line N:
    KEY: ...``, KEY being what the line that opened the outermost bracket assigns, in the
    table of the header above it."""
    depth, line, opened, table = 0, 1, (1, ""), ""
    for match in _TOKEN.finditer(text):
        token = match.group()
        if token in "[{":
            if depth == 0:
                start = text.rfind("\n", 0, match.start()) + 1
                end = text.find("\n", match.start())
                before = text[start : match.start()]
                if not before.strip():  # a [table] or [[array]] header: its brackets close here
                    header = text[match.start() : len(text) if end < 0 else end]
                    table = header.partition("#")[0].strip().strip("[]").strip()
                    key = ""
                else:
                    key = before.partition("=")[0].strip()
                opened = (line, f"{table}.{key}" if table and key else key)
            depth += 1
            if depth > MAX_NESTING:
                key = f"{opened[1]}: " if opened[1] else ""
                return f"line {opened[0]}: {key}{_NESTING_MESSAGE}"
        elif token in "]}":
            depth = max(depth - 1, 0)
        line += token.count("\n")
    return f"invalid TOML: {_NESTING_MESSAGE}"
