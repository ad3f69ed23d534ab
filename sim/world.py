"""The simulated world: a quadrotor with a body-mounted camera among traffic cones.

The model is assembled in code with ``mujoco.MjSpec``: ``models/scene.xml`` (ground, sky,
lights, and the quadrotor of ``models/quadrotor.xml``) is loaded, then the onboard camera, an
external chase camera and the cones (a mesh built from ``vnav.cone.TRAFFIC_CONE``) are added.

Ground truth comes out in vnav's conventions (docs/CONVENTIONS.md): ``T_w_b`` (body FLU in the
world ENU), ``T_b_c`` (the mount, optical frame RDF), ``T_w_c`` and the pinhole intrinsics that
describe MuJoCo's rendering exactly, ``T_b_i`` (the IMU's true mount, where its site sits) and
the body's accelerations (``acceleration_w``, ``angular_acceleration_b``).

MuJoCo's camera frame (``glc``: x right, y up, looking along -z) never leaves this module:
``R_b_glc = R_b_c @ R_GLC_RDF`` where ``R_GLC_RDF = diag(1, -1, -1)``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from importlib import resources
from pathlib import Path

import numpy as np

from sim import names
from sim.config import RENDER_QUALITY, CameraConfig, SceneConfig
from sim.gl import mujoco
from vnav import frames, quat, se3
from vnav.camera import PinholeCamera
from vnav.cone import TRAFFIC_CONE, ConeModel

logger = logging.getLogger(__name__)

CONE_MESH_SEGMENTS = 64
"""Vertices around the cone's circular section (the rendered cone is a 64-sided pyramid)."""
CONE_SHELL_MASS_KG = 1.2
CONE_BASE_MASS_KG = 1.5

MAX_SPEED_M_S = 200.0
"""Above this linear speed the state is declared exploding."""
MAX_ANGULAR_SPEED_RAD_S = 500.0
"""Above this angular speed the state is declared exploding."""
MAX_DISTANCE_M = 1.0e5
"""Further than this from the origin the state is declared exploding."""

GROUND_GRID_SPACING_M = 10.0
"""Rendering grid of the ground plane (see build_spec)."""

CHASE_OFFSET_W = (-3.0, 0.0, 1.5)
"""Where the chase camera sits relative to the drone, metres, along the world's axes: MuJoCo's
``track`` camera mode keeps this offset in world coordinates as the drone turns."""


_INSTABILITY_WARNINGS = (
    (mujoco.mjtWarning.mjWARN_BADQPOS, "position (qpos) became NaN, inf or huge"),
    (mujoco.mjtWarning.mjWARN_BADQVEL, "velocity (qvel) became NaN, inf or huge"),
    (mujoco.mjtWarning.mjWARN_BADQACC, "acceleration (qacc) became NaN, inf or huge"),
)
_WARNING_INDEX = np.array([int(w) for w, _ in _INSTABILITY_WARNINGS])
_FAST_QVEL2 = min(MAX_SPEED_M_S, MAX_ANGULAR_SPEED_RAD_S) ** 2
"""Below this |qvel|^2 no speed limit can be exceeded (the fast path of World.step)."""
_FAST_QPOS2 = MAX_DISTANCE_M**2
"""Below this |qpos|^2 (position plus a unit quaternion per body) the position is in range."""


class SimulationError(RuntimeError):
    """The simulation produced a NaN or an exploding state."""


def models_dir() -> Path:
    """Directory holding ``scene.xml`` and ``quadrotor.xml``."""
    return Path(str(resources.files("models")))


def _mat_to_quat_wxyz(R: np.ndarray) -> np.ndarray:
    """Rotation matrix -> MuJoCo quaternion [w, x, y, z] (through vnav's xyzw)."""
    return quat.xyzw_to_wxyz(quat.from_matrix(np.asarray(R, dtype=np.float64)))


def cone_mesh_vertices(cone: ConeModel = TRAFFIC_CONE, segments: int = CONE_MESH_SEGMENTS):
    """Vertices of the cone's body (the part above the base plate), in the cone frame.

    The cone frame has its origin at the base centre on the ground, z up. The body is a circle
    of radius ``body_radius_m`` on top of the base plate and the apex at ``height_m``; MuJoCo
    takes their convex hull.

    Returns
    -------
    np.ndarray, shape (segments + 1, 3)
        Metres.
    """
    angles = np.linspace(0.0, 2.0 * math.pi, segments, endpoint=False)
    ring = np.column_stack(
        [
            cone.body_radius_m * np.cos(angles),
            cone.body_radius_m * np.sin(angles),
            np.full(segments, cone.base_thickness_m),
        ]
    )
    return np.vstack([ring, [[0.0, 0.0, cone.height_m]]])


