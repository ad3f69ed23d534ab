"""Run a scenario in the simulator: fly, render, detect, evaluate each camera tick.

One camera tick of ``run_scenario``::

    fly      step the physics (or the keyframes) to the tick's time     <- sim.flight
    truth    T_w_b, T_b_c, cones_w                                      <- sim.world.World
    render   rgb, depth, one pass, plus the scenario's image and depth noise
                                                     <- sim.render.Renderer, sim.noise
    detect   detections                                                 <- vnav.detect
    evaluate estimates per method, matched and compared with the truth  <- scenarios.run.evaluate
    observe  the tick's record and images go to the observer (the recording, if any)

The observer is started before the first tick and told to ``abort`` if the run fails; it is not
finished here: its owner (``scenarios.pipeline``) first judges the run, then finishes it with
the verdicts, so that what is judged is also recorded.
The estimator is given ``T_w_b_est``: the true pose, plus the scenario's pose noise if any,
and the camera mount with the scenario's mount error; it is told the noise figures and the
poses' covariances, and gives each estimate a covariance. Every draw comes from the run's
seed, so a seed fixes the whole run. This module runs MuJoCo but knows
nothing of Rerun: whatever is done with each tick is the observer's business.
"""

from __future__ import annotations

import bisect
import contextlib
import logging
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from scenarios.run.evaluate import TickTruth, evaluate_tick
from scenarios.run.navigation import Navigator
from scenarios.run.observers import abort_all
from scenarios.run.records import ImageTiming, ImuRecord, PoseStream, RunResult, TickRecord
from scenarios.run.streams import BODY, WORLD, Delivered, Receiver, Streams
from scenarios.scenario.spec import (
    ControlledFlight,
    KinematicFlight,
    NavigateFlight,
    OrbitFlight,
    ScenarioSpec,
)
from sim.flight import (
    Autopilot,
    KeyframePlayer,
    KeyframeTrajectory,
    MinimumJerkTrajectory,
    OrbitTrajectory,
    ReferenceFollower,
)
from sim.imu import (
    ImuSampler,
    ImuSteps,
    chain_imu_many_i,
    imu_discrepancy_many,
    rate_correction_i,
    to_stamp_many,
)
from sim.mesh import Scenery, scenery
from sim.noise import mount_error, noisy_depth, noisy_pose, noisy_rgb
from sim.render import RenderedImage, Renderer
from sim.scene_cache import SceneCache
from sim.world import World
from vnav import quat, se3, so3
from vnav.camera import PinholeCamera
from vnav.detect import detect_cones
from vnav.frames import FrameBuffer
from vnav.localize import Localizer
from vnav.sensor_noise import body_pose_covariance, mount_covariance

__all__ = ["STAGES", "FanOut", "TickObserver", "run_scenario"]

logger = logging.getLogger(__name__)

STAGES = ("physics", "streams", "render", "detect", "localize", "navigate", "clearance", "log")
"""The per-tick stages timed in ``RunResult.timing_s``: ``streams`` is the sensor streams' and
the pose buffers' share (sampling, sending, delivering, looking up); ``navigate`` and
``clearance`` the closed loop's (``scenarios.run.navigation.Navigator``): its map, planner and
steering at each camera tick (``on_tick``), and the truth it reads from MuJoCo after each
pose sample's physics (``after_physics``: contact, clearance, goal), both 0 for a flight that
does not navigate. ``setup`` is once per run:
here the world, the GL context and the observer's ``start``; ``scenarios.pipeline`` adds the
observer's finish (the recording's end: its plots, layout and file footer)."""


class TickObserver(Protocol):
    """Receives a run as it happens (``scenarios.record.recording.Recording`` is one).

    ``start`` before the first tick (with the camera and the drone and cones as meshes built
    from the MuJoCo model, ``sim.mesh``), ``on_tick`` after each, or ``abort`` if the run
    fails. The run does not finish its observer: whoever passed it in does, once the run is
    judged (``scenarios.pipeline.run``), and aborts it if judging fails.
    """

    def start(
        self, spec: ScenarioSpec, seed: int, camera: PinholeCamera, scenery: Scenery
    ) -> None: ...

    def on_tick(self, record: TickRecord, rgb: np.ndarray, depth_m: np.ndarray | None) -> None: ...

    def abort(self) -> None: ...


