"""Run a scenario in the simulator: fly, render, detect, evaluate each camera tick.

One camera tick of ``run_scenario``::

    fly      step the physics (or the keyframes) to the tick's time     <- sim.flight
    truth    T_w_b, T_b_c, cones_w                                      <- sim.world.World
    render   rgb, depth, one pass                                       <- sim.render.Renderer
    detect   detections                                                 <- vnav.detect
    evaluate estimates per method, matched and compared with the truth  <- scenarios.evaluate
    observe  the tick's record and images go to the observer (the recording, if any)

The estimator is given ``T_w_b_est``: the true pose, plus the scenario's pose noise if any
(drawn from the run's seed), so a seed fixes the whole run. This module runs MuJoCo but knows
nothing of Rerun: whatever is done with each tick is the observer's business.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from typing import Protocol

import numpy as np

from scenarios.evaluate import TickTruth, evaluate_tick
from scenarios.records import RunResult, TickRecord
from scenarios.spec import ControlledFlight, KinematicFlight, OrbitFlight, ScenarioSpec
from sim.flight import (
    Autopilot,
    KeyframePlayer,
    KeyframeTrajectory,
    MinimumJerkTrajectory,
    OrbitTrajectory,
)
from sim.mesh import Scenery, scenery
from sim.render import Renderer
from sim.world import World
from vnav import quat, se3, so3
from vnav.camera import PinholeCamera
from vnav.detect import detect_cones

__all__ = ["STAGES", "TickObserver", "run_scenario"]

logger = logging.getLogger(__name__)

STAGES = ("physics", "render", "detect", "localize", "log")
"""The per-tick stages timed in ``RunResult.timing_s`` (``setup`` is once per run)."""


class TickObserver(Protocol):
    """Receives a run as it happens (``scenarios.recording.Recording`` is one).

    ``start`` before the first tick (with the camera and the drone and cones as meshes built
    from the MuJoCo model, ``sim.mesh``), ``on_tick`` after each, then ``finish`` with the
    whole result, or ``abort`` if the run fails.
    """

    def start(
        self, spec: ScenarioSpec, seed: int, camera: PinholeCamera, scenery: Scenery
    ) -> None: ...

    def on_tick(self, record: TickRecord, rgb: np.ndarray, depth_m: np.ndarray | None) -> None: ...

    def finish(self, result: RunResult) -> None: ...

    def abort(self) -> None: ...


def run_scenario(
    spec: ScenarioSpec,
    *,
    seed: int = 1,
    observer: TickObserver | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> RunResult:
    """Run ``spec`` headless and return what it saw, tick by tick.

    Parameters
    ----------
    spec : ScenarioSpec
    seed : int
        Seeds the pose noise (if the scenario has any).
    observer : TickObserver, optional
        Given every tick's record and images as they are made (e.g. a recording).
    progress : callable(done, total), optional
        Called after every camera tick.

    Raises
    ------
    sim.world.SimulationError
        If the flight diverges (NaN or an exploding state), naming the time. The observer is
        told to ``abort`` first.
    """
    setup_start = time.perf_counter()
    result = RunResult(spec=spec, seed=seed, timing_s=dict.fromkeys(STAGES, 0.0))
    world = World.from_config(spec.scene)
    try:
        if observer:
            observer.start(
                spec, seed, world.camera, scenery(world.model, world.data, len(spec.scene.cones_w))
            )
        with Renderer(world) as renderer:
            setup_s = time.perf_counter() - setup_start
            _run_ticks(spec, world, renderer, result, observer, progress)
        finish_start = time.perf_counter()
        if observer:
            observer.finish(result)
        # Building the world, the GL context and the observer's start, and its finish.
        result.timing_s["setup"] = setup_s + time.perf_counter() - finish_start
    except BaseException:
        if observer:
            observer.abort()
        raise
    return result


def _run_ticks(
    spec: ScenarioSpec,
    world: World,
    renderer: Renderer,
    result: RunResult,
    observer: TickObserver | None,
    progress: Callable[[int, int], None] | None,
) -> None:
    """Every camera tick of the run, appended to ``result.ticks``, each stage timed."""
    rng = np.random.default_rng(result.seed)
    timing = result.timing_s
    dt = float(world.model.opt.timestep)
    n_ticks = spec.n_ticks
    driver = _driver(world, spec)
    camera_track = _camera_track(spec)
    cones_w = world.cones_w
    for k in range(n_ticks):
        t0 = time.perf_counter()
        n_steps = round((k / spec.camera_rate_hz - world.time_s) / dt)
        if n_steps > 0:
            driver.step(n_steps)
        if camera_track:
            world.set_camera_position_b(_interpolate(camera_track, world.time_s))
        t1 = time.perf_counter()
        image = renderer.render(depth=True)
        t2 = time.perf_counter()
        detections = detect_cones(image.rgb)
        t3 = time.perf_counter()
        truth = _truth(k, world, driver, cones_w)
        T_w_b_est = _noisy_pose(truth.T_w_b, spec, rng)
        record = evaluate_tick(
            truth, detections, image.depth, world.camera, T_w_b_est, spec.scene.zfar_m
        )
        result.ticks.append(record)
        t4 = time.perf_counter()
        if observer:
            observer.on_tick(record, image.rgb, image.depth)
        t5 = time.perf_counter()
        for stage, seconds in zip(
            STAGES, (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4), strict=True
        ):
            timing[stage] += seconds
        if progress:
            progress(k + 1, n_ticks)


def _truth(tick: int, world: World, driver, cones_w: np.ndarray) -> TickTruth:
    """The simulator's ground truth now, in vnav's conventions."""
    T_w_b = world.T_w_b
    reference = getattr(driver, "last_reference", None)
    return TickTruth(
        tick=tick,
        t_s=world.time_s,
        T_w_b=T_w_b,
        T_b_c=world.T_b_c,
        quat_xyzw=world.quat_xyzw,
        cones_w=cones_w,
        reference_error_m=None
        if reference is None
        else float(np.linalg.norm(T_w_b[:3, 3] - reference.p_w)),
    )


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
    """The pose the estimator is given: the truth, perturbed by the scenario's pose noise."""
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
