"""sim.scene_cache: a scene reused across runs gives the same run as a freshly built one."""

from __future__ import annotations

import dataclasses

import pytest

from scenarios import pipeline
from scenarios.scenario import builtin
from sim.scene_cache import SceneCache


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
