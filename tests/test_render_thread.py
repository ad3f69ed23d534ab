"""Rendering off the caller's thread: every OpenGL call on the process's one OpenGL thread,
``Renderer.render_async`` reading the simulation when called, and runs that overlap each
image's render with the physics and the estimation giving the reports of runs that do not."""

from __future__ import annotations

import dataclasses
import os
import select
import signal
import threading

import numpy as np

from scenarios import pipeline
from scenarios.scenario import builtin
from scenarios.scenario.spec import from_dict
from sim.config import SceneConfig
from sim.gl import on_gl_thread
from sim.render import Renderer
from sim.world import World
from vnav import se3, so3


def test_every_gl_call_runs_on_one_thread_not_the_callers():
    first = on_gl_thread(threading.current_thread)
    assert first is not threading.current_thread()
    assert first.name.startswith("vnav-gl")
    assert on_gl_thread(threading.current_thread) is first
    # A call made on that thread runs there at once (no deadlock waiting for itself).
    assert on_gl_thread(on_gl_thread, threading.current_thread) is first


def test_render_async_draws_the_state_of_its_call_not_of_its_result():
    world = World.from_config(SceneConfig())
    T_a = se3.make(so3.from_rpy(0.0, 0.0, np.arctan2(1.0, 6.0)), [0.0, 0.0, 4.0])
    T_b = se3.make(np.eye(3), [1.0, -0.5, 3.0])
    with Renderer(world) as renderer:
        world.set_pose(T_a)
        pending = [renderer.render_async(depth=True) for _ in range(3)]  # both scenes reused
        world.set_pose(T_b)  # while they render
        at_b = renderer.render(depth=True)
        world.set_pose(T_a)
        at_a = renderer.render(depth=True)
        for future in pending:
            image = future.result()
            np.testing.assert_array_equal(image.rgb, at_a.rgb)
            np.testing.assert_array_equal(image.depth, at_a.depth)
            assert image.time_s == at_a.time_s
    assert not np.array_equal(at_a.rgb, at_b.rgb)  # the two states do look different


def _report(spec, render_ahead: bool) -> dict:
    outcome = pipeline.run(spec, seed=3, render_ahead=render_ahead)
    report = dict(outcome.report)
    del report["timing_s"]
    return report


def test_a_run_rendering_ahead_reports_what_one_waiting_for_each_render_does():
    # The reference: each image evaluated as it is delivered, the run waiting for its render
    # (as a sweep's worker runs, and as every run did before rendering ahead). Image and
    # depth noise (their draws in the images' order) and a link with latency and jitter
    # (images delivered late, several at a time).
    late = builtin.latency()  # three images in flight at a time, with uncertainty's noise
    late["timing"] = {**late["timing"], "image_latency_s": 0.25, "jitter_s": 0.02}
    late["noise"] = builtin.uncertainty()["noise"]
    for spec in (
        dataclasses.replace(builtin.load("uncertainty"), duration_s=3.0),
        dataclasses.replace(from_dict(late), duration_s=3.0),
    ):
        assert _report(spec, render_ahead=True) == _report(spec, render_ahead=False)


def test_a_forked_child_calls_on_a_gl_thread_of_its_own():
    # The parent's OpenGL thread does not exist in a forked child: a call queued for it
    # would wait for ever. (No context is made in the child: an EGL display initialised
    # before a fork is not usable after it, which is why worker processes start from a
    # fresh interpreter, ``scenarios.commands.workers``.)
    parent_tid = on_gl_thread(threading.get_native_id)
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:
        try:
            child_tid = on_gl_thread(threading.get_native_id)
            os.write(write, b"ok" if child_tid not in (parent_tid, os.getpid()) else b"no")
        finally:
            os._exit(0)
    os.close(write)
    ready, _, _ = select.select([read], [], [], 30.0)
    os.waitpid(pid, 0) if ready else os.kill(pid, signal.SIGKILL)
    assert ready and os.read(read, 2) == b"ok"
    assert on_gl_thread(threading.get_native_id) == parent_tid
