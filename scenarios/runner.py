"""Run a scenario: fly, render, detect, localise, compare with ground truth, record.

One camera frame of :func:`run_scenario`::

    truth    T_w_b, cones_w            <- the simulator (sim.world.World)
    render   rgb, depth                <- sim.render.Renderer, one pass
    detect   detections                <- vnav.detect.detect_cones(rgb)
    estimate p_w per method            <- vnav.localize.localize(det, camera, T_w_b, T_b_c, depth)
    compare  error = |p_w - truth|     <- matched to the nearest true cone (vnav.metrics)
    record   .rrd entities             <- scenarios.recording

The estimator is given ``T_w_b_est``: the true pose, plus the scenario's pose noise if any
(drawn from the run's seed), so a seed fixes the whole run.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scenarios.recording import Recording
from scenarios.spec import METHODS, ControlledFlight, KinematicFlight, OrbitFlight, ScenarioSpec
from sim.flight import (
    Autopilot,
    KeyframePlayer,
    KeyframeTrajectory,
    MinimumJerkTrajectory,
    OrbitTrajectory,
)
from sim.render import Renderer
from sim.world import World
from vnav import metrics, quat, se3, so3
from vnav.camera import PinholeCamera, depth_to_world_points
from vnav.cone import TRAFFIC_CONE, ConeModel
from vnav.detect import detect_cones
from vnav.localize import localize

logger = logging.getLogger(__name__)

MATCH_GATE_M = 3.0
"""An estimate farther than this from every true cone is reported unmatched."""

CLOUD_STRIDE_PX = 16
"""Every 16th row and column of the depth image goes into the logged world cloud."""

MIN_CONE_HEIGHT_PX = 12.0
"""A cone counts as in view (for detection rates) when fully inside and at least this tall."""

CONTRACT_RANGE_M = (2.0, 25.0)
"""Ranges over which the perception accuracy contract (issue 4) is stated."""


@dataclass
class DetectionRecord:
    """One detection of one frame, with its estimates and errors."""

    cone_index: int | None
    """The true cone it was matched to, or None."""
    estimates_w: dict[str, np.ndarray]
    errors_m: dict[str, float]
    range_m: float | None
    p_c_true: np.ndarray | None
    """The matched cone's true base centre in the camera frame."""
    in_contract: bool = False
    """The matched cone is fully in view, >= 12 px tall and 2-25 m away: the domain of the
    accuracy contract (``scenarios.checks.ERROR_BOUNDS_M``)."""


@dataclass
class FrameRecord:
    """What one camera frame saw and computed."""

    frame: int
    t_s: float
    T_w_b: np.ndarray
    quat_xyzw: np.ndarray
    rpy_rad: np.ndarray
    gimbal_locked: bool
    cones_in_view: list[int]
    detections: list[DetectionRecord]
    reference_error_m: float | None = None


@dataclass
class RunResult:
    """Everything a finished run produced, before it is judged and written."""

    spec: ScenarioSpec
    seed: int
    frames: list[FrameRecord] = field(default_factory=list)
    trajectory_w: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    timing_s: dict[str, float] = field(default_factory=dict)

    def _scored(self, method: str, contract_only: bool) -> list[DetectionRecord]:
        return [
            d
            for f in self.frames
            for d in f.detections
            if method in d.errors_m and (d.in_contract or not contract_only)
        ]

    def errors(self, method: str, *, contract_only: bool = False) -> np.ndarray:
        """Errors of ``method`` over matched detections, metres, shape (K,).

        ``contract_only`` keeps only detections in the accuracy contract's domain.
        """
        return np.array(
            [d.errors_m[method] for d in self._scored(method, contract_only)], dtype=np.float64
        )

    def ranges_for(self, method: str, *, contract_only: bool = False) -> np.ndarray:
        """Ranges of the detections behind :meth:`errors`, same order, metres."""
        return np.array([d.range_m for d in self._scored(method, contract_only)], dtype=np.float64)


def cone_points_w(p_base_w: np.ndarray, cone: ConeModel = TRAFFIC_CONE) -> np.ndarray:
    """The apex and the base plate's eight corners of a cone at ``p_base_w``, shape (9, 3)."""
    h = cone.base_width_m / 2.0
    corners = np.array(
        [
            [sx * h, sy * h, z]
            for sx in (-1, 1)
            for sy in (-1, 1)
            for z in (0.0, cone.base_thickness_m)
        ]
    )
    return np.vstack([p_base_w + np.array([0.0, 0.0, cone.height_m]), p_base_w + corners])