class FanOut:
    """One ``TickObserver`` that passes everything to several, in order (the recording, then
    each exporter, ``scenarios.export``).

    Parameters
    ----------
    *observers : TickObserver
    """

    def __init__(self, *observers: TickObserver) -> None:
        self.observers = observers

    def start(self, spec: ScenarioSpec, seed: int, camera: PinholeCamera, scenery: Scenery) -> None:
        for o in self.observers:
            o.start(spec, seed, camera, scenery)

    def on_tick(self, record: TickRecord, rgb: np.ndarray, depth_m: np.ndarray | None) -> None:
        for o in self.observers:
            o.on_tick(record, rgb, depth_m)

    def abort(self) -> None:
        """Abort every observer, even if one fails to; then raise the first failure."""
        abort_all(self.observers)


def run_scenario(
    spec: ScenarioSpec,
    *,
    seed: int = 1,
    observer: TickObserver | None = None,
    progress: Callable[[int, int], None] | None = None,
    scenes: SceneCache | None = None,
    render_ahead: bool = True,
) -> RunResult:
    """Run ``spec`` headless and return what it saw, tick by tick.

    Parameters
    ----------
    spec : ScenarioSpec
    seed : int
        Seeds the pose noise (if the scenario has any).
    observer : TickObserver, optional
        Given every tick's record and images as they are made (e.g. a recording); started
        here, aborted here if the run fails, left open otherwise (the caller finishes it).
    progress : callable(done, total), optional
        Called after every camera tick.
    scenes : sim.scene_cache.SceneCache, optional
        Where to take the world and its renderer from (and leave them): a process running
        many episodes builds each scene once. Without it the run builds and frees its own.
    render_ahead : bool
        Render each image on the OpenGL thread while the run estimates the one before and
        steps the physics to the next (a flight that does not steer by what it sees): about
        two cores' work at once. False: each image is evaluated as soon as it is delivered,
        the run waiting for its render, for a process that has one core of several (a
        sweep's worker). The results are the same either way.

    Raises
    ------
    sim.world.SimulationError
        If the flight diverges (NaN or an exploding state), naming the time. The observer is
        told to ``abort`` first.
    """
    setup_start = time.perf_counter()
    result = RunResult(spec=spec, seed=seed, timing_s=dict.fromkeys((*STAGES, "render_gl"), 0.0))
    with contextlib.ExitStack() as owned:
        if scenes is None:
            world = World.from_config(spec.scene)
            renderer = owned.enter_context(Renderer(world))
        else:
            world, renderer = scenes.acquire(spec.scene)
        _observe_and_run(
            spec, seed, world, renderer, result, observer, progress, setup_start, render_ahead
        )
    return result


def _observe_and_run(
    spec: ScenarioSpec,
    seed: int,
    world: World,
    renderer: Renderer,
    result: RunResult,
    observer: TickObserver | None,
    progress: Callable[[int, int], None] | None,
    setup_start: float,
    render_ahead: bool,
) -> None:
    """The ticks, after the observer's ``start`` (its ``abort`` if they fail)."""
    try:
        if observer:
            observer.start(
                spec, seed, world.camera, scenery(world.model, world.data, len(spec.scene.cones_w))
            )
        # Building the world, the GL context and the observer's start.
        result.timing_s["setup"] = time.perf_counter() - setup_start
        _run_ticks(spec, world, renderer, result, observer, progress, render_ahead)
    except BaseException:
        if observer:
            observer.abort()
        raise


def _run_ticks(
    spec: ScenarioSpec,
    world: World,
    renderer: Renderer,
    result: RunResult,
    observer: TickObserver | None,
    progress: Callable[[int, int], None] | None,
    render_ahead: bool = True,
) -> None:
    """Every camera tick of the run, appended to ``result.ticks`` in order, each stage timed.

    The physics advances one pose sample at a time; each sample goes out on the pose stream,
    each image on the camera's link, and every image is evaluated once it has arrived and its
    exposure pose can be looked up (``scenarios.run.streams``). After the last exposure the
    simulation runs on until every image has been evaluated.
    """
    flow = _Flow(spec, world, result.seed)
    camera_track = _camera_track(spec)
    cones_w = world.cones_w
    evaluate = _Evaluator(flow, result, observer, progress, spec.n_ticks, render_ahead)
    for k in range(spec.n_ticks):
        evaluate(flow.advance_to(flow.step_of(k / spec.camera_rate_hz)))
        if flow.navigator is not None and flow.navigator.ended:
            break  # at the goal or a cone: no more images
        image = _capture(k, flow, world, renderer, camera_track, cones_w, result.timing_s)
        evaluate.settle()  # the images before this one, while it renders
        evaluate(flow.expose(image))
    evaluate(flow.drain())
    evaluate.settle()
    _finish(flow, world, result)


