"""vnav-sim's whole pipeline against a PyBullet EGL camera loop (gym-pybullet-drones'), same scene.

The peer is the camera loop of gym-pybullet-drones (``BaseAviary``): PyBullet stepped at
240 Hz, each step applying the four rotor forces and the yaw torque and reading the state back,
and at every camera tick ``getCameraImage`` (RGB, depth buffer and segmentation mask, shadows
on) through PyBullet's EGL renderer plugin, the view matrix from the drone's pose. It is
rebuilt here from PyBullet alone (the ``bench`` extra; gym-pybullet-drones is not needed): a
ground plane (``plane.urdf``) and the cones built in code from ``vnav.cone.TRAFFIC_CONE``
(the base plate a box, the body the same 64-segment mesh MuJoCo draws, the same colour),
seen by a camera with the scenario's mount, resolution and vertical field of view. Where
gym-pybullet-drones' PID controller would fly the drone, the drone is put on the scenario's
reference pose at each camera tick: the path is the same, the controller's cost left out.

The scene is ``multi-cone``'s (camera 30 deg down, 640x480, fovy 60 deg, 10 Hz) with its first
four cones, flown through its keyframes' positions and headings by the geometric controller
(``flight.mode = "controlled"``: vnav-sim steps MuJoCo at 200 Hz with the controller in every
step, as PyBullet steps at 240 Hz; ``--kinematic`` flies ``multi-cone``'s keyframes
themselves, the drone placed without dynamics). Each variant runs in a fresh process (spawned,
so no two GL contexts share one), in alternating rounds (A B C D, D C B A, ...):

- ``pipeline``: ``scenarios.pipeline.run`` writing the recording and the report, as
  ``vnav-demo run`` does (physics, streams, render, detect, localize, log; then judge, write);
- ``pipeline-no-rec``: the same without writing anything;
- ``vnav-bare``: MuJoCo with the controller and one RGB + depth render per tick, nothing else;
- ``pybullet``: the peer's loop above.

Per variant, best and median of the rounds: frames per second of the frame loop (frames 2..N,
from the first frame's end to the last's: the first frame's warm-up, the world and GL context
built, the judging and the recording's start and end left out), the same per CPU second (every
thread of the process: the software renderer's and the encoder's included; steadier than wall
time on a shared machine), and of the whole run (all N frames over everything, from the first
call to the last file closed). The figure the target reads: the pipeline's frames/s over
PyBullet's, loop against loop (target >= 1.5). Also printed, the machine's load average at the
start and the end: a busy machine slows the variants unevenly.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import contextlib
import multiprocessing
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from scenarios.scenario import builtin
from scenarios.scenario.spec import KinematicFlight, ScenarioSpec, from_dict
from sim.flight import Autopilot, KeyframeTrajectory, MinimumJerkTrajectory
from sim.world import cone_mesh_vertices
from vnav import quat, se3, so3
from vnav.cone import TRAFFIC_CONE, ConeModel

TARGET_RATIO = 1.5
"""The whole pipeline's frames/s over the PyBullet EGL camera loop's, at least."""

VARIANTS = ("pipeline", "pipeline-no-rec", "vnav-bare", "pybullet")

PYBULLET_RATE_HZ = 240
"""gym-pybullet-drones' default physics rate (``pyb_freq``), one control step per physics step
(its default ``ctrl_freq`` is the same)."""

DRONE_MASS_KG = 1.325
DRONE_HALF_EXTENTS_M = (0.1, 0.1, 0.03)
"""The PyBullet drone's collision box, behind and below the camera's optical centre (a body
without a visual shape, so the camera never sees it)."""

ROTOR_POSITIONS_B = ((0.14, 0.18, 0.0), (0.14, -0.18, 0.0), (-0.14, -0.18, 0.0), (-0.14, 0.18, 0.0))

N_CONES = 4


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--rounds", type=int, default=3, help="alternating rounds (default 3)")
    parser.add_argument(
        "--kinematic",
        action="store_true",
        help="fly multi-cone's keyframes (no dynamics) instead of the controller through them",
    )
    parser.add_argument(
        "--duration-s",
        type=float,
        default=None,
        help="seconds flown (the path ends at 5 s; longer hovers at its end)",
    )
    parser.add_argument(
        "--no-segmentation",
        action="store_true",
        help="PyBullet without the segmentation mask (gym-pybullet-drones' RL observations)",
    )


# ------------------------------------------------------------------------------- the scene


def peer_scenario(*, kinematic: bool = False, duration_s: float | None = None) -> dict:
    """The benchmark's scenario, in the TOML schema: ``multi-cone`` with its first four cones.

    Parameters
    ----------
    kinematic : bool
        True: ``multi-cone``'s keyframe flight. False: the geometric controller flies through
        the keyframes' positions and headings (``flight.mode = "controlled"``).
    duration_s : float, optional
        The run's length; default the path's (5 s).

    Returns
    -------
    dict
        A scenario (``scenarios.scenario.spec.from_dict`` reads it).
    """
    scenario = builtin.multi_cone()
    scenario["name"] = "peers"
    scenario["cones"] = scenario["cones"][:N_CONES]
    scenario["checks"] = [
        {**c, "limit": float(N_CONES)} if c["kind"] == "matched_cones" else c
        for c in scenario["checks"]
    ]
    if not kinematic:
        scenario["flight"] = {
            "mode": "controlled",
            "waypoints": [
                {"t": k["t"], "position_w": k["position_w"], "yaw_deg": k["rpy_deg"][2]}
                for k in scenario["flight"]["keyframes"]
            ],
        }
    if duration_s is not None:
        scenario["duration_s"] = duration_s
    return scenario


def peer_spec(*, kinematic: bool = False, duration_s: float | None = None) -> ScenarioSpec:
    """``peer_scenario`` validated as a user's file is."""
    return from_dict(peer_scenario(kinematic=kinematic, duration_s=duration_s), where="peers")