def build_spec(cfg: SceneConfig, cone: ConeModel = TRAFFIC_CONE) -> mujoco.MjSpec:
    """Assemble the scene's ``mujoco.MjSpec`` from the configuration.

    Parameters
    ----------
    cfg : SceneConfig
        The scene.
    cone : ConeModel
        The cone's dimensions and colour.

    Returns
    -------
    mujoco.MjSpec
        Not yet compiled.
    """
    spec = mujoco.MjSpec.from_file(str(models_dir() / "scene.xml"))
    spec.option.timestep = cfg.timestep_s
    _set_visual(spec, cfg)

    # The plane is drawn as a grid of quads this many metres wide: 1 m quads over a 400 m
    # plane cost ~8 ms per 640x480 image on a CPU renderer; 10 m quads cost ~1 ms.
    ground = spec.geom(names.GROUND_GEOM)
    ground.size = [cfg.ground_size_m, cfg.ground_size_m, GROUND_GRID_SPACING_M]

    # Drone start pose (the free joint's initial qpos comes from the body pose).
    drone = spec.body(names.DRONE_BODY)
    drone.pos = list(cfg.start_position_w)
    drone.quat = list(quat.xyzw_to_wxyz(np.asarray(cfg.start_quat_xyzw, dtype=np.float64)))
    _add_cameras(drone, cfg.camera)

    # The IMU site (MuJoCo's accelerometer and gyro read there) at the true mount: the
    # model's site stays at the body origin when the scene declares no IMU.
    if cfg.imu is not None:
        T_b_i = cfg.imu.T_b_i
        imu = spec.site(names.IMU_SITE)
        imu.pos = list(T_b_i[:3, 3])
        imu.quat = list(_mat_to_quat_wxyz(T_b_i[:3, :3]))

    add_cones(spec, cfg.cones_w, cone)
    return spec


def _set_visual(spec: mujoco.MjSpec, cfg: SceneConfig) -> None:
    """The rendering settings: off-screen buffer, clipping planes in metres, shadows, quality.

    Parameters
    ----------
    spec : mujoco.MjSpec
        The scene, edited in place.
    cfg : SceneConfig
        The scene: its camera's image size, clipping distances and render quality.
    """
    # Off-screen buffer at least as large as the configured image; clipping planes in metres
    # (MuJoCo scales znear/zfar by the model extent, which we fix).
    cam_cfg = cfg.camera
    spec.visual.global_.offwidth = max(640, cam_cfg.width)
    spec.visual.global_.offheight = max(480, cam_cfg.height)
    extent_m = 10.0
    spec.stat.extent = extent_m
    spec.visual.map.znear = cfg.znear_m / extent_m
    spec.visual.map.zfar = cfg.zfar_m / extent_m
    # Shadow map ("high" quality) covering +-30 m: tighter clips show acne on the ground.
    spec.visual.map.shadowclip = 3.0
    quality = RENDER_QUALITY[cfg.render_quality]
    spec.visual.quality.shadowsize = quality.shadowsize
    spec.visual.quality.offsamples = quality.offsamples


