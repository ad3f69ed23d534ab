"""Test-wide settings and the fixtures shared by several test files.

MuJoCo renders off-screen: choose EGL before anything imports mujoco (sim.gl does the same
when MUJOCO_GL is unset and there is no display). Under CI (CI=true) Hypothesis runs
derandomized, so a CI run is repeatable; locally it explores new examples each run.

Helpers (samplers, strategies, rendering, reading recordings) live in ``tests/helpers.py``.
"""

import os

from hypothesis import settings

os.environ.setdefault("MUJOCO_GL", "egl")

settings.register_profile("ci", derandomize=True, deadline=None)
if os.environ.get("CI"):
    settings.load_profile("ci")


import dataclasses  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from helpers import (  # noqa: E402
    BUILTIN_TEST_RATE_HZ,
    REFERENCE_SEED,
    BuiltinRun,
    render_one_view,
)


@pytest.fixture
def rng() -> np.random.Generator:
    """The seeded generator of the reference tests (a fresh one per test)."""
    return np.random.default_rng(REFERENCE_SEED)


@pytest.fixture(scope="session")
def builtin_runs(tmp_path_factory):
    """Every built-in scenario, run once per session with its recording and report written."""
    from scenarios import pipeline
    from scenarios.scenario import builtin

    out = tmp_path_factory.mktemp("builtin-runs")
    runs = {}
    for name in builtin.names():
        spec = dataclasses.replace(builtin.load(name), camera_rate_hz=BUILTIN_TEST_RATE_HZ)
        o = pipeline.run(spec, seed=3, out_dir=out)
        runs[name] = BuiltinRun(spec, o.result, o.judged, o.report, o.rrd_path, o.json_path)
    return runs


@pytest.fixture(scope="session")
def runs(builtin_runs):
    """``builtin_runs`` as ``{name: (spec, result, judged, report)}``."""
    return {n: (r.spec, r.result, r.judged, r.report) for n, r in builtin_runs.items()}


@pytest.fixture(scope="session")
def one_view() -> dict:
    """One rendered view of one cone (``helpers.render_one_view``), rendered once."""
    return render_one_view()
