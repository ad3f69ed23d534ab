"""Typed scene configuration: frozen dataclasses, validated when they are made.

Every field is checked in ``__post_init__``; nonsense raises ``ValueError`` naming the field,
what was expected and what was received. Degrees appear here only, in names that say so; the
simulator converts them at the edge.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from vnav import frames, se3, so3
from vnav.imu import ImuNoise


@dataclass(frozen=True)
class RenderQuality:
    """MuJoCo's rendering settings behind one quality name.

    Attributes
    ----------
    shadowsize : int
        Side of the shadow map in texels (0: no shadows).
    offsamples : int
        Multisamples of the off-screen buffer (0: no anti-aliasing).
    """

    shadowsize: int
    offsamples: int

    @property
    def shadows(self) -> bool:
        """Whether shadows are drawn."""
        return self.shadowsize > 0


RENDER_QUALITY: dict[str, RenderQuality] = {
    "fast": RenderQuality(shadowsize=0, offsamples=0),
    "high": RenderQuality(shadowsize=4096, offsamples=4),
}
"""``fast``: no shadow map, no multisampling (about 7 ms per 640x480 image on a CPU);
``high``: 4096 shadow map and 4x multisampling, for pictures."""
RENDER_QUALITIES: tuple[str, ...] = tuple(RENDER_QUALITY)

MAX_IMAGE_SIZE_PX = 8192
MIN_FOVY_DEG = 1.0
"""Narrowest vertical field of view: below it OpenGL's single precision misplaces what it
draws (a point off by 0.08 px at 0.1 deg, 0.8 px at 0.01 deg: measured against the
projection), and a field of view that rounds to zero is no camera at all."""
MAX_FOVY_DEG = 170.0
"""Widest vertical field of view a pinhole (rectilinear) camera is given: beyond it the
focal length falls under 21 px per 480 rows and a lens would be a fisheye, which vnav does
not model (and towards 180 deg MuJoCo draws nothing)."""
SKY_MARGIN = 5.0
"""zfar_m >= SKY_MARGIN * ground_size_m: MuJoCo's sky dome lies about 0.7 zfar from the
camera, and the far corner of the ground is at most 2 sqrt(2) ground_size_m away."""


def _vector(value: Any, length: int, name: str) -> tuple[float, ...]:
    """Check ``value`` is ``length`` finite numbers; return them as a tuple of float."""
    try:
        items = tuple(float(v) for v in value)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ValueError(f"{name} must be {length} numbers, got {value!r}") from exc
    if len(items) != length:
        raise ValueError(f"{name} must have {length} elements, got {len(items)}: {value!r}")
    if not all(math.isfinite(v) for v in items):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return items


def _finite(value: Any, name: str) -> float:
    try:
        out = float(value)
    except OverflowError as exc:
        raise ValueError(
            f"{name} must be a finite number, got an integer of {value.bit_length()} bits"
        ) from exc
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a number, got {value!r}") from exc
    if not math.isfinite(out):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return out


def _size(value: Any, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | float) or int(value) != value:
        raise ValueError(f"{name} must be a whole number of pixels, got {value!r}")
    if not 1 <= int(value) <= MAX_IMAGE_SIZE_PX:
        raise ValueError(f"{name} must be in [1, {MAX_IMAGE_SIZE_PX}] pixels, got {value!r}")
    return int(value)


def _check_names(cls: type, kwargs: dict[str, Any]) -> None:
    valid = {f.name for f in fields(cls)}
    unknown = sorted(set(kwargs) - valid)
    if unknown:
        raise ValueError(
            f"unknown {cls.__name__} field(s) {unknown}; valid fields are {sorted(valid)}"
        )


MAX_MOUNT_ERROR_M = 1.0
MAX_MOUNT_ERROR_DEG = 45.0


@dataclass(frozen=True)
class MountError:
    """How a sensor's true mount differs from the declared one: the true mount is the
    declared mount, then this transform in the (declared) sensor frame: the camera's
    ``T_b_c_true = T_b_c_declared @ E``, the IMU's ``T_b_i_true = T_b_i_declared @ E``.

    Attributes
    ----------
    position_m : tuple of 3 float
        ``E``'s translation in the sensor's frame (the camera's optical frame, the IMU's
        frame), metres, each within 1 m.
    rpy_deg : tuple of 3 float
        ``E``'s rotation ``Rz(yaw) Ry(pitch) Rx(roll)`` about the sensor's axes, degrees, each
        within 45.
    """

    position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for name, limit in (("position_m", MAX_MOUNT_ERROR_M), ("rpy_deg", MAX_MOUNT_ERROR_DEG)):
            values = _vector(getattr(self, name), 3, f"mount_error.{name}")
            if not all(abs(v) <= limit for v in values):
                raise ValueError(f"mount_error.{name} must be within +-{limit:g}, got {values}")
            object.__setattr__(self, name, values)

    @property
    def T(self) -> np.ndarray:
        """``E``, (4, 4)."""
        roll, pitch, yaw = (math.radians(a) for a in self.rpy_deg)
        return se3.make(so3.from_rpy(roll, pitch, yaw), np.asarray(self.position_m))

    @property
    def is_zero(self) -> bool:
        return not any(self.position_m) and not any(self.rpy_deg)

    @property
    def angle_deg(self) -> float:
        """The angle of ``E``'s rotation, degrees: how far the true mount is turned from the
        declared one, whatever the axis (not the sum or norm of ``rpy_deg``)."""
        return math.degrees(float(np.linalg.norm(so3.log(self.T[:3, :3]))))

    @property
    def offset_m(self) -> float:
        """The length of ``E``'s translation, metres: how far the true camera centre is from
        the declared one."""
        return float(np.linalg.norm(self.position_m))


@dataclass(frozen=True)
class CameraConfig:
    """The onboard camera: where it sits on the body and what it images.

    Attributes
    ----------
    position_b : tuple of 3 float
        Optical centre in the body frame (FLU), metres.
    pitch_down_deg : float
        Tilt of the optical axis below the body's x axis, degrees, in [-90, 90]
        (``R_b_c = rot_y(pitch_down) @ R_FLU_RDF``).
    fovy_deg : float
        Vertical field of view, degrees, in [``MIN_FOVY_DEG``, ``MAX_FOVY_DEG``] = [1, 170].
    width, height : int
        Image size in pixels.
    mount_error : MountError
        The true mount's error from the declared one above (what the estimator is told):
        the simulator renders through ``T_b_c``, the true mount.
    """

    position_b: tuple[float, float, float] = (0.15, 0.0, 0.05)
    pitch_down_deg: float = 30.0
    fovy_deg: float = 60.0
    width: int = 640
    height: int = 480
    mount_error: MountError = field(default_factory=MountError)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "position_b", _vector(self.position_b, 3, "CameraConfig.position_b"))
        pitch = _finite(self.pitch_down_deg, "CameraConfig.pitch_down_deg")
        if not -90.0 <= pitch <= 90.0:
            raise ValueError(f"CameraConfig.pitch_down_deg must be in [-90, 90], got {pitch}")
        set_(self, "pitch_down_deg", pitch)
        fovy = _finite(self.fovy_deg, "CameraConfig.fovy_deg")
        if not MIN_FOVY_DEG <= fovy <= MAX_FOVY_DEG:
            raise ValueError(
                f"CameraConfig.fovy_deg must be in [{MIN_FOVY_DEG:g}, {MAX_FOVY_DEG:g}] degrees, "
                f"got {fovy!r}"
            )
        set_(self, "fovy_deg", fovy)
        set_(self, "width", _size(self.width, "CameraConfig.width"))
        set_(self, "height", _size(self.height, "CameraConfig.height"))
        if isinstance(self.mount_error, dict):
            _check_names(MountError, self.mount_error)
            set_(self, "mount_error", MountError(**self.mount_error))
        elif not isinstance(self.mount_error, MountError):
            raise ValueError(f"CameraConfig.mount_error must be a table, got {self.mount_error!r}")

    @property
    def T_b_c_declared(self) -> np.ndarray:
        """(4, 4) the declared mount: the optical frame in the body frame from ``position_b``
        and ``pitch_down_deg`` (``vnav.frames.mount_rotation``)."""
        R_b_c = frames.mount_rotation(math.radians(self.pitch_down_deg))
        return se3.make(R_b_c, np.asarray(self.position_b, dtype=np.float64))

    @property
    def T_b_c(self) -> np.ndarray:
        """(4, 4) the true mount, ``T_b_c_declared @ mount_error.T``: what MuJoCo renders."""
        if self.mount_error.is_zero:
            return self.T_b_c_declared
        return self.T_b_c_declared @ self.mount_error.T

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> CameraConfig:
        """Build from a mapping (``mount_error`` a mapping too), rejecting unknown keys with a
        ValueError."""
        _check_names(cls, values)
        return cls(**values)


MAX_IMU_RATE_HZ = 10000.0
"""Largest IMU sampling rate accepted here; a scene also keeps it at most its physics rate."""
MAX_IMU_TIME_OFFSET_S = 5.0
"""Largest camera-IMU clock offset, seconds (as the ``[timing]`` offsets)."""
MAX_IMU_POSITION_M = 10.0
"""Farthest an IMU sits from the body origin along each axis, metres (as the camera)."""


@dataclass(frozen=True)
class ImuConfig:
    """An IMU on its own mount: where it sits on the body, its clock, rate and noise.

    Attributes
    ----------
    rate_hz : float
        Readings per second, in (0, ``MAX_IMU_RATE_HZ``]; a scene keeps it at most its physics
        rate (a reading is the state after a physics step).
    position_b : tuple of 3 float
        The declared IMU origin in the body frame (FLU), metres, each within 10 m.
    rpy_deg : tuple of 3 float
        The declared IMU axes in the body frame, ``R_b_i = Rz(yaw) Ry(pitch) Rx(roll)``,
        degrees, ``[roll, pitch, yaw]``.
    mount_error : MountError
        The true mount's error from the declared one, in the IMU frame:
        ``T_b_i = T_b_i_declared @ E``. The simulator's IMU sits at the true mount; an
        estimator is told the declared one.
    time_offset_s : float
        The camera-IMU clock offset, Kalibr's ``timeshift_cam_imu``:
        ``t_imu = t_cam + time_offset_s``, seconds, within 5 s.
    accelerometer_noise_density, accelerometer_random_walk, gyroscope_noise_density,
    gyroscope_random_walk : float
        Kalibr's noise figures in Kalibr's units (``vnav.imu.ImuNoise``): m/s^2/sqrt(Hz),
        m/s^3/sqrt(Hz), rad/s/sqrt(Hz), rad/s^2/sqrt(Hz).
    """

    rate_hz: float = 200.0
    position_b: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mount_error: MountError = field(default_factory=MountError)
    time_offset_s: float = 0.0
    accelerometer_noise_density: float = 0.0
    accelerometer_random_walk: float = 0.0
    gyroscope_noise_density: float = 0.0
    gyroscope_random_walk: float = 0.0

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        rate = _finite(self.rate_hz, "ImuConfig.rate_hz")
        if not 0.0 < rate <= MAX_IMU_RATE_HZ:
            raise ValueError(f"ImuConfig.rate_hz must be in (0, {MAX_IMU_RATE_HZ:g}], got {rate}")
        set_(self, "rate_hz", rate)
        position_b = _vector(self.position_b, 3, "ImuConfig.position_b")
        if not all(abs(v) <= MAX_IMU_POSITION_M for v in position_b):
            raise ValueError(
                f"ImuConfig.position_b must be within +-{MAX_IMU_POSITION_M:g} m, got {position_b}"
            )
        set_(self, "position_b", position_b)
        set_(self, "rpy_deg", _vector(self.rpy_deg, 3, "ImuConfig.rpy_deg"))
        if isinstance(self.mount_error, dict):
            _check_names(MountError, self.mount_error)
            set_(self, "mount_error", MountError(**self.mount_error))
        elif not isinstance(self.mount_error, MountError):
            raise ValueError(f"ImuConfig.mount_error must be a table, got {self.mount_error!r}")
        offset = _finite(self.time_offset_s, "ImuConfig.time_offset_s")
        if abs(offset) > MAX_IMU_TIME_OFFSET_S:
            raise ValueError(
                f"ImuConfig.time_offset_s must be within +-{MAX_IMU_TIME_OFFSET_S:g} s, "
                f"got {offset}"
            )
        set_(self, "time_offset_s", offset)
        self.noise  # noqa: B018 -- validates the four figures (ImuNoise's messages)

    @property
    def noise(self) -> ImuNoise:
        """The four noise figures as ``vnav.imu.ImuNoise``."""
        return ImuNoise(
            accelerometer_noise_density=self.accelerometer_noise_density,
            accelerometer_random_walk=self.accelerometer_random_walk,
            gyroscope_noise_density=self.gyroscope_noise_density,
            gyroscope_random_walk=self.gyroscope_random_walk,
        )

    @property
    def T_b_i_declared(self) -> np.ndarray:
        """(4, 4) the declared mount: the IMU frame in the body frame."""
        roll, pitch, yaw = (math.radians(a) for a in self.rpy_deg)
        return se3.make(so3.from_rpy(roll, pitch, yaw), np.asarray(self.position_b))

    @property
    def T_b_i(self) -> np.ndarray:
        """(4, 4) the true mount, ``T_b_i_declared @ mount_error.T``: where the simulator's
        IMU site is."""
        if self.mount_error.is_zero:
            return self.T_b_i_declared
        return self.T_b_i_declared @ self.mount_error.T

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> ImuConfig:
        """Build from a mapping (``mount_error`` a mapping too), rejecting unknown keys with a
        ValueError."""
        _check_names(cls, values)
        return cls(**values)


@dataclass(frozen=True)
class SceneConfig:
    """A scene: the drone's start pose, its camera and the cones.

    Attributes
    ----------
    camera : CameraConfig
        The onboard camera.
    cones_w : tuple of (x, y, z)
        Each cone's base centre in the world, metres; z must be 0 (cones stand on the ground).
    start_position_w : tuple of 3 float
        Initial body origin in the world, metres.
    start_quat_xyzw : tuple of 4 float
        Initial body attitude ``R_w_b`` as a unit quaternion, scalar last.
    timestep_s : float
        Physics time step, seconds, in (0, 0.1]. The default, 5 ms, samples the state at
        200 Hz: the pose stream's default rate (``scenarios.scenario.spec.Timing``).
    render_quality : str
        ``"fast"`` or ``"high"`` (see ``RENDER_QUALITIES``).
    ground_size_m : float
        Half side of the square ground plane, metres.
    znear_m, zfar_m : float
        Near and far clipping distances of every camera, metres; ``zfar_m`` must be at least
        ``SKY_MARGIN * ground_size_m`` (depth reads ``zfar_m`` on the sky).
    imu : ImuConfig or None
        The IMU, if the scene has one declared: its site sits at the true mount
        ``imu.T_b_i``, and ``imu.rate_hz`` is at most the physics rate. None: the model's IMU
        site stays at the body origin, axes along the body's (nothing reads it).
    """

    camera: CameraConfig = field(default_factory=CameraConfig)
    cones_w: tuple[tuple[float, float, float], ...] = ((6.0, 1.0, 0.0),)
    start_position_w: tuple[float, float, float] = (0.0, 0.0, 10.0)
    start_quat_xyzw: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    timestep_s: float = 0.005
    render_quality: str = "fast"
    ground_size_m: float = 200.0
    znear_m: float = 0.05
    zfar_m: float = 1000.0
    imu: ImuConfig | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        if not isinstance(self.camera, CameraConfig):
            raise ValueError(
                f"SceneConfig.camera must be a CameraConfig, got {type(self.camera).__name__}"
            )
        set_(self, "cones_w", _cones_on_ground(self.cones_w))
        set_(
            self,
            "start_position_w",
            _vector(self.start_position_w, 3, "SceneConfig.start_position_w"),
        )
        set_(self, "start_quat_xyzw", _unit_quaternion(self.start_quat_xyzw))
        dt = _finite(self.timestep_s, "SceneConfig.timestep_s")
        if not 0.0 < dt <= 0.1:
            raise ValueError(f"SceneConfig.timestep_s must be in (0, 0.1] seconds, got {dt}")
        set_(self, "timestep_s", dt)
        if self.render_quality not in RENDER_QUALITY:
            raise ValueError(
                f"SceneConfig.render_quality must be one of {RENDER_QUALITIES}, got "
                f"{self.render_quality!r}"
            )
        ground = _finite(self.ground_size_m, "SceneConfig.ground_size_m")
        if ground <= 0.0:
            raise ValueError(f"SceneConfig.ground_size_m must be positive, got {ground}")
        set_(self, "ground_size_m", ground)
        znear, zfar = _clip_planes(self.znear_m, self.zfar_m, ground)
        set_(self, "znear_m", znear)
        set_(self, "zfar_m", zfar)
        if isinstance(self.imu, dict):
            set_(self, "imu", ImuConfig.from_dict(self.imu))
        elif self.imu is not None and not isinstance(self.imu, ImuConfig):
            raise ValueError(
                f"SceneConfig.imu must be an ImuConfig or None, got {type(self.imu).__name__}"
            )
        if self.imu is not None and self.imu.rate_hz > 1.0 / dt + 1e-9:
            raise ValueError(
                f"SceneConfig.imu.rate_hz must be at most the physics rate, {1.0 / dt:g} Hz "
                f"(one reading per physics step), got {self.imu.rate_hz:g}"
            )

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> SceneConfig:
        """Build from a nested mapping (e.g. parsed TOML), rejecting unknown keys.

        ``camera`` may be a mapping of ``CameraConfig`` fields, ``imu`` of ``ImuConfig``'s.
        """
        _check_names(cls, values)
        values = dict(values)
        camera = values.get("camera")
        if isinstance(camera, dict):
            values["camera"] = CameraConfig.from_dict(camera)
        if "cones_w" in values:
            values["cones_w"] = tuple(tuple(c) for c in values["cones_w"])
        return cls(**values)


def _cones_on_ground(cones_w: Any) -> tuple[tuple[float, float, float], ...]:
    """Validated cone base centres: a sequence of (x, y, 0)."""
    try:
        cones = tuple(cones_w)
    except TypeError as exc:
        raise ValueError(
            f"SceneConfig.cones_w must be a sequence of (x, y, z), got {cones_w!r}"
        ) from exc
    checked = []
    for i, cone in enumerate(cones):
        p_w = _vector(cone, 3, f"SceneConfig.cones_w[{i}]")
        if p_w[2] != 0.0:
            where = "is under the ground (z < 0)" if p_w[2] < 0.0 else "floats above the ground"
            raise ValueError(
                f"SceneConfig.cones_w[{i}] = {p_w} {where}; cones stand on the ground, z = 0"
            )
        checked.append(p_w)
    return tuple(checked)


def _unit_quaternion(value: Any) -> tuple[float, ...]:
    """A validated unit quaternion [x, y, z, w] (norm within 1e-6 of 1)."""
    q = _vector(value, 4, "SceneConfig.start_quat_xyzw")
    norm = math.sqrt(sum(v * v for v in q))
    if abs(norm - 1.0) > 1e-6:
        raise ValueError(
            f"SceneConfig.start_quat_xyzw must be a unit quaternion [x, y, z, w], got "
            f"{q} with norm {norm}"
        )
    return q


def _clip_planes(znear_m: Any, zfar_m: Any, ground_size_m: float) -> tuple[float, float]:
    """Validated clipping distances: ``0 < znear < zfar`` and the ground inside the sky dome."""
    znear = _finite(znear_m, "SceneConfig.znear_m")
    zfar = _finite(zfar_m, "SceneConfig.zfar_m")
    if not 0.0 < znear < zfar:
        raise ValueError(
            f"SceneConfig.znear_m and zfar_m must satisfy 0 < znear_m < zfar_m, got "
            f"znear_m={znear}, zfar_m={zfar}"
        )
    if zfar < SKY_MARGIN * ground_size_m:
        raise ValueError(
            f"SceneConfig.zfar_m ({zfar}) must be at least {SKY_MARGIN} x ground_size_m "
            f"({ground_size_m}) so that the whole ground lies inside the sky dome"
        )
    return znear, zfar
