"""sim.scene_cache: a scene reused across runs gives the same run as a freshly built one."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from scenarios import pipeline
from scenarios.scenario import builtin
from sim.config import CameraConfig, SceneConfig
from sim.render import Renderer
from sim.scene_cache import SceneCache
from sim.world import World


def _numbers(outcome: pipeline.Outcome) -> dict:
    """The report without the machine's timings."""
    return {k: v for k, v in outcome.report.items() if k != "timing_s"}


@pytest.mark.parametrize("name", ["transform-composer", "uncertainty"])
def test_reused_scene_runs_as_a_fresh_one(name):
    """transform-composer slides the camera on the body (``World.reset`` must put it back);
    uncertainty draws noise from the seed. Both run after other scenes and seeds."""
    spec = dataclasses.replace(builtin.load(name), duration_s=3.0)
    fresh = _numbers(pipeline.run(spec, seed=4))
    with SceneCache(capacity=2) as scenes:
        pipeline.run(spec, seed=9, scenes=scenes)
        pipeline.run(
            dataclasses.replace(builtin.load("frame-problem"), duration_s=1.0),
            seed=1,
            scenes=scenes,
        )
        reused = _numbers(pipeline.run(spec, seed=4, scenes=scenes))
        assert scenes.builds == 2  # the third run took its scene from the cache
    assert reused == fresh


def test_least_recently_used_scene_is_dropped():
    specs = [builtin.load(n) for n in ("frame-problem", "approach", "orbit")]
    with SceneCache(capacity=2) as scenes:
        for spec in specs:
            scenes.acquire(spec.scene)
        assert len(scenes) == 2 and scenes.builds == 3
        scenes.acquire(specs[2].scene)  # kept
        assert scenes.builds == 3
        scenes.acquire(specs[0].scene)  # dropped first: built again
        assert scenes.builds == 4
    assert len(scenes) == 0


@pytest.mark.parametrize("bad", [0, -1, 1.5])
def test_bad_capacity_is_refused(bad):
    with pytest.raises(ValueError, match="capacity"):
        SceneCache(capacity=bad)


def test_acquire_refuses_what_is_not_a_scene_config():
    with pytest.raises(ValueError, match="SceneConfig"):
        SceneCache().acquire("frame-problem")


def _own_render(config) -> tuple:
    """What a renderer with an OpenGL context of its own draws of ``config``'s start."""
    with Renderer(World.from_config(config)) as renderer:
        image = renderer.render(depth=True, segmentation=True)
    return image.rgb, image.depth, image.segmentation


def test_scenes_sharing_one_gl_context_draw_what_their_own_contexts_draw():
    """Two scenes of different sizes and cones drawn in turn in the cache's one OpenGL
    context (each renderer's off-screen buffer bound before it draws), then a third after the
    first is dropped: every image equals, pixel for pixel, a renderer's with a context of its
    own."""
    configs = [
        SceneConfig(camera=CameraConfig(width=320, height=240), cones_w=((6.0, 0.5, 0.0),)),
        SceneConfig(
            camera=CameraConfig(width=200, height=160, pitch_down_deg=15.0),
            cones_w=((4.0, -1.0, 0.0), (7.0, 1.5, 0.0)),
        ),
        SceneConfig(camera=CameraConfig(width=160, height=120), cones_w=((3.0, 0.0, 0.0),)),
    ]
    expected = [_own_render(c) for c in configs]
    with SceneCache(capacity=2) as scenes:
        renderers = [scenes.acquire(c)[1] for c in configs[:2]]
        for i in (0, 1, 0, 1):  # the second renderer was made last: its buffer was bound
            image = renderers[i].render(depth=True, segmentation=True)
            for got, want in zip(
                (image.rgb, image.depth, image.segmentation), expected[i], strict=True
            ):
                np.testing.assert_array_equal(got, want)
        image = scenes.acquire(configs[2])[1].render(depth=True, segmentation=True)
        assert len(scenes) == 2 and scenes.builds == 3
        for got, want in zip(
            (image.rgb, image.depth, image.segmentation), expected[2], strict=True
        ):
            np.testing.assert_array_equal(got, want)