class _Evaluator:
    """Evaluates the images the camera's link delivers, in order: each one's record appended
    to the run's, the navigator steered by it and the observer told, each stage timed.

    In a flight that does not steer by what it sees, the images delivered wait (``settle``
    evaluates them): the run steps the physics to the next image and queues its render
    first, so that rendering overlaps the estimation and the physics. Every result is the
    same: the images are evaluated in the same order, each with what was delivered with it
    (the pose stream's lookups are made on delivery), and the noise of each image is drawn
    in the order the images were taken (``_Flow.finish_through``). A closed loop evaluates
    each image as it is delivered: what it sees steers the next physics step.
    """

    def __init__(
        self,
        flow: _Flow,
        result: RunResult,
        observer: TickObserver | None,
        progress: Callable[[int, int], None] | None,
        n_ticks: int,
        render_ahead: bool = True,
    ) -> None:
        self.flow = flow
        self.result = result
        self.observer = observer
        self.progress = progress
        self.n_ticks = n_ticks
        self.done = 0
        """Images evaluated so far."""
        self.deferred = render_ahead and flow.navigator is None
        self.waiting: list[Delivered] = []

    def __call__(self, delivered: list[Delivered]) -> None:
        """Evaluate ``delivered``, in order (after those waiting), or keep them waiting."""
        self.waiting += delivered
        if not self.deferred:
            self.settle()

    def settle(self) -> None:
        """Evaluate every image waiting, in order."""
        delivered, self.waiting = self.waiting, []
        flow, observer, timing = self.flow, self.observer, self.result.timing_s
        for d in delivered:
            image: _Image = d.payload
            flow.finish_through(image, timing)
            t0 = time.perf_counter()
            record = flow.evaluate(d)
            self.result.ticks.append(record)
            t1 = time.perf_counter()
            if flow.navigator is not None:  # the closed loop: what was seen steers
                newest = d.T_w_b_latest if d.T_w_b_latest is not None else d.T_w_b_at_exposure
                flow.navigator.on_tick(record, newest)
            t2 = time.perf_counter()
            if observer:
                observer.on_tick(record, image.rgb, image.depth)
            timing["localize"] += t1 - t0
            timing["navigate"] += t2 - t1
            timing["log"] += time.perf_counter() - t2
            self.done += 1
            if self.progress:
                self.progress(self.done, self.n_ticks)


def _capture(
    k: int,
    flow: _Flow,
    world: World,
    renderer: Renderer,
    camera_track: list[tuple[float, np.ndarray]],
    cones_w: np.ndarray,
    timing: dict[str, float],
) -> _Image:
    """Camera tick ``k``'s image taken now: the camera moved along its track, the render
    queued (``_Flow.finish_through`` adds the scenario's noise and detects the cones), with
    the truth at this instant (its ``cones_w`` the run's)."""
    t0 = time.perf_counter()
    if camera_track:
        world.set_camera_position_b(_interpolate(camera_track, world.time_s))
    # The simulator's truth is read (counted with the physics) before the render is queued,
    # so that its time is not shared with the render's.
    truth = _truth(k, world, flow.driver, cones_w)
    t1 = time.perf_counter()
    image = flow.take(renderer)
    image.truth = truth
    timing["physics"] += t1 - t0
    timing["render"] += time.perf_counter() - t1
    return image


def _finish(flow: _Flow, world: World, result: RunResult) -> None:
    """The run's streams' times and records into ``result`` once every image is evaluated:
    the pose stream, the IMU's readings (its reading on every step stopped) and the closed
    loop's record."""
    timing = result.timing_s
    timing["physics"] += flow.physics_s
    timing["clearance"] += flow.clearance_s
    timing["streams"] += flow.streams_s
    result.poses = flow.pose_stream()
    if flow.imu is not None:
        world.on_step = None
        result.imu = flow.imu.record()
    if flow.navigator is not None:
        result.navigation = flow.navigator.record


