"""Worlds and their renderers kept across runs of the same scene.

Building a scene costs about 150 ms on this project's 2-core machine (compiling the model
~10 ms, MuJoCo's rendering context ~125 ms, the first render ~25 ms) and a process's first
OpenGL context ~300 ms more; a 14 s scenario runs in about 1.7 s. A process that runs many
episodes (a sweep worker, ``vnav-demo run`` with several scenarios) keeps the scenes it built:
the next run of the same ``SceneConfig`` starts from ``World.reset``, which is the state of a
world just built (a test compares the two runs number for number). Every renderer of a cache
draws in one OpenGL context: a new scene then costs about 25 ms, not 200 (most of a scene's
cost is a new context's first ``MjrContext``; a test compares the images with those of a
renderer of its own).

A cache belongs to the process that made it: an OpenGL context cannot be pickled or carried
across ``fork``, so a worker builds its own cache after it starts.
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from typing import Any

from sim.config import SceneConfig
from sim.gl import create_gl_context, on_gl_thread
from sim.render import Renderer
from sim.world import World

__all__ = ["SceneCache"]

logger = logging.getLogger(__name__)


class SceneCache:
    """The ``capacity`` most recently used scenes, each a ``World`` with its ``Renderer``.

    Parameters
    ----------
    capacity : int
        Scenes kept (least recently used dropped first); each holds an OpenGL context and
        its buffers, a few MB.

    Use as a context manager (or call ``close``) to free the rendering contexts.
    """

    def __init__(self, capacity: int = 2) -> None:
        if int(capacity) != capacity or capacity < 1:
            raise ValueError(f"capacity must be a positive int, got {capacity!r}")
        self.capacity = int(capacity)
        self._scenes: OrderedDict[SceneConfig, tuple[World, Renderer]] = OrderedDict()
        self._gl: Any = None  # the OpenGL context of every renderer, made with the first
        self.builds = 0
        """Scenes built so far (a reused scene does not count)."""

    def acquire(self, config: SceneConfig) -> tuple[World, Renderer]:
        """The world of ``config`` at its start state (time 0, at rest), and its renderer.

        The pair stays owned by the cache: do not close the renderer.
        """
        if not isinstance(config, SceneConfig):
            raise ValueError(f"config must be a SceneConfig, got {type(config).__name__}")
        scene = self._scenes.get(config)
        if scene is not None:
            self._scenes.move_to_end(config)
            scene[0].reset()
            return scene
        while len(self._scenes) >= self.capacity:
            _, (_, old) = self._scenes.popitem(last=False)
            old.close()
        world = World.from_config(config)
        if self._gl is None:
            camera = config.camera
            self._gl = create_gl_context(camera.width, camera.height)
        scene = (world, Renderer(world, gl_context=self._gl))
        self._scenes[config] = scene
        self.builds += 1
        logger.debug("built scene %d (%d kept)", self.builds, len(self._scenes))
        return scene

    def close(self) -> None:
        """Free every scene's rendering context, then the OpenGL context (idempotent)."""
        while self._scenes:
            _, (_, renderer) = self._scenes.popitem()
            renderer.close()
        if self._gl is not None:
            on_gl_thread(self._gl.free)  # where every OpenGL call of the process runs
            self._gl = None

    def __len__(self) -> int:
        return len(self._scenes)

    def __enter__(self) -> SceneCache:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