def reference_pose(spec: ScenarioSpec) -> Callable[[float], np.ndarray]:
    """The flight's path as ``T_w_b(t_s)``, (4, 4): the keyframes' interpolation of a
    kinematic flight, else the controller's minimum-jerk reference (level, at its heading)."""
    flight = spec.flight
    if isinstance(flight, KinematicFlight):
        keyframes = KeyframeTrajectory(
            [k.t_s for k in flight.keyframes],
            [se3.make(quat.to_matrix(k.quat_xyzw), k.position_w) for k in flight.keyframes],
        )
        return keyframes.pose
    trajectory = _trajectory(spec)

    def pose(t_s: float) -> np.ndarray:
        ref = trajectory.sample(t_s)
        return se3.make(so3.from_rpy(0.0, 0.0, ref.yaw_rad), ref.p_w)

    return pose


def _trajectory(spec: ScenarioSpec) -> MinimumJerkTrajectory:
    wps = spec.flight.waypoints
    return MinimumJerkTrajectory(
        [w.t_s for w in wps], [w.position_w for w in wps], [w.yaw_rad for w in wps]
    )


def write_cone_obj(cone: ConeModel, path: Path) -> None:
    """The cone's body as MuJoCo draws it (``sim.world.cone_mesh_vertices``: a ring on the base
    plate and the apex), as a Wavefront OBJ file: PyBullet's EGL renderer draws meshes from
    files only (a mesh given by its vertices is skipped with a warning). Each face has its own
    normal; faces wind counter-clockwise seen from outside."""
    v = cone_mesh_vertices(cone)
    ring, apex = v[:-1], v[-1]
    centre = np.array([0.0, 0.0, cone.base_thickness_m])
    n = len(ring)
    lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in (*ring, apex, centre)]
    faces = []
    for i in range(n):
        j = (i + 1) % n
        faces += [(i, j, n), (j, i, n + 1)]  # a side, a piece of the bottom disc
    points = np.vstack([ring, apex, centre])
    for k, (a, b, c) in enumerate(faces):
        normal = np.cross(points[b] - points[a], points[c] - points[a])
        x, y, z = normal / np.linalg.norm(normal)
        lines.append(f"vn {x:.9g} {y:.9g} {z:.9g}")
        lines.append(f"f {a + 1}//{k + 1} {b + 1}//{k + 1} {c + 1}//{k + 1}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


class PyBulletScene:
    """The benchmark's scene in PyBullet, rendered through the EGL plugin (DIRECT mode).

    Parameters
    ----------
    spec : ScenarioSpec
        Its cones, camera (mount, size, fovy) and clipping planes are used.
    segmentation : bool
        Ask ``getCameraImage`` for the segmentation mask (object and link index), as
        gym-pybullet-drones' ``_getDroneImages`` does by default.

    Use as a context manager (or call ``close``): it disconnects PyBullet.

    Raises
    ------
    RuntimeError
        If the EGL renderer plugin cannot be loaded.
    """

    def __init__(self, spec: ScenarioSpec, *, segmentation: bool = True) -> None:
        import pkgutil

        import pybullet as p
        import pybullet_data

        self.p = p
        self.client = p.connect(p.DIRECT)
        self._plugin = -1
        self._files = tempfile.TemporaryDirectory(prefix="vnav-bench-peers-")
        self._cone_obj = Path(self._files.name) / "cone.obj"
        try:
            write_cone_obj(TRAFFIC_CONE, self._cone_obj)
            egl = pkgutil.get_loader("eglRenderer")
            if egl is not None:
                self._plugin = p.loadPlugin(
                    egl.get_filename(), "_eglRendererPlugin", physicsClientId=self.client
                )
            if self._plugin < 0:
                raise RuntimeError("PyBullet's EGL renderer plugin (eglRenderer) did not load")
            p.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=self.client)
            p.setGravity(0.0, 0.0, -9.8, physicsClientId=self.client)
            p.setTimeStep(1.0 / PYBULLET_RATE_HZ, physicsClientId=self.client)
            self.plane = p.loadURDF("plane.urdf", physicsClientId=self.client)
            self.cone_ids = [self._add_cone(p_w, TRAFFIC_CONE) for p_w in spec.scene.cones_w]
            box = p.createCollisionShape(
                p.GEOM_BOX, halfExtents=DRONE_HALF_EXTENTS_M, physicsClientId=self.client
            )
            self.drone = p.createMultiBody(
                DRONE_MASS_KG,
                box,
                -1,
                list(spec.scene.start_position_w),
                physicsClientId=self.client,
            )
        except BaseException:
            self.close()
            raise
        camera = spec.scene.camera
        self.width, self.height = camera.width, camera.height
        self.T_b_c = camera.T_b_c
        self.projection = p.computeProjectionMatrixFOV(
            fov=camera.fovy_deg,
            aspect=camera.width / camera.height,
            nearVal=spec.scene.znear_m,
            farVal=spec.scene.zfar_m,
        )
        self.flags = (
            p.ER_SEGMENTATION_MASK_OBJECT_AND_LINKINDEX
            if segmentation
            else p.ER_NO_SEGMENTATION_MASK
        )
        self.hover_thrust_N = DRONE_MASS_KG * 9.8 / 4.0

    def _add_cone(self, p_w, cone: ConeModel) -> int:
        """A static cone: the base plate (the multibody's base) and the body (a fixed link)."""
        p, cid = self.p, self.client
        rgba = [*cone.color_rgb, 1.0]
        half = cone.base_width_m / 2.0
        plate_extents = [half, half, cone.base_thickness_m / 2.0]
        plate_at = [0.0, 0.0, cone.base_thickness_m / 2.0]
        plate_vis = p.createVisualShape(
            p.GEOM_BOX,
            halfExtents=plate_extents,
            visualFramePosition=plate_at,
            rgbaColor=rgba,
            physicsClientId=cid,
        )
        plate_col = p.createCollisionShape(
            p.GEOM_BOX,
            halfExtents=plate_extents,
            collisionFramePosition=plate_at,
            physicsClientId=cid,
        )
        body_vis = p.createVisualShape(
            p.GEOM_MESH, fileName=str(self._cone_obj), rgbaColor=rgba, physicsClientId=cid
        )
        body_col = p.createCollisionShape(
            p.GEOM_MESH, vertices=cone_mesh_vertices(cone).tolist(), physicsClientId=cid
        )
        return p.createMultiBody(
            0.0,
            plate_col,
            plate_vis,
            list(p_w),
            linkMasses=[0.0],
            linkCollisionShapeIndices=[body_col],
            linkVisualShapeIndices=[body_vis],
            linkPositions=[[0.0, 0.0, 0.0]],
            linkOrientations=[[0.0, 0.0, 0.0, 1.0]],
            linkInertialFramePositions=[[0.0, 0.0, 0.0]],
            linkInertialFrameOrientations=[[0.0, 0.0, 0.0, 1.0]],
            linkParentIndices=[0],
            linkJointTypes=[p.JOINT_FIXED],
            linkJointAxis=[[0.0, 0.0, 1.0]],
            physicsClientId=cid,
        )

    def step(self) -> None:
        """One physics step as gym-pybullet-drones' ``BaseAviary.step`` takes it (one control
        step per physics step): the rotor forces and yaw torque (``_physics``, here the hover
        thrust), ``stepSimulation``, the state read back
        (``_updateAndStoreKinematicInformation``)."""
        p, cid, drone = self.p, self.client, self.drone
        for r_b in ROTOR_POSITIONS_B:
            p.applyExternalForce(
                drone, -1, [0.0, 0.0, self.hover_thrust_N], r_b, p.LINK_FRAME, physicsClientId=cid
            )
        p.applyExternalTorque(drone, -1, [0.0, 0.0, 0.0], p.LINK_FRAME, physicsClientId=cid)
        p.stepSimulation(physicsClientId=cid)
        _, quat_xyzw = p.getBasePositionAndOrientation(drone, physicsClientId=cid)
        p.getEulerFromQuaternion(quat_xyzw)
        p.getBaseVelocity(drone, physicsClientId=cid)

    def place(self, T_w_b: np.ndarray) -> None:
        """Put the drone at ``T_w_b`` (4, 4), at rest: the path instead of a controller."""
        p = self.p
        p.resetBasePositionAndOrientation(
            self.drone,
            T_w_b[:3, 3].tolist(),
            quat.from_matrix(T_w_b[:3, :3]).tolist(),
            physicsClientId=self.client,
        )
        p.resetBaseVelocity(
            self.drone, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=self.client
        )

    def drone_T_w_c(self) -> np.ndarray:
        """(4, 4) the camera's pose from the drone's state, as ``_getDroneImages`` reads it
        (position and quaternion, ``getMatrixFromQuaternion``)."""
        p = self.p
        p_w, quat_xyzw = p.getBasePositionAndOrientation(self.drone, physicsClientId=self.client)
        R_w_b = np.array(p.getMatrixFromQuaternion(quat_xyzw)).reshape(3, 3)
        return se3.make(R_w_b, p_w) @ self.T_b_c

    def render(self, T_w_c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The camera's image from ``T_w_c`` (4, 4; optical frame: x right, y down, z forward).

        Returns
        -------
        rgba : ndarray, shape (H, W, 4), uint8
        depth_buffer : ndarray, shape (H, W), float32
            OpenGL's non-linear depth in [0, 1], as gym-pybullet-drones keeps it.
        segmentation : ndarray, shape (H, W), int32
            ``object id + ((link index + 1) << 24)``, -1 on the sky; all -1 without the mask.
        """
        p = self.p
        eye = T_w_c[:3, 3]
        # OpenGL's camera looks along its -z with y up: the optical z ahead, -y up.
        view = p.computeViewMatrix(
            cameraEyePosition=eye.tolist(),
            cameraTargetPosition=(eye + T_w_c[:3, 2]).tolist(),
            cameraUpVector=(-T_w_c[:3, 1]).tolist(),
            physicsClientId=self.client,
        )
        w, h, rgba, depth, seg = p.getCameraImage(
            self.width,
            self.height,
            viewMatrix=view,
            projectionMatrix=self.projection,
            shadow=1,
            flags=self.flags,
            renderer=p.ER_BULLET_HARDWARE_OPENGL,
            physicsClientId=self.client,
        )
        return (
            np.reshape(rgba, (h, w, 4)),
            np.reshape(depth, (h, w)),
            np.reshape(seg, (h, w)),
        )

    def close(self) -> None:
        """Unload the plugin and disconnect (again: nothing)."""
        if self.client is None:
            return
        with contextlib.suppress(Exception):
            if self._plugin >= 0:
                self.p.unloadPlugin(self._plugin, physicsClientId=self.client)
            self.p.disconnect(physicsClientId=self.client)
        self.client = None
        self._files.cleanup()

    def __enter__(self) -> PyBulletScene:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# ---------------------------------------------------------------------------- the variants


class _Stamps:
    """Wall and CPU time (this process's, every thread's: the renderer's and the encoder's
    included) after each frame; the frame rate over frames 2..N leaves the first frame's
    warm-up (shader compilation, first allocations) out, the same way for every variant."""

    def __init__(self) -> None:
        self.wall_s: list[float] = []
        self.cpu_s: list[float] = []

    def __call__(self, *_) -> None:
        self.wall_s.append(time.perf_counter())
        self.cpu_s.append(time.process_time())

    def figures(self) -> dict:
        return {
            "frames": len(self.wall_s),
            "loop_s": self.wall_s[-1] - self.wall_s[0],
            "loop_cpu_s": self.cpu_s[-1] - self.cpu_s[0],
        }


def _pybullet(spec: ScenarioSpec, segmentation: bool, stamp: _Stamps) -> None:
    """gym-pybullet-drones' camera loop: physics at 240 Hz, an image every 1/rate s."""
    T_w_b_at = reference_pose(spec)
    steps_per_frame = round(PYBULLET_RATE_HZ / spec.camera_rate_hz)
    with PyBulletScene(spec, segmentation=segmentation) as scene:
        for k in range(spec.n_ticks):
            if k > 0:
                for _ in range(steps_per_frame):
                    scene.step()
            scene.place(T_w_b_at(k / spec.camera_rate_hz))
            scene.render(scene.drone_T_w_c())
            stamp()


def _vnav_bare(spec: ScenarioSpec, stamp: _Stamps) -> None:
    """MuJoCo, the flight's driver and one RGB + depth render per camera tick."""
    from sim.flight import KeyframePlayer
    from sim.render import Renderer
    from sim.world import World

    world = World.from_config(spec.scene)
    with Renderer(world) as renderer:
        if isinstance(spec.flight, KinematicFlight):
            times = [k.t_s for k in spec.flight.keyframes]
            T_w_b_at = reference_pose(spec)
            driver = KeyframePlayer(world, KeyframeTrajectory(times, [T_w_b_at(t) for t in times]))
        else:
            driver = Autopilot(world, _trajectory(spec))
        dt = float(world.model.opt.timestep)
        step = 0
        for k in range(spec.n_ticks):
            target = round(k / spec.camera_rate_hz / dt)
            driver.step(target - step)
            step = target
            renderer.render(depth=True)
            stamp()


def _pipeline(spec: ScenarioSpec, record: bool, stamp: _Stamps) -> bool:
    """``scenarios.pipeline.run``, writing its files (``record``) as ``vnav-demo run`` does;
    whether the run passed its checks. A frame is stamped when its tick has been evaluated
    and logged (the pipeline's ``progress``)."""
    from scenarios import pipeline

    with tempfile.TemporaryDirectory(prefix="vnav-bench-peers-") as tmp:
        outcome = pipeline.run(spec, seed=1, out_dir=Path(tmp) if record else None, progress=stamp)
    return outcome.passed


def measure(
    variant: str,
    *,
    kinematic: bool = False,
    duration_s: float | None = None,
    segmentation: bool = True,
) -> dict:
    """One run of ``variant`` (one of ``VARIANTS``; the benchmark calls it in a fresh process).

    Returns
    -------
    dict
        ``frames``; ``loop_s`` and ``loop_cpu_s``, wall and CPU seconds from the first frame's
        end to the last's (``frames - 1`` frames); ``run_s`` and ``cpu_s``, the whole run's
        (the scene and GL context built, files written and closed, everything freed); and
        ``passed`` for the pipeline's variants.
    """
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r}; valid: {', '.join(VARIANTS)}")
    spec = peer_spec(kinematic=kinematic, duration_s=duration_s)
    if spec.n_ticks < 2:
        raise ValueError(f"duration_s={duration_s} gives {spec.n_ticks} frame; at least 2 needed")
    stamp = _Stamps()
    run_s, cpu_s = time.perf_counter(), time.process_time()
    passed = None
    if variant == "pybullet":
        _pybullet(spec, segmentation, stamp)
    elif variant == "vnav-bare":
        _vnav_bare(spec, stamp)
    else:
        passed = _pipeline(spec, variant == "pipeline", stamp)
    out = {
        **stamp.figures(),
        "run_s": time.perf_counter() - run_s,
        "cpu_s": time.process_time() - cpu_s,
    }
    if passed is not None:
        out["passed"] = passed
    return out