class _Imu:
    """The scenario's IMU (``[imu]``), read at every physics step as it is taken
    (``World.on_step``: the state it starts from, under the controls it applies): a reading
    when one is due, and the noise-free sensors compared with ``vnav.imu``'s chain at every
    step.

    Each step only keeps the state the IMU reads (``sim.imu.ImuSteps``) and whether a reading
    is due; the readings, their noise, the chain and the discrepancy are computed for every
    step at once in ``record`` (equal to the last bit to the per-step functions':
    ``tests/test_sim_imu.py``), so that the IMU adds little to a camera tick."""

    def __init__(self, spec: ScenarioSpec, world: World, seq: np.random.SeedSequence) -> None:
        imu = spec.scene.imu
        assert imu is not None
        # t_imu = t_cam + time_offset_s (Kalibr) and t_sim = t_pose = t_cam + camera offset.
        clock_offset_s = imu.time_offset_s - spec.timing.camera_clock_offset_s
        self.sampler = ImuSampler(
            imu, float(world.model.opt.timestep), np.random.default_rng(seq), clock_offset_s
        )
        self.timestep_s = float(world.model.opt.timestep)
        self.gravity_w = world.model.opt.gravity.copy()
        self.T_b_i = world.T_b_i
        self.state = ImuSteps(world)
        self.steps: list[int] = []
        """The step of each reading."""
        world.on_step = self  # the first step's call reads t = 0

    def __call__(self, world: World) -> None:
        self.state.take(world)
        if self.sampler.take_due(world):
            self.steps.append(len(self.state) - 1)

    def record(self) -> ImuRecord:
        s = self.state.stacked()
        chain_i = chain_imu_many_i(
            s["T_w_b"],
            self.T_b_i,
            s["acceleration_w"],
            s["angular_velocity_b"],
            s["angular_acceleration_b"],
            self.gravity_w,
        )
        discrepancy = imu_discrepancy_many(s["accel_i"], s["gyro_i"], *chain_i)
        # The largest, NaN aside, 0 without a step (as a running max from 0 would be).
        max_discrepancy = float(np.nanmax(discrepancy, initial=0.0))
        steps = np.array(self.steps, dtype=np.int64)
        omega_b, alpha_b = s["angular_velocity_b"], s["angular_acceleration_b"]
        # The readings and the chain's prediction at their instants, moved to the stamps.
        accel_i, gyro_i = to_stamp_many(
            self.timestep_s,
            self.T_b_i,
            s["accel_i"][steps],
            s["gyro_i"][steps],
            omega_b[steps],
            alpha_b[steps],
        )
        t_s, accel_i, gyro_i = self.sampler.sample_many(s["time_s"][steps], accel_i, gyro_i)
        accel_chain_i, gyro_chain_i = to_stamp_many(
            self.timestep_s,
            self.T_b_i,
            chain_i[0][steps],
            chain_i[1][steps],
            omega_b[steps],
            alpha_b[steps],
        )
        # MuJoCo's Euler step: the rate the last step leaves.
        omega_next_b = omega_b[-1] + self.timestep_s * alpha_b[-1] if len(omega_b) else np.zeros(3)
        # The gyro's rate at each stamp to fourth order, now that the steps after are known.
        fourth_i = rate_correction_i(
            np.concatenate([omega_b, omega_next_b[None]]), steps, self.T_b_i[:3, :3].copy()
        ).reshape(-1, 3)
        return ImuRecord(
            t_s=t_s,
            accel_i=accel_i.reshape(-1, 3),
            gyro_i=gyro_i.reshape(-1, 3) + fourth_i,
            max_discrepancy=max_discrepancy,
            steps_checked=len(self.state),
            accel_chain_i=accel_chain_i.reshape(-1, 3),
            gyro_chain_i=gyro_chain_i.reshape(-1, 3) + fourth_i,
        )


@dataclass
class _Image:
    """What travels with an image to the estimator (and the truth the evaluation needs):
    its render until ``_Flow.finish_through`` has made the rest."""

    rendering: Future[RenderedImage] | None
    truth: TickTruth | None = None
    detections: list | None = None
    rgb: np.ndarray | None = None
    depth: np.ndarray | None = None