def cones_fully_in_view(
    cones_w: np.ndarray,
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    min_height_px: float = MIN_CONE_HEIGHT_PX,
) -> list[int]:
    """Indices of cones whose apex and base corners all project inside the image (truth only)."""
    T_c_w = se3.invert(T_w_c)
    points_w = np.concatenate([cone_points_w(p_w) for p_w in cones_w])  # one call for all
    uv = camera.project(se3.apply(T_c_w, points_w)).reshape(len(cones_w), -1, 2)
    visible = []
    for i, uv_i in enumerate(uv):
        if not np.isfinite(uv_i).all() or not camera.in_image(uv_i).all():
            continue
        if np.ptp(uv_i[:, 1]) >= min_height_px:
            visible.append(i)
    return visible


def _view_from(spec: ScenarioSpec, cones_w: np.ndarray) -> dict[str, np.ndarray]:
    """A 3D-view eye behind and above the start, looking between the drone and the cones."""
    start_w = np.asarray(spec.scene.start_position_w)
    target_w = 0.5 * (start_w + cones_w.mean(axis=0))
    heading_w = cones_w.mean(axis=0) - start_w
    heading_w[2] = 0.0
    norm = np.linalg.norm(heading_w)
    heading_w = heading_w / norm if norm > 1e-6 else np.array([1.0, 0.0, 0.0])
    distance_m = max(8.0, 1.5 * float(np.linalg.norm(cones_w.mean(axis=0) - start_w)))
    side_w = np.array([-heading_w[1], heading_w[0], 0.0])
    eye_w = target_w - distance_m * heading_w + 0.6 * distance_m * side_w
    eye_w[2] = target_w[2] + 0.7 * distance_m
    return {"eye_w": eye_w, "look_target_w": target_w}


def _camera_track(spec: ScenarioSpec) -> list[tuple[float, np.ndarray]]:
    """(time, camera position on the body) of a flight that slides the camera, else []."""
    flight = spec.flight
    if not isinstance(flight, KinematicFlight) or not flight.moves_camera:
        return []
    default_b = spec.scene.camera.position_b
    return [
        (k.t_s, np.array(k.camera_position_b if k.camera_position_b is not None else default_b))
        for k in flight.keyframes
    ]


def _interpolate(track: list[tuple[float, np.ndarray]], t_s: float) -> np.ndarray:
    """Linear interpolation in a time-sorted track, held constant outside it."""
    times = np.array([t for t, _ in track])
    values = np.array([v for _, v in track])
    return np.array([np.interp(t_s, times, values[:, i]) for i in range(values.shape[1])])


def _noisy_pose(T_w_b: np.ndarray, spec: ScenarioSpec, rng: np.random.Generator) -> np.ndarray:
    noise = spec.noise
    if noise.position_std_m == 0.0 and noise.attitude_std_deg == 0.0:
        return T_w_b
    dp_w = rng.normal(0.0, noise.position_std_m, 3)
    dtheta_b = rng.normal(0.0, math.radians(noise.attitude_std_deg), 3)
    return se3.make(T_w_b[:3, :3] @ so3.exp(dtheta_b), T_w_b[:3, 3] + dp_w)


def _driver(world: World, spec: ScenarioSpec):
    """The object that advances the world along the scenario's flight: ``step(n)``."""
    flight = spec.flight
    if isinstance(flight, KinematicFlight):
        T_w_b = [se3.make(quat.to_matrix(k.quat_xyzw), k.position_w) for k in flight.keyframes]
        times = [k.t_s for k in flight.keyframes]
        return KeyframePlayer(world, KeyframeTrajectory(times, np.array(T_w_b)))
    if isinstance(flight, OrbitFlight):
        orbit = OrbitTrajectory(
            flight.center_w,
            flight.radius_m,
            flight.height_m,
            flight.period_s,
            flight.start_angle_rad,
            flight.ramp_s,
        )
        return Autopilot(world, orbit)
    assert isinstance(flight, ControlledFlight)
    wps = flight.waypoints  # one waypoint is a hover there
    trajectory = MinimumJerkTrajectory(
        [w.t_s for w in wps], [w.position_w for w in wps], [w.yaw_rad for w in wps]
    )
    return Autopilot(world, trajectory)