def _quiet_stdout() -> None:
    """A worker's C libraries print to file descriptor 1 (PyBullet's build time, EGL's
    vendor): sent to stderr, so that ``--json`` prints JSON alone."""
    sys.stdout.flush()
    os.dup2(2, 1)


def _in_fresh_process(*args, **kwargs) -> dict:
    context = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(
        max_workers=1, mp_context=context, initializer=_quiet_stdout
    ) as pool:
        return pool.submit(measure, *args, **kwargs).result()


def _require_pybullet() -> None:
    """Stop here unless PyBullet is importable.

    Raises
    ------
    SystemExit
        If PyBullet (the bench extra) is not installed.
    """
    try:
        import pybullet  # noqa: F401
    except ImportError:
        raise SystemExit(
            "benchmarks peers: PyBullet is not installed; it is in the bench extra: "
            "pip install -e '.[bench]'"
        ) from None


def _alternating_runs(
    rounds: int, kinematic: bool, duration_s: float | None, segmentation: bool
) -> dict[str, list[dict]]:
    """``rounds`` runs of every variant, each in a fresh process (``measure``), the order
    reversed every other round.

    Returns
    -------
    dict
        Each of ``VARIANTS`` to its runs' figures, in the order they ran.
    """
    runs: dict[str, list[dict]] = {v: [] for v in VARIANTS}
    for i in range(rounds):
        # A B C D, then D C B A: no variant always first (a warmer cache, a quieter moment).
        for variant in VARIANTS[:: 1 if i % 2 == 0 else -1]:
            runs[variant].append(
                _in_fresh_process(
                    variant, kinematic=kinematic, duration_s=duration_s, segmentation=segmentation
                )
            )
    return runs


