"""The pytest plugin of vnav-sim: judge your own estimator from a test.

Installing vnav-sim registers it (the ``pytest11`` entry point ``vnav`` in pyproject.toml); it
offers:

- the fixture ``vnav_judge``: ``verdict = vnav_judge(fn, scenario="frame-problem", seed=1)``
  judges ``fn`` (a function ``fn(obs) -> p_w``, or a SPEC ``package.module:function`` or
  ``path/to/file.py:function``) on a built-in scenario or a TOML file, optionally shortened
  (``duration_s``), as ``vnav-demo run NAME --estimator SPEC`` judges it, and returns a
  ``scenarios.grading.verdict.Verdict``: ``assert verdict.passed, verdict.explain()``;
- the option ``--vnav-estimator SPEC`` (repeatable): one test per SPEC and built-in scenario
  with a cone, failing with the verdict's explanation; ``--vnav-seed`` (1) and
  ``--vnav-duration`` (each built-in's own) set their runs.

Each (scenario, seed, duration) is flown once per pytest session (process), however many
functions are judged on it: the flight, the images and the detections are kept, and judging a
function only calls it on each kept detection and judges again (``verdict.RunCache``).

Nothing heavy is imported until a run is needed: a test session that uses none of this pays
for none of it.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

if TYPE_CHECKING:
    from scenarios.grading.verdict import Judge, Verdict

__all__ = ["VerdictError", "pytest_addoption", "vnav_judge"]

_JUDGE = pytest.StashKey["Judge"]()


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("vnav", "vnav-sim: judge your own estimator")
    group.addoption(
        "--vnav-estimator",
        action="append",
        default=[],
        metavar="SPEC",
        help="judge the function SPEC (package.module:function or path/to/file.py:function) "
        "on every built-in scenario with a cone: one test each (repeatable)",
    )
    group.addoption(
        "--vnav-seed",
        type=int,
        default=1,
        metavar="SEED",
        help="the seed of --vnav-estimator's runs (default 1, as vnav-demo run's)",
    )
    group.addoption(
        "--vnav-duration",
        type=float,
        default=None,
        metavar="SECONDS",
        help="shorten --vnav-estimator's runs to at most this (default: each scenario's own)",
    )


def _judge(config: pytest.Config) -> Judge:
    """The session's judge, made on first use (its runs cached for the whole session)."""
    judge = config.stash.get(_JUDGE, None)
    if judge is None:
        from scenarios.grading.verdict import Judge

        judge = config.stash[_JUDGE] = Judge()
    return judge


def pytest_configure(config: pytest.Config) -> None:
    """Refuse a ``--vnav-estimator`` that does not load before anything runs (as
    ``vnav-demo run --estimator`` does), and a duration that is not positive."""
    specs = config.getoption("vnav_estimator", default=[])
    if not specs:
        return
    from vnav.plugin import load_estimator

    for spec in specs:
        try:
            load_estimator(spec)
        except ValueError as exc:
            raise pytest.UsageError(f"--vnav-estimator: {exc}") from None
    duration_s = config.getoption("vnav_duration")
    if duration_s is not None and not duration_s > 0.0:
        raise pytest.UsageError(f"--vnav-duration must be > 0 seconds, got {duration_s:g}")


@pytest.fixture(scope="session")
def vnav_judge(pytestconfig: pytest.Config) -> Judge:
    """``vnav_judge(fn, scenario="frame-problem", seed=1, duration_s=None) -> Verdict``: your
    function judged on a scenario as ``vnav-demo run --estimator`` judges it; each scenario
    flown once per session (``scenarios.grading.verdict.Judge``)."""
    return _judge(pytestconfig)


class VerdictError(Exception):
    """A function's verdict did not pass; the test's report is its explanation."""

    def __init__(self, verdict: Verdict) -> None:
        super().__init__(verdict.explain())
        self.verdict = verdict


class _Estimators(pytest.Collector):
    """The ``--vnav-estimator`` tests: one per SPEC and built-in scenario with a cone (their
    node ids start ``vnav-estimator::``)."""

    def __init__(self, *, specs: list[str], **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.specs = specs

    def collect(self) -> list[pytest.Item]:
        from scenarios.grading.verdict import judged_builtins

        scenarios = judged_builtins()
        return [
            EstimatorItem.from_parent(
                self, name=f"{spec}[{scenario}]", spec=spec, scenario=scenario
            )
            for spec in dict.fromkeys(self.specs)
            for scenario in scenarios
        ]


class EstimatorItem(pytest.Item):
    """One ``--vnav-estimator`` test: a SPEC judged on one built-in scenario."""

    fixturenames: tuple[str, ...] = ()  # it requests none (read by plugins that sort by them)

    def __init__(self, *, spec: str, scenario: str, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.spec, self.scenario = spec, scenario

    def runtest(self) -> None:
        config = self.config
        verdict = _judge(config)(
            self.spec,
            self.scenario,
            seed=config.getoption("vnav_seed"),
            duration_s=config.getoption("vnav_duration"),
        )
        if not verdict.passed:
            raise VerdictError(verdict)

    def repr_failure(self, excinfo: pytest.ExceptionInfo[BaseException], style=None) -> str:
        if isinstance(excinfo.value, VerdictError):
            return excinfo.value.verdict.explain()
        return super().repr_failure(excinfo, style=style)

    def reportinfo(self) -> tuple[Path, int | None, str]:
        return self.path, None, f"{self.spec} on {self.scenario}"


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(
    session: pytest.Session, config: pytest.Config, items: list[pytest.Item]
) -> None:
    """Add the ``--vnav-estimator`` tests, before ``-k`` and ``-m`` select (tryfirst)."""
    specs = config.getoption("vnav_estimator", default=[])
    if not specs:
        return
    parent = _Estimators.from_parent(
        session, name="vnav-estimator", nodeid="vnav-estimator", specs=specs
    )
    # Collected as pytest collects a file (its reports counted and shown), after the others.
    items.extend(session.genitems(parent))
