"""Test-wide settings and the fixtures shared by several test files.

MuJoCo renders off-screen: choose EGL before anything imports mujoco (sim.gl does the same
when MUJOCO_GL is unset and there is no display). Under CI (CI=true) Hypothesis runs
derandomized, so a CI run is repeatable; locally it explores new examples each run.

Helpers (samplers, strategies, rendering, reading recordings) live in ``tests/helpers.py``.

The suite runs on two processes (pytest-xdist, ``-n 2`` in pyproject.toml's ``addopts``; ``-n 0``
runs it in this one): the end of this file says which tests share a process, and starts the
longest first.
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

pytest_plugins = ["pytester"]  # tests/test_grading.py runs pytest sessions of its own


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


# ------------------------------------------------------------------ running on two processes
#
# pyproject.toml's addopts run the suite on two processes: ``-n 2 --dist loadscope``, with the
# scopes (the units of work a process takes whole) defined here rather than by module:
#
# - the tests that read a costly shared fixture form one unit, so that one process computes it
#   once (``SHARED``); each is named by its node id, because the process that hands out the
#   units sees node ids only; ``pytest_collection_modifyitems`` checks the lists against the
#   fixtures the tests actually request;
# - the modules of long, independent tests (scenario runs through the command line,
#   subprocesses, Ray) are spread over both processes test by test (``SPLIT_MODULES``);
# - any other module is one unit (its module fixtures computed once).
#
# The longest units start first (``LONGEST_FIRST``, measured with ``--durations``), the rest
# in collection order (``--no-loadscope-reorder``), so that neither process is left with a long
# test at the end. pytest-xdist's own ``--dist loadgroup`` would do the grouping from marks,
# but cannot with pytest 9.2 (pytest-xdist #1386 on GitHub: the groups are silently dropped).

SHARED = {
    "builtin_runs": (
        "builtin-runs",
        (
            "tests/test_builtin.py::",
            "tests/test_recording.py::",
            "tests/test_report.py::",
            "tests/test_recording_outcome.py::",
            "tests/test_recording_views.py::",
            "tests/test_recording_navigation.py::",
            "tests/test_recording_imu.py::",
            "tests/test_calibrate_command.py::test_calibrate_a_recording_recovers_",
            "tests/test_calibrate_command.py::test_recording_inputs_are_the_runs",
            "tests/test_calibrate_command.py::test_in_run_calibration_meets_",
            "tests/test_calibrate_command.py::test_calibrate_refuses_what_it_cannot_use",
            "tests/test_calibrate_imu_command.py::test_the_imu_builtin_recording",
            "tests/test_multiview.py::test_pnp_trajectory_of_the_calibration_builtin_",
            "tests/test_covariance.py::test_uncertainty_builtin_covariance_grows_",
            "tests/test_diagnose.py::test_builtin_",
            "tests/test_navigation.py::test_builtin_",
            "tests/test_grading.py::test_vnav_estimator_adds_one_test_per_builtin_with_",
        ),
    ),
    "first_run": (
        "readme-first-run",
        (
            "tests/test_readme.py::test_first_command_writes_",
            "tests/test_readme.py::test_viewer_command_opens_the_file_",
            "tests/test_readme.py::test_serve_web_command_serves_the_recording_",
        ),
    ),
}
"""Costly fixture: (its unit, the node id prefixes of the tests that request it)."""

SPLIT_MODULES = (
    "tests/test_cli.py",
    "tests/test_grading.py",
    "tests/test_readme.py",
    "tests/test_sweep.py",
)
"""Modules spread test by test; their module fixtures are session-scoped (test_sweep's sweep,
test_grading's judge, once per process) or ``SHARED``."""

LONGEST_FIRST = (
    "tests/test_readme.py::test_vnav_demo_commands_run_in_order",
    "tests/test_sweep.py::test_an_existing_cluster_gives_the_serial_rows",
    "tests/test_readme.py::test_sweep_commands_run",
    "builtin-runs",
    "tests/test_outputs.py",
    "tests/test_calibrate_command.py",
    "tests/test_imu_calibration_run.py",
    "tests/test_calibrate_imu_command.py",
    "tests/test_plugin_mistakes.py",
    "tests/test_sweep.py::test_resume_after_an_interruption_runs_only_the_missing_episodes",
    "tests/test_readme.py::test_avoid_sweep_shows_what_the_readme_says",
    "tests/test_sweep.py::test_on_ray_an_episode_that_raises_or_kills_its_worker_costs_",
    "tests/test_sweep.py::test_ray_engine_reuses_each_workers_scene",
    "tests/test_sweep.py::test_ray_workers_give_the_serial_rows",
    "tests/test_readme.py::test_vnav_demo_command_on_its_own",
    "tests/test_readme.py::test_the_walk_through_finds_the_mistake_and_the_fix_passes",
    "tests/test_grading.py::test_a_calibrated_runs_verdict_is_what_vnav_demo_run_reports",
    "tests/test_sweep.py::test_a_killed_worker_costs_no_episode",
    "tests/test_localize.py",
    "tests/test_cli.py::test_progress_bar_only_on_a_terminal",
)
"""Units (node id prefixes) that start first, longest first."""


def _unit(nodeid: str) -> str:
    """The unit of work ``nodeid`` belongs to (see above)."""
    for unit, prefixes in SHARED.values():
        if nodeid.startswith(prefixes):
            return unit
    module = nodeid.split("::", 1)[0]
    return nodeid if module in SPLIT_MODULES else module


def _rank(nodeid: str) -> int:
    unit = _unit(nodeid)
    starts = [i for i, p in enumerate(LONGEST_FIRST) if nodeid.startswith(p) or unit == p]
    return starts[0] if starts else len(LONGEST_FIRST)


def pytest_collection_modifyitems(config, items):
    """Check ``SHARED`` against the fixtures requested; put the longest units first (stable:
    the rest keep the collection order)."""
    for item in items:
        for fixture, (unit, _) in SHARED.items():
            if fixture in item.fixturenames and _unit(item.nodeid) != unit:
                raise pytest.UsageError(
                    f"{item.nodeid} requests {fixture}: add it to SHARED in tests/conftest.py "
                    "(else each test process computes the fixture)"
                )
    items.sort(key=lambda item: _rank(item.nodeid))


@pytest.hookimpl(optionalhook=True)  # a hook of pytest-xdist's
def pytest_xdist_make_scheduler(config, log):
    """``--dist loadscope`` with the units above as its scopes."""
    if config.getvalue("dist") != "loadscope":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class UnitScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return _unit(nodeid)

    return UnitScheduling(config, log)