def _per_variant(runs: dict[str, list[dict]]) -> dict[str, dict]:
    """Each variant's frame rates over its runs (``_alternating_runs``): the loop's (frames
    2..N) best and median per wall second, best per CPU second; the whole run's (all N) best
    per wall and per CPU second; and the runs themselves."""

    def rates(variant: str, key: str) -> list[float]:
        loop = key.startswith("loop")  # frames 2..N; a whole run's all N
        return [(r["frames"] - loop) / r[key] for r in runs[variant]]

    return {
        v: {
            "frames": runs[v][0]["frames"],
            "loop_fps_best": max(rates(v, "loop_s")),
            "loop_fps_median": statistics.median(rates(v, "loop_s")),
            "loop_frames_per_cpu_s_best": max(rates(v, "loop_cpu_s")),
            "run_fps_best": max(rates(v, "run_s")),
            "run_frames_per_cpu_s_best": max(rates(v, "cpu_s")),
            "runs": runs[v],
        }
        for v in VARIANTS
    }


def _ratios_over_pybullet(per: dict[str, dict]) -> dict[str, dict[str, float]]:
    """Each vnav variant's rates (``_per_variant``) over PyBullet's: best against best,
    median against median."""
    peer = per["pybullet"]
    return {
        v: {
            key: per[v][f"{key}_best"] / peer[f"{key}_best"]
            for key in ("loop_fps", "loop_frames_per_cpu_s", "run_fps", "run_frames_per_cpu_s")
        }
        | {"loop_fps_median": per[v]["loop_fps_median"] / peer["loop_fps_median"]}
        for v in VARIANTS
        if v != "pybullet"
    }


