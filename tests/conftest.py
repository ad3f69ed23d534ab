"""Test-wide settings.

MuJoCo renders off-screen: choose EGL before anything imports mujoco (sim.gl does the same
when MUJOCO_GL is unset and there is no display). Under CI (CI=true) Hypothesis runs
derandomized, so a CI run is repeatable; locally it explores new examples each run.
"""

import os

from hypothesis import settings

os.environ.setdefault("MUJOCO_GL", "egl")

settings.register_profile("ci", derandomize=True, deadline=None)
if os.environ.get("CI"):
    settings.load_profile("ci")


import dataclasses  # noqa: E402

import pytest  # noqa: E402

BUILTIN_TEST_RATE_HZ = 5.0
"""Built-in scenarios run in tests at 5 Hz instead of 10: the same flights, half the frames."""


@dataclasses.dataclass
class BuiltinRun:
    spec: object
    result: object
    judged: list
    report: dict
    rrd: object
    json_path: object


@pytest.fixture(scope="session")
def builtin_runs(tmp_path_factory):
    """Every built-in scenario, run once per session with its recording and report written."""
    from scenarios import builtin, pipeline

    out = tmp_path_factory.mktemp("builtin-runs")
    runs = {}
    for name in builtin.names():
        spec = dataclasses.replace(builtin.load(name), camera_rate_hz=BUILTIN_TEST_RATE_HZ)
        o = pipeline.run(spec, seed=3, out_dir=out)
        runs[name] = BuiltinRun(spec, o.result, o.judged, o.report, o.rrd_path, o.json_path)
    return runs
