"""Test-wide settings and the fixtures shared by several test files.

MuJoCo renders off-screen: choose EGL before anything imports mujoco (sim.gl does the same
when MUJOCO_GL is unset and there is no display). Under CI (CI=true) Hypothesis runs
derandomized, so a CI run is repeatable; locally it explores new examples each run.

Helpers (samplers, strategies, rendering, reading recordings) live in ``tests/helpers.py``.

The suite runs on two processes (pytest-xdist, ``-n 2 --dist loadgroup`` in pyproject.toml's
``addopts``); ``pytest_collection_modifyitems`` below says which tests must share a process,
and starts the longest first.
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
    from scenarios import builtin, pipeline

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

SHARED_FIXTURE_GROUPS = {"builtin_runs": "builtin-runs"}
"""Session fixtures costly enough that every test reading them runs in one process, which
computes them once (fixture name: xdist group). Module fixtures need nothing here: a module's
tests stay together (``_group``)."""

SPLIT_MODULES = ("tests/test_cli.py", "tests/test_readme.py", "tests/test_sweep.py")
"""Modules of long, independent tests (subprocesses, scenario runs, Ray), spread over both
processes test by test. Their module fixtures are computed once per process: session-scoped
(test_sweep's sweep) or grouped here (test_readme's first command)."""

SPLIT_MODULE_FIXTURE_GROUPS = {"first_run": "readme-first-run"}

LONGEST_FIRST = (
    "tests/test_readme.py::test_vnav_demo_commands_run_in_order",
    "tests/test_sweep.py::test_an_existing_cluster_gives_the_serial_rows",
    "builtin-runs",
    "tests/test_readme.py::test_sweep_commands_run",
    "tests/test_sweep.py::test_resume_after_an_interruption_runs_only_the_missing_episodes",
    "tests/test_sweep.py::test_ray_workers_give_the_serial_rows",
    "tests/test_sweep.py::test_ray_engine_reuses_each_workers_scene",
)
"""Tests (node id prefixes) and groups that take longest, in the order they start: the rest
fills the other process around them (measured with ``--durations``)."""


def _group(item: pytest.Item) -> str | None:
    """The xdist group of ``item``: a shared session fixture's, else its module's, except in
    ``SPLIT_MODULES`` (none, or a module fixture's)."""
    for fixture, group in SHARED_FIXTURE_GROUPS.items():
        if fixture in item.fixturenames:
            return group
    module = item.nodeid.split("::", 1)[0]
    if module not in SPLIT_MODULES:
        return module
    for fixture, group in SPLIT_MODULE_FIXTURE_GROUPS.items():
        if fixture in item.fixturenames:
            return group
    return None


@pytest.hookimpl(tryfirst=True)  # before xdist reads the groups
def pytest_collection_modifyitems(config, items):
    """Group the tests that share a costly fixture (``--dist loadgroup`` runs a group in one
    process), and put the longest first (stable: the rest keep the collection order)."""
    rank = {}
    for item in items:
        group = _group(item)
        if group is not None:
            item.add_marker(pytest.mark.xdist_group(group))
        keys = (item.nodeid, group or "")
        rank[item] = next(
            (i for i, p in enumerate(LONGEST_FIRST) for k in keys if k.startswith(p)),
            len(LONGEST_FIRST),
        )
    items.sort(key=rank.__getitem__)