def run(args: argparse.Namespace) -> dict:
    """Every variant ``--rounds`` times, alternating, each in a fresh process; print the table
    unless ``--json``; return the figures."""
    _require_pybullet()
    rounds = max(1, getattr(args, "rounds", 3))
    kinematic = getattr(args, "kinematic", False)
    duration_s = getattr(args, "duration_s", None)
    segmentation = not getattr(args, "no_segmentation", False)
    spec = peer_spec(kinematic=kinematic, duration_s=duration_s)
    load_start = os.getloadavg()
    runs = _alternating_runs(rounds, kinematic, duration_s, segmentation)
    load_end = os.getloadavg()
    per = _per_variant(runs)
    camera = spec.scene.camera
    figures = {
        "scenario": "multi-cone, first 4 cones, " + ("keyframes" if kinematic else "controlled"),
        "width": camera.width,
        "height": camera.height,
        "fovy_deg": camera.fovy_deg,
        "camera_rate_hz": spec.camera_rate_hz,
        "duration_s": spec.end_s,
        "vnav_physics_hz": 1.0 / spec.scene.timestep_s,
        "pybullet_segmentation": segmentation,
        "rounds": rounds,
        "load_avg_start": list(load_start),
        "load_avg_end": list(load_end),
        "variants": per,
        "ratio_over_pybullet": _ratios_over_pybullet(per),
        "target_ratio": TARGET_RATIO,
        "passed": all(r["passed"] for v in ("pipeline", "pipeline-no-rec") for r in runs[v]),
    }
    if not args.json:
        _print(figures)
    return figures