def _add_cameras(drone: mujoco.MjsBody, cam_cfg: CameraConfig) -> None:
    """The onboard camera at its mount and the chase camera, both on the drone's body.

    Parameters
    ----------
    drone : mujoco.MjsBody
        The drone's body in the spec, edited in place.
    cam_cfg : CameraConfig
        The onboard camera: its mount ``T_b_c`` (optical frame, ``docs/CONVENTIONS.md``) and
        its vertical field of view.
    """
    # Onboard camera: optical R_b_c from the mount, turned into MuJoCo's camera convention.
    R_b_glc = cam_cfg.T_b_c[:3, :3] @ frames.R_GLC_RDF
    drone.add_camera(
        name=names.ONBOARD_CAMERA,
        pos=list(cam_cfg.T_b_c[:3, 3]),
        quat=list(_mat_to_quat_wxyz(R_b_glc)),
        fovy=cam_cfg.fovy_deg,
    )

    # Chase camera: follows the drone's position with a world-aligned offset, looks at it.
    offset = np.asarray(CHASE_OFFSET_W, dtype=np.float64)
    z_glc = offset / np.linalg.norm(offset)  # looks along -z_glc = -offset: at the drone
    x_glc = np.cross([0.0, 0.0, 1.0], z_glc)
    x_glc /= np.linalg.norm(x_glc)
    y_glc = np.cross(z_glc, x_glc)
    chase = drone.add_camera(
        name=names.CHASE_CAMERA,
        pos=list(offset),
        quat=list(_mat_to_quat_wxyz(np.column_stack([x_glc, y_glc, z_glc]))),
        fovy=50.0,
    )
    chase.mode = mujoco.mjtCamLight.mjCAMLIGHT_TRACK


def add_cones(
    spec: mujoco.MjSpec, cones_w: tuple[tuple[float, float, float], ...], cone: ConeModel
) -> None:
    """Add the cone mesh and material, and one static cone body per position.

    Each cone body's origin is its base centre on the ground (the compiler re-centres the mesh
    on its centre of mass and moves the geom by as much, so the vertices stay where given).
    """
    mesh = spec.add_mesh(name=names.CONE_MESH)
    mesh.uservert = cone_mesh_vertices(cone).ravel().tolist()
    rgba = [*cone.color_rgb, 1.0]
    spec.add_material(
        name=names.CONE_MATERIAL,
        rgba=rgba,
        specular=0.15,
        shininess=0.2,
        emission=0.15,
    )
    for i, p_w in enumerate(cones_w):
        body = spec.worldbody.add_body(name=names.cone_body(i), pos=list(p_w))
        body.add_geom(
            name=names.cone_base_geom(i),
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[cone.base_width_m / 2, cone.base_width_m / 2, cone.base_thickness_m / 2],
            pos=[0.0, 0.0, cone.base_thickness_m / 2],
            material=names.CONE_MATERIAL,
            mass=CONE_BASE_MASS_KG,
        )
        body.add_geom(
            name=names.cone_shell_geom(i),
            type=mujoco.mjtGeom.mjGEOM_MESH,
            meshname=names.CONE_MESH,
            material=names.CONE_MATERIAL,
            mass=CONE_SHELL_MASS_KG,
        )