def run_scenario(
    spec: ScenarioSpec,
    *,
    seed: int = 1,
    rrd_path: Path | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> RunResult:
    """Run ``spec`` headless and return what it saw; optionally write the ``.rrd``.

    Parameters
    ----------
    spec : ScenarioSpec
    seed : int
        Seeds the pose noise (if the scenario has any).
    rrd_path : Path, optional
        Where the recording goes; written whole at the end or not at all.
    progress : callable(done, total), optional
        Called after every camera frame.

    Raises
    ------
    sim.world.SimulationError
        If the flight diverges (NaN or an exploding state), naming the time.
    """
    rng = np.random.default_rng(seed)
    setup_start = time.perf_counter()
    timing = dict.fromkeys(("physics", "render", "detect", "localize", "log"), 0.0)
    result = RunResult(spec=spec, seed=seed, timing_s=timing)
    world = World.from_config(spec.scene)
    camera, T_b_c = world.camera, world.T_b_c
    cones_w = world.cones_w
    far_m = spec.scene.zfar_m
    dt = float(world.model.opt.timestep)
    n_frames = math.floor(spec.end_s * spec.camera_rate_hz + 1e-9) + 1
    driver = _driver(world, spec)
    camera_track = _camera_track(spec)
    recording = Recording(rrd_path, f"{spec.name}-seed{seed}") if rrd_path else None
    positions_w = []
    try:
        if recording:
            recording.log_setup(
                camera=camera,
                T_b_c=None if camera_track else T_b_c,  # None: logged every frame instead
                cones_w=cones_w,
                description_md=describe(spec, seed),
                **_view_from(spec, cones_w),
                view=spec.view,
            )
        with Renderer(world) as renderer:
            setup_s = time.perf_counter() - setup_start
            for k in range(n_frames):
                t0 = time.perf_counter()
                target_s = k / spec.camera_rate_hz
                n_steps = round((target_s - world.time_s) / dt)
                if n_steps > 0:
                    driver.step(n_steps)
                if camera_track:
                    world.set_camera_position_b(_interpolate(camera_track, world.time_s))
                    T_b_c = world.T_b_c
                t1 = time.perf_counter()
                frame = renderer.render(depth=True)
                t2 = time.perf_counter()
                detections = detect_cones(frame.rgb)
                t3 = time.perf_counter()
                record, estimates_w, errors_m, range_m, cloud_w = _evaluate_frame(
                    k, world, driver, detections, frame.depth, camera, T_b_c, cones_w, far_m,
                    spec, rng,
                )  # fmt: skip
                result.frames.append(record)
                positions_w.append(record.T_w_b[:3, 3])
                t4 = time.perf_counter()
                if recording:
                    recording.log_frame(
                        frame=k,
                        t_s=record.t_s,
                        T_w_b=record.T_w_b,
                        rgb=frame.rgb,
                        depth_m=frame.depth,
                        detections=detections,
                        estimates_w=estimates_w,
                        errors_m=errors_m,
                        range_m=range_m,
                        cloud_w=cloud_w,
                        rpy_rad=record.rpy_rad,
                        gimbal_locked=record.gimbal_locked,
                        cone_coords=_cone0_coordinates(record, T_b_c, cones_w),
                        T_b_c=T_b_c if camera_track else None,
                    )
                t5 = time.perf_counter()
                for key, seconds in zip(
                    timing, (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4), strict=True
                ):
                    timing[key] += seconds
                if progress:
                    progress(k + 1, n_frames)
        finish_start = time.perf_counter()
        result.trajectory_w = np.array(positions_w).reshape(-1, 3)
        if recording:
            recording.log_trajectory(result.trajectory_w)
            recording.commit()
        # Building the world, the GL context and the recording's header, and closing the file.
        timing["setup"] = setup_s + time.perf_counter() - finish_start
    except BaseException:
        if recording:
            recording.discard()
        raise
    return result


def _evaluate_frame(
    k: int,
    world: World,
    driver,
    detections: list,
    depth_m: np.ndarray | None,
    camera: PinholeCamera,
    T_b_c: np.ndarray,
    cones_w: np.ndarray,
    far_m: float,
    spec: ScenarioSpec,
    rng: np.random.Generator,
):
    """Localise every detection, match to the truth, and build the frame's record.

    Returns the record, this frame's estimates per method (K, 3), its mean error per method,
    the mean range of the matched cones and the decimated world cloud of the depth image.
    """
    T_w_b = world.T_w_b
    T_w_b_est = _noisy_pose(T_w_b, spec, rng)
    T_w_c = T_w_b @ T_b_c
    R_w_b = T_w_b[:3, :3]
    # One tolerance for the flag and for the angles (so3's default): a frame flagged locked
    # is exactly one whose angles to_rpy computed with roll = 0.
    locked = bool(so3.gimbal_locked(R_w_b))
    rpy = so3.to_rpy(R_w_b, warn=False)
    in_view = cones_fully_in_view(cones_w, camera, T_w_c)

    per_det = [
        localize(d, camera, T_w_b_est, T_b_c, depth=depth_m, far_m=far_m).as_dict()
        for d in detections
    ]
    # Match on the ground plane with the first available non-naive estimate of each detection.
    anchors = [next((e[m] for m in METHODS[:3] if e[m] is not None), None) for e in per_det]
    usable = [i for i, a in enumerate(anchors) if a is not None]
    pairs = (
        metrics.match_nearest(
            cones_w[:, :2], np.array([anchors[i][:2] for i in usable]), max_distance=MATCH_GATE_M
        )
        if usable
        else []
    )
    cone_of = {usable[j]: i for i, j in pairs}

    T_c_w = se3.invert(T_w_c)
    det_records = []
    estimates_w: dict[str, list[np.ndarray]] = {m: [] for m in METHODS}
    frame_errors: dict[str, list[float]] = {m: [] for m in METHODS}
    ranges = []
    for i, est in enumerate(per_det):
        cone_index = cone_of.get(i)
        errors, range_m, p_c_true = {}, None, None
        if cone_index is not None:
            p_true_w = cones_w[cone_index]
            p_c_true = se3.apply(T_c_w, p_true_w)
            range_m = float(np.linalg.norm(p_c_true))
            ranges.append(range_m)
            for method, p_w in est.items():
                if p_w is not None:
                    errors[method] = float(metrics.position_error(p_true_w, p_w)[0])
                    frame_errors[method].append(errors[method])
        for method, p_w in est.items():
            if p_w is not None:
                estimates_w[method].append(p_w)
        in_contract = (
            cone_index in in_view
            and range_m is not None
            and CONTRACT_RANGE_M[0] <= range_m <= CONTRACT_RANGE_M[1]
        )
        det_records.append(
            DetectionRecord(
                cone_index,
                {m: p for m, p in est.items() if p is not None},
                errors,
                range_m,
                p_c_true,
                in_contract,
            )
        )

    reference_error = None
    last_reference = getattr(driver, "last_reference", None)
    if last_reference is not None:
        reference_error = float(np.linalg.norm(T_w_b[:3, 3] - last_reference.p_w))

    record = FrameRecord(
        frame=k,
        t_s=world.time_s,
        T_w_b=T_w_b,
        quat_xyzw=world.quat_xyzw,
        rpy_rad=rpy,
        gimbal_locked=locked,
        cones_in_view=in_view,
        detections=det_records,
        reference_error_m=reference_error,
    )
    cloud_w = None
    if depth_m is not None:
        cloud_w = depth_to_world_points(
            depth_m, camera, T_w_b_est @ T_b_c, stride=CLOUD_STRIDE_PX, far_m=far_m
        )
    return (
        record,
        {m: np.array(v).reshape(-1, 3) for m, v in estimates_w.items()},
        {m: float(np.mean(v)) for m, v in frame_errors.items() if v},
        float(np.mean(ranges)) if ranges else None,
        cloud_w,
    )


def _cone0_coordinates(
    record: FrameRecord, T_b_c: np.ndarray, cones_w: np.ndarray
) -> dict[str, np.ndarray]:
    """Cone 0's true base centre in world, body and camera frames, and its depth estimate.

    The lecture's chapter 8 composer: ``p_b = T_b_w p_w`` and ``p_c = T_c_b p_b``.
    """
    p_w = cones_w[0]
    T_b_w = se3.invert(record.T_w_b)
    p_b = se3.apply(T_b_w, p_w)
    p_c = se3.apply(se3.invert(T_b_c), p_b)
    out = {"world": p_w, "body": p_b, "camera": p_c}
    estimate = next(
        (
            d.estimates_w.get("depth_image")
            for d in record.detections
            if d.cone_index == 0 and "depth_image" in d.estimates_w
        ),
        None,
    )
    if estimate is not None:
        out["estimate_world"] = estimate
    return out


def describe(spec: ScenarioSpec, seed: int) -> str:
    """Markdown shown beside the recording: what the scenario is and teaches."""
    cam = spec.scene.camera
    lines = [
        f"# {spec.name}",
        "",
        spec.description,
        "",
    ]
    if spec.lesson:
        lines += [spec.lesson.strip(), ""]
    lines += [
        f"- flight: {spec.flight.mode}, {spec.end_s:g} s simulated, camera at "
        f"{spec.camera_rate_hz:g} Hz, seed {seed}",
        f"- camera: {cam.width}x{cam.height}, fovy {cam.fovy_deg:g} deg, pitched "
        f"{cam.pitch_down_deg:g} deg down at {list(cam.position_b)} m in the body frame",
        f"- cones (base centres, world): {[list(c) for c in spec.scene.cones_w]}",
        "",
        "Estimates: **depth_image** (blue), **ground_plane** (green), **known_height** "
        "(magenta), **naive** (red: camera coordinates added to the drone's position as if "
        "they were world coordinates, lecture chapter 0). Truth: white.",
    ]
    return "\n".join(lines)