def _print(figures: dict) -> None:
    f = figures
    print(
        f"{f['scenario']}: {f['width']}x{f['height']}, fovy {f['fovy_deg']:g} deg, "
        f"{f['camera_rate_hz']:g} Hz, {f['duration_s']:g} s "
        f"({f['variants']['pipeline']['frames']} frames); {f['rounds']} alternating rounds, "
        "each variant in a fresh process"
    )
    print(
        "PyBullet: EGL plugin, RGB + depth buffer"
        + (" + segmentation" if f["pybullet_segmentation"] else "")
        + f", shadows, physics at {PYBULLET_RATE_HZ} Hz; vnav-sim: MuJoCo EGL, RGB + depth, "
        f"physics at {f['vnav_physics_hz']:g} Hz"
    )
    print(
        "loop: frames 2..N (the first's warm-up left out), per wall second and per CPU second "
        "(every thread's); run: all N over the whole run (scene, GL context, files)"
    )
    header = (
        f"{'variant':<17}{'loop fps':>9}{'median':>8}{'per CPU s':>10}{'run fps':>9}"
        f"{'per CPU s':>10}{'x PyBullet':>11}"
    )
    print(header)
    print("-" * len(header))
    for v in VARIANTS:
        p = f["variants"][v]
        ratio = f["ratio_over_pybullet"].get(v, {}).get("loop_fps", 1.0)
        print(
            f"{v:<17}{p['loop_fps_best']:>9.1f}{p['loop_fps_median']:>8.1f}"
            f"{p['loop_frames_per_cpu_s_best']:>10.1f}{p['run_fps_best']:>9.1f}"
            f"{p['run_frames_per_cpu_s_best']:>10.1f}{ratio:>11.2f}"
        )
    r = f["ratio_over_pybullet"]["pipeline"]
    verdict = "meets" if r["loop_fps"] >= f["target_ratio"] else "misses"
    print(
        f"\nwhole pipeline (recording) / PyBullet EGL camera loop, frames/s: "
        f"{r['loop_fps']:.2f} best, {r['loop_fps_median']:.2f} median (target >= "
        f"{f['target_ratio']:g}: {verdict}); per CPU second {r['loop_frames_per_cpu_s']:.2f}; "
        f"whole runs {r['run_fps']:.2f} (per CPU second {r['run_frames_per_cpu_s']:.2f})"
    )
    print(
        "load average (1, 5, 15 min): start "
        + ", ".join(f"{x:.1f}" for x in f["load_avg_start"])
        + "; end "
        + ", ".join(f"{x:.1f}" for x in f["load_avg_end"])
        + f" ({os.cpu_count()} cores)"
    )
    if not f["passed"]:
        print("note: a pipeline run failed its checks (the speed figures stand)")