class World:
    """A compiled scene with its state, and ground truth in vnav's conventions.

    Attributes
    ----------
    model : mujoco.MjModel
    data : mujoco.MjData
    config : SceneConfig
    spec : mujoco.MjSpec
        The spec the model was compiled from (add elements and call ``recompile``).
    on_step : callable(World) or None
        Called at every physics step, just before it is taken (the controllers set the
        controls, then ``step``), with the world in the state the step starts from and its
        accelerations and sensors recomputed under the controls the step applies: what
        MuJoCo's integrator moves the body by (a sensor that reads every physics step:
        ``sim.imu``). ``reset`` clears it.
    """

    def __init__(self, spec: mujoco.MjSpec, config: SceneConfig) -> None:
        self.spec = spec
        self.config = config
        self.on_step: Callable[[World], None] | None = None
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        self._index()
        mujoco.mj_forward(self.model, self.data)

    @classmethod
    def from_config(cls, cfg: SceneConfig | None = None) -> World:
        """Build the world of a ``SceneConfig`` (default scene if ``None``)."""
        if cfg is None:
            cfg = SceneConfig()
        if not isinstance(cfg, SceneConfig):
            raise ValueError(f"cfg must be a SceneConfig, got {type(cfg).__name__}")
        return cls(build_spec(cfg), cfg)

    def recompile(self) -> None:
        """Recompile after editing ``spec``, keeping the state."""
        self.model, self.data = self.spec.recompile(self.model, self.data)
        self._index()
        mujoco.mj_forward(self.model, self.data)

    def _index(self) -> None:
        m = self.model
        self.body_id = m.body(names.DRONE_BODY).id
        joint = m.joint(names.DRONE_JOINT)
        self._qpos_adr = int(joint.qposadr[0])
        self._qvel_adr = int(joint.dofadr[0])
        self.camera_id = m.camera(names.ONBOARD_CAMERA).id
        self.chase_camera_id = m.camera(names.CHASE_CAMERA).id
        self.actuator_ids = np.array([m.actuator(n).id for n in names.MOTORS])
        n_cones = len(self.config.cones_w)
        self.cone_geom_ids = np.array(
            [
                [m.geom(names.cone_base_geom(i)).id, m.geom(names.cone_shell_geom(i)).id]
                for i in range(n_cones)
            ],
            dtype=np.int64,
        ).reshape(n_cones, 2)
        """(N, 2) geom ids of each cone: [base plate, body]."""
        self.drone_geom_ids = np.flatnonzero(m.geom_bodyid == self.body_id)
        """Geom ids of the drone's geoms (every one drawn and colliding), in model order."""
        self.cone_index_of_geom = np.full(m.ngeom, -1, dtype=np.int64)
        """(ngeom,) the cone index a geom belongs to, -1 for geoms that are no cone's."""
        for i, ids in enumerate(self.cone_geom_ids):
            self.cone_index_of_geom[ids] = i
        self.imu_site_id = m.site(names.IMU_SITE).id
        self.imu_accel_adr = int(m.sensor(names.IMU_ACCEL).adr[0])
        self.imu_gyro_adr = int(m.sensor(names.IMU_GYRO).adr[0])
        cam_cfg = self.config.camera
        self._T_b_c = cam_cfg.T_b_c
        self._cam_pos0 = m.cam_pos[self.camera_id].copy()
        self._camera = PinholeCamera.from_fovy(
            float(m.cam_fovy[self.camera_id]), cam_cfg.width, cam_cfg.height
        )

    # ------------------------------------------------------------------ ground truth
    @property
    def time_s(self) -> float:
        """Simulated time, seconds."""
        return float(self.data.time)

    @property
    def T_b_c(self) -> np.ndarray:
        """(4, 4) the camera mount: optical frame in the body frame."""
        return self._T_b_c.copy()

    def set_camera_position_b(self, position_b) -> None:
        """Slide the onboard camera on the body to ``position_b`` (FLU, metres), keeping its
        orientation: the lecture's chapter 8 composer moves the camera offset at run time.
        ``position_b`` is the declared mount's; with a mount error the true camera moves with
        it (``sim.config.MountError``).

        Writes MuJoCo's ``cam_pos`` (a body-relative position, no recompile needed) and the
        mount returned by ``T_b_c``, then recomputes the kinematics.

        Raises
        ------
        ValueError
            If ``position_b`` is not 3 finite numbers.
        """
        p_b = np.asarray(position_b, dtype=np.float64)
        if p_b.shape != (3,) or not np.all(np.isfinite(p_b)):
            raise ValueError(f"position_b must be 3 finite numbers, got {position_b!r}")
        cam_cfg = self.config.camera
        declared = cam_cfg.T_b_c_declared
        declared[:3, 3] = p_b
        true = declared if cam_cfg.mount_error.is_zero else declared @ cam_cfg.mount_error.T
        self.model.cam_pos[self.camera_id] = true[:3, 3]
        self._T_b_c = true
        mujoco.mj_forward(self.model, self.data)

    @property
    def T_b_i(self) -> np.ndarray:
        """(4, 4) the IMU site's pose in the body frame: the IMU's true mount (the identity
        when the scene declares no IMU), read from the compiled model."""
        m = self.model
        R_b_i = np.empty(9)
        mujoco.mju_quat2Mat(R_b_i, m.site_quat[self.imu_site_id])
        T = np.eye(4)
        T[:3, :3] = R_b_i.reshape(3, 3)
        T[:3, 3] = m.site_pos[self.imu_site_id]
        return T

    @property
    def camera(self) -> PinholeCamera:
        """Intrinsics of the onboard camera, exactly as MuJoCo renders it."""
        return self._camera

    @property
    def T_w_b(self) -> np.ndarray:
        """(4, 4) the body pose in the world (from MuJoCo's body frame after kinematics)."""
        # MuJoCo's own rotation matrix: built directly, without se3.make's validation, as
        # this is read at every pose sample (200 Hz).
        T = np.eye(4)
        T[:3, :3] = self.data.xmat[self.body_id].reshape(3, 3)
        T[:3, 3] = self.data.xpos[self.body_id]
        return T

    @property
    def T_w_c(self) -> np.ndarray:
        """(4, 4) the onboard camera's pose in the world, optical convention (RDF)."""
        return self.T_w_b @ self._T_b_c

    @property
    def cones_w(self) -> np.ndarray:
        """(N, 3) the cones' true base centres in the world, metres."""
        return np.array(self.config.cones_w, dtype=np.float64).reshape(-1, 3)

    @property
    def position_w(self) -> np.ndarray:
        """(3,) body origin (centre of mass) in the world, metres."""
        return self.data.qpos[self._qpos_adr : self._qpos_adr + 3].copy()

    @property
    def quat_xyzw(self) -> np.ndarray:
        """(4,) body attitude ``R_w_b`` as [x, y, z, w]."""
        q_wxyz = self.data.qpos[self._qpos_adr + 3 : self._qpos_adr + 7]
        return quat.wxyz_to_xyzw(q_wxyz / np.linalg.norm(q_wxyz))

    @property
    def R_w_b(self) -> np.ndarray:
        """(3, 3) body attitude (MuJoCo's body frame, kept current by step/set_pose)."""
        return self.data.xmat[self.body_id].reshape(3, 3).copy()

    @property
    def velocity_w(self) -> np.ndarray:
        """(3,) linear velocity of the body origin in the world, m/s (MuJoCo free joint)."""
        return self.data.qvel[self._qvel_adr : self._qvel_adr + 3].copy()

    @property
    def angular_velocity_b(self) -> np.ndarray:
        """(3,) angular velocity in the body frame, rad/s (MuJoCo free joint)."""
        return self.data.qvel[self._qvel_adr + 3 : self._qvel_adr + 6].copy()

    @property
    def acceleration_w(self) -> np.ndarray:
        """(3,) linear acceleration of the body origin in the world, m/s^2: the free joint's
        ``qacc[0:3]``, of the current state under the current controls (``step`` and the
        ``set_*`` methods recompute it)."""
        return self.data.qacc[self._qvel_adr : self._qvel_adr + 3].copy()

    @property
    def angular_acceleration_b(self) -> np.ndarray:
        """(3,) time derivative of ``angular_velocity_b``, body axes, rad/s^2 (the free
        joint's ``qacc[3:6]``)."""
        return self.data.qacc[self._qvel_adr + 3 : self._qvel_adr + 6].copy()

    # ------------------------------------------------------------------ state
    def set_pose(self, T_w_b: np.ndarray) -> None:
        """Place the body kinematically: write the free joint, zero its velocity, forward.

        Parameters
        ----------
        T_w_b : array_like, shape (4, 4)
            Body pose in the world.
        """
        T_w_b = se3.check_transform(T_w_b, "T_w_b")
        a = self._qpos_adr
        self.data.qpos[a : a + 3] = T_w_b[:3, 3]
        # MuJoCo's own conversion, into its [w, x, y, z] order (the tests read the pose back
        # against SciPy); fast, as a keyframe flight calls it at every physics step.
        mujoco.mju_mat2Quat(self.data.qpos[a + 3 : a + 7], T_w_b[:3, :3].ravel())
        self.data.qvel[self._qvel_adr : self._qvel_adr + 6] = 0.0
        mujoco.mj_forward(self.model, self.data)

    def set_velocity(self, v_w: np.ndarray, omega_b: np.ndarray) -> None:
        """Set the body's linear velocity (world, m/s) and angular velocity (body, rad/s)."""
        v_w = np.asarray(v_w, dtype=np.float64)
        omega_b = np.asarray(omega_b, dtype=np.float64)
        if v_w.shape != (3,) or omega_b.shape != (3,):
            raise ValueError(
                f"v_w and omega_b must have shape (3,), got {v_w.shape} and {omega_b.shape}"
            )
        self.data.qvel[self._qvel_adr : self._qvel_adr + 3] = v_w
        self.data.qvel[self._qvel_adr + 3 : self._qvel_adr + 6] = omega_b
        mujoco.mj_forward(self.model, self.data)

    def set_time(self, time_s: float) -> None:
        """Set the simulated time (used by kinematic playback)."""
        self.data.time = float(time_s)

    def set_rotor_thrusts(self, thrusts_N: np.ndarray) -> None:
        """Command the four rotor thrusts (order of ``sim.names.MOTORS``), newtons."""
        thrusts_N = np.asarray(thrusts_N, dtype=np.float64)
        if thrusts_N.shape != (4,) or not np.all(np.isfinite(thrusts_N)):
            raise ValueError(f"thrusts_N must be 4 finite values, got {thrusts_N!r}")
        self.data.ctrl[self.actuator_ids] = thrusts_N

    def reset(self) -> None:
        """Back to the configured start pose, at rest, time 0, with the configured camera mount
        (undoing ``set_camera_position_b``): the state of a world just built from its config."""
        self.model.cam_pos[self.camera_id] = self._cam_pos0
        self._T_b_c = self.config.camera.T_b_c
        self.on_step = None
        mujoco.mj_resetData(self.model, self.data)
        mujoco.mj_forward(self.model, self.data)

    def step(self, n: int = 1) -> None:
        """Advance the physics by ``n`` time steps.

        Before each step ``on_step`` is called, if set, with the accelerations and sensors
        recomputed under the controls now set. Afterwards every derived quantity (``T_w_b``,
        camera poses, what is rendered, the sensors and accelerations under the current
        controls) is that of the new state at ``time_s``.

        Raises
        ------
        SimulationError
            If the state becomes NaN/inf or explodes; the message names the time and cause.
        """
        if int(n) != n or n < 0:
            raise ValueError(f"n must be a non-negative int, got {n!r}")
        d, m = self.data, self.model
        step = mujoco.mj_step
        counts = d.warning.number[_WARNING_INDEX]
        on_step = self.on_step
        for _ in range(int(n)):
            t_s = d.time + m.opt.timestep
            if on_step is not None:
                # The last forward pass computed the accelerations (and the accelerometer)
                # under the previous step's controls, and, after the first step of this call,
                # for the state before it; the step about to be taken moves the body by those
                # of this state under the controls just set (a forward pass is a few us).
                mujoco.mj_forward(m, d)
                on_step(self)
            step(m, d)
            # MuJoCo resets the data itself on a NaN/huge qpos, qvel or qacc and only warns.
            now = d.warning.number[_WARNING_INDEX]
            if (now != counts).any():
                w = _INSTABILITY_WARNINGS[int(np.argmax(now > counts))]
                raise SimulationError(
                    f"t = {t_s:.4f} s: {w[1]} (MuJoCo {w[0].name}; it reset the state)"
                )
            qv2 = float(d.qvel @ d.qvel)
            qp2 = float(d.qpos @ d.qpos)
            if not (qv2 <= _FAST_QVEL2 and qp2 <= _FAST_QPOS2):  # also catches NaN
                self._check_state()
        # mj_step leaves xpos/xmat/cam_xpos (what T_w_b reports and the renderer draws) at the
        # state before its integration; recompute them for the current qpos and time.
        mujoco.mj_forward(m, d)

    def _check_state(self) -> None:
        """Raise SimulationError naming the time and cause on a NaN/inf or exploding state."""
        d = self.data
        a, v = self._qpos_adr, self._qvel_adr
        p_w = d.qpos[a : a + 3]
        v_w = d.qvel[v : v + 3]
        omega_b = d.qvel[v + 3 : v + 6]
        speed2, spin2, dist2 = float(v_w @ v_w), float(omega_b @ omega_b), float(p_w @ p_w)
        t = d.time
        if not np.all(np.isfinite(d.qpos)):
            raise SimulationError(f"t = {t:.4f} s: qpos is not finite (NaN/inf in the pose)")
        if not np.all(np.isfinite(d.qvel)):
            raise SimulationError(f"t = {t:.4f} s: qvel is not finite (NaN/inf in the velocity)")
        if speed2 > MAX_SPEED_M_S**2:
            raise SimulationError(
                f"t = {t:.4f} s: state exploding, speed {math.sqrt(speed2):.1f} m/s > "
                f"{MAX_SPEED_M_S} m/s"
            )
        if spin2 > MAX_ANGULAR_SPEED_RAD_S**2:
            raise SimulationError(
                f"t = {t:.4f} s: state exploding, angular speed {math.sqrt(spin2):.1f} rad/s > "
                f"{MAX_ANGULAR_SPEED_RAD_S} rad/s"
            )
        if dist2 > MAX_DISTANCE_M**2:
            raise SimulationError(
                f"t = {t:.4f} s: state exploding, {math.sqrt(dist2):.1f} m from the origin > "
                f"{MAX_DISTANCE_M} m"
            )