class _Flow:
    """The simulation's clock and the sensor streams: physics stepped a pose sample at a time.

    Pose sample ``j`` is the state after the physics step nearest ``j / pose_rate_hz``; it
    is sent (with the scenario's pose noise, drawn per sample) on the pose stream and kept
    exactly in a truth buffer, which gives the body's true motion between two stamps.
    """

    def __init__(self, spec: ScenarioSpec, world: World, seed: int) -> None:
        self.spec = spec
        self.world = world
        self.driver = _driver(world, spec)
        self.navigator = (
            Navigator(spec.flight, world, self.driver)
            if isinstance(spec.flight, NavigateFlight)
            else None
        )
        self.dt = float(world.model.opt.timestep)
        t = spec.timing
        # Independent streams of randomness: pose noise, arrival jitter, image and depth noise,
        # the mount's error, the IMU's noise (children 0 and 1 are those of runs before the
        # others existed; a SeedSequence's first children do not depend on how many it spawns).
        noise_seq, jitter_seq, image_seq, depth_seq, mount_seq, imu_seq = np.random.SeedSequence(
            seed
        ).spawn(6)
        self._noise_rng = np.random.default_rng(noise_seq)
        self.image_rng = np.random.default_rng(image_seq)
        self.depth_rng = np.random.default_rng(depth_seq)
        self.mount_error = mount_error(spec.noise, np.random.default_rng(mount_seq))
        self.cov_T_b_c = mount_covariance(spec.noise)
        # The scenario's fixed mount error: T_b_c_true = T_b_c_declared @ E, so the estimator's
        # declared mount is the true one times E^-1 (then the per-run extrinsic noise).
        self.true_to_declared = se3.invert(spec.scene.camera.mount_error.T)
        self.localizer = Localizer(
            world.camera,
            far_m=spec.scene.zfar_m,
            noise=spec.noise,
        )
        self.streams = Streams(
            pose_latency_s=t.pose_latency_s,
            image_latency_s=t.image_latency_s,
            jitter_s=t.jitter_s,
            camera_clock_offset_s=t.camera_clock_offset_s,
            rng=np.random.default_rng(jitter_seq),
        )
        # The receiver keeps what the slowest image may still need; the truth buffer all.
        wait_s = t.image_latency_s + t.pose_latency_s + 20.0 * t.jitter_s + 2.0 / t.pose_rate_hz
        self.receiver = Receiver(t.camera_clock_offset_s, cache_s=max(10.0, 2.0 * wait_s))
        self.truth = FrameBuffer(cache_s=spec.end_s + wait_s + 10.0)  # the whole run
        self._wait_s = wait_s + 1.0
        self.physics_s = 0.0  # seconds in the driver's steps
        self.clearance_s = 0.0  # seconds in the navigator's truth after them
        self.streams_s = 0.0  # seconds in everything else here
        self._step = 0
        self._j = 0  # the next pose sample
        self._truth_new: list[tuple[float, np.ndarray]] = []  # not yet in self.truth
        self._stamps: list[float] = []
        self._sent: list[np.ndarray] = []
        self._arrivals: list[float] = []
        self._unfinished: deque[_Image] = deque()  # taken, not yet finished, in order
        self._sample()  # the first pose, at t = 0
        self.imu = None if spec.scene.imu is None else _Imu(spec, world, imu_seq)

    def step_of(self, t_s: float) -> int:
        """The physics step nearest ``t_s``."""
        return round(t_s / self.dt)

    def _next_sample_step(self) -> int:
        return self.step_of(self._j / self.spec.timing.pose_rate_hz)

    def _sample(self) -> None:
        """Take pose sample ``j`` now and send it."""
        self._send(self.world.time_s, self.world.T_w_b)
        self._j += 1

    def _send(self, stamp_s: float, T_w_b: np.ndarray) -> None:
        """Keep the true pose at ``stamp_s`` and send it, with the pose noise, to the estimator."""
        self._truth_new.append((stamp_s, T_w_b))
        sent = noisy_pose(T_w_b, self.spec.noise, self._noise_rng)
        self._arrivals.append(self.streams.send_pose(stamp_s, sent))
        self._stamps.append(stamp_s)
        self._sent.append(sent)

    def _deliver(self) -> list[Delivered]:
        if not (self.streams.images_in_flight or self.receiver.waiting):
            return []  # poses wait in the link until an image needs them
        return self.streams.deliver(self.world.time_s, self.receiver)

    def _drive(self, n: int) -> None:
        t0 = time.perf_counter()
        nav = self.navigator
        nav_s = 0.0
        if nav is None:
            self.driver.step(n)
        else:
            t_end_s = self.world.time_s + n * self.dt
            if not nav.ended:
                self.driver.step(n)  # stops at the first contact with a cone
                t1 = time.perf_counter()
                nav.after_physics()
                nav_s = time.perf_counter() - t1
            if nav.ended:
                # The flight is over (a cone or the goal): the drone is held where it ended
                # while time runs on, so that the images in flight still arrive.
                self.world.data.time = t_end_s
        self.clearance_s += nav_s
        self.physics_s += time.perf_counter() - t0 - nav_s

    def advance_to(self, step: int) -> list[Delivered]:
        """Step the physics to ``step``, sampling poses on the way; the images delivered."""
        t0 = time.perf_counter()
        driven0 = self.physics_s + self.clearance_s
        if isinstance(self.driver, KeyframePlayer):
            out = self._advance_keyframes(step)
        else:
            out = []
            while self._step < step:
                n = min(self._next_sample_step(), step) - self._step
                self._drive(n)
                self._step += n
                if self._step == self._next_sample_step():
                    self._sample()
                    out += self._deliver()
        driven_s = self.physics_s + self.clearance_s - driven0
        self.streams_s += time.perf_counter() - t0 - driven_s
        return out

    def _advance_keyframes(self, step: int) -> list[Delivered]:
        """``advance_to`` for a keyframe flight, which has no dynamics: the world is placed
        once, at ``step``, and the samples on the way are the keyframes' poses at their stamps
        (what the world would report there), looked up together."""
        if self._step >= step:
            return []
        t0_s, step0 = self.world.time_s, self._step
        steps = []
        while self._next_sample_step() <= step:
            steps.append(self._next_sample_step())
            self._j += 1
        self._drive(step - step0)
        self._step = step
        if steps:
            # The player sets the time to t0 + n dt: a sample at ``step`` gets exactly the
            # world's time, the exposure stamp of an image taken there.
            stamps = [t0_s + (s - step0) * self.dt for s in steps]
            for stamp_s, T_w_b in zip(stamps, self.driver.keyframes.poses(stamps), strict=True):
                self._send(stamp_s, T_w_b)
        return self._deliver()

    def expose(self, image: _Image) -> list[Delivered]:
        """The image just rendered leaves, stamped at exposure; the images delivered."""
        t0 = time.perf_counter()
        self.streams.send_image(self.world.time_s, image)
        out = self._deliver()
        self.streams_s += time.perf_counter() - t0
        return out

    def drain(self) -> list[Delivered]:
        """Run on until every image sent has been evaluated."""
        out = self._deliver()
        deadline_s = self.world.time_s + self._wait_s
        while self.streams.images_in_flight or self.receiver.waiting:
            if self.world.time_s > deadline_s:
                raise RuntimeError(
                    f"images still undelivered {self._wait_s:.3g} s after the last exposure"
                )
            out += self.advance_to(self._next_sample_step())
        return out

    def take(self, renderer: Renderer) -> _Image:
        """The camera's image of the state now, its render queued (``Renderer.render_async``)."""
        image = _Image(renderer.render_async(depth=True))
        self._unfinished.append(image)
        return image

    def finish_through(self, image: _Image, timing: dict[str, float]) -> None:
        """Finish every image taken up to ``image``, in the order taken: the render waited
        for, the scenario's image and depth noise added (drawn in that order, as if each were
        finished when taken), the cones detected."""
        noise = self.spec.noise
        while image.rendering is not None:
            first = self._unfinished.popleft()
            t0 = time.perf_counter()
            rendered = first.rendering.result()
            first.rendering = None
            first.rgb = noisy_rgb(rendered.rgb, noise, self.image_rng)
            first.depth = rendered.depth
            if first.depth is not None:
                first.depth = noisy_depth(
                    first.depth, noise, self.spec.scene.zfar_m, self.depth_rng
                )
            t1 = time.perf_counter()
            first.detections = detect_cones(first.rgb)
            timing["render"] += t1 - t0
            timing["render_gl"] += rendered.draw_s
            timing["detect"] += time.perf_counter() - t1

    def evaluate(self, d: Delivered) -> TickRecord:
        """Evaluate a delivered image with what the estimator was told: the pose at its
        exposure stamp, the declared mount (``[camera.mount_error]`` and the run's extrinsic
        error away from the truth), the sensors' noise and the apex tracks."""
        image: _Image = d.payload
        return evaluate_tick(
            image.truth,
            image.detections,
            image.depth,
            self.localizer,
            d.T_w_b_at_exposure,
            self.image_timing(d),
            T_b_c_est=self.mount_error @ image.truth.T_b_c @ self.true_to_declared,
            cov_T_w_b=self.pose_covariance(d),
            cov_T_b_c=self.cov_T_b_c,
            # A calibrated run is estimated again with the mount it recovers: keep its depth.
            keep_depth=self.spec.checks_calibration,
        )

    def pose_covariance(self, d: Delivered) -> np.ndarray:
        """The covariance the estimator is told for ``d.T_w_b_at_exposure``, (6, 6).

        Each sample's noise is independent; the pose interpolated at a fraction ``a`` between
        two samples carries ``(1 - a) xi_0 + a xi_1`` to first order, so its covariance is the
        sample's times ``(1 - a)^2 + a^2`` (1 on a sample, 1/2 half-way).
        """
        if not self.spec.noise.noisy("pose"):
            return np.zeros((6, 6))
        t = d.exposure_pose_s
        j = bisect.bisect_left(self._stamps, t - 1e-9)
        a = 0.0
        if j < len(self._stamps) and abs(self._stamps[j] - t) > 1e-9 and j > 0:
            t0, t1 = self._stamps[j - 1], self._stamps[j]
            a = (t - t0) / (t1 - t0)
        factor = (1.0 - a) ** 2 + a * a
        return factor * body_pose_covariance(d.T_w_b_at_exposure, self.spec.noise)

    def image_timing(self, d: Delivered) -> ImageTiming:
        """The stamps of a delivered image and the body's true motion since the newest pose."""
        t0 = time.perf_counter()
        motion_m = motion_rad = 0.0
        if d.latest_stamp_s is not None and d.latest_stamp_s != d.exposure_pose_s:
            if self._truth_new:  # in one batch, only when needed: far cheaper than per sample
                stamps, poses = zip(*self._truth_new, strict=True)
                self.truth.set_transform(WORLD, BODY, np.array(stamps), np.array(poses))
                self._truth_new.clear()
            T_a = self.truth.lookup(WORLD, BODY, d.exposure_pose_s)
            T_b = self.truth.lookup(WORLD, BODY, d.latest_stamp_s)
            motion_m = float(np.linalg.norm(T_b[:3, 3] - T_a[:3, 3]))
            motion_rad = float(np.linalg.norm(so3.log(T_a[:3, :3].T @ T_b[:3, :3])))
        self.streams_s += time.perf_counter() - t0
        return ImageTiming(
            stamp_cam_s=d.stamp_cam_s,
            exposure_pose_s=d.exposure_pose_s,
            arrival_s=d.arrival_s,
            latest_pose_s=d.latest_stamp_s,
            T_w_b_latest=d.T_w_b_latest,
            true_motion_m=motion_m,
            true_motion_rad=motion_rad,
        )

    def pose_stream(self) -> PoseStream:
        """Every pose sample sent, as stamped, with its arrival."""
        return PoseStream(
            np.array(self._stamps), np.array(self._sent).reshape(-1, 4, 4), np.array(self._arrivals)
        )


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
        # A keyframe flight places the body and zeroes MuJoCo's velocity: its keyframes know.
        v_w_b_mps=driver.keyframes.velocity_w(world.time_s)
        if isinstance(driver, KeyframePlayer)
        else world.velocity_w,
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
    if isinstance(flight, NavigateFlight):
        return ReferenceFollower(world)  # steered by the run's Navigator
    assert isinstance(flight, ControlledFlight)
    wps = flight.waypoints  # one waypoint is a hover there
    trajectory = MinimumJerkTrajectory(
        [w.t_s for w in wps], [w.position_w for w in wps], [w.yaw_rad for w in wps]
    )
    return Autopilot(world, trajectory)
