"""A user's function judged on a scenario as ``vnav-demo run NAME --estimator SPEC`` judges it,
with the flight run once however many functions are judged.

``vnav-demo run`` calls a user's function at every detection while the scenario flies. A test
that judges ten functions would fly, render and detect ten times for nothing: the function
changes none of that. Here a scenario is run once per (scenario, seed, duration)
(``RunCache``), with a stand-in user method that only keeps what a function is given: each
detection's ``vnav.plugin.PluginObservation``, or the reason the function would not be
called (``StoredRun``). Judging a function (``judge_function``) then calls it on those
observations in the run's order, puts its estimates in a copy of the run's records with their
errors against the truth (``scenarios.run.evaluate.with_method``, the comparison every method
gets), and judges the copy with the checks ``scenarios.pipeline.judge`` gives a run. The
stored run is never changed. A scenario that checks its calibration also keeps what the
function is given on the ticks estimated again with the recovered mount, so that the function
is called there too, as in a run.

The ``Verdict`` holds every check, the function's errors per detection, its failures and the
frame-bug doctor's diagnosis (``vnav.diagnose``); ``Verdict.explain()`` says it for a student.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from scenarios import pipeline
from scenarios.judge import report
from scenarios.judge.checks import CHAIN, CheckResult
from scenarios.run.evaluate import with_method
from scenarios.run.records import RunResult, TickRecord
from scenarios.run.runner import run_scenario
from scenarios.scenario import builtin
from scenarios.scenario.spec import MAX_SEED, ScenarioSpec, load_toml
from vnav.diagnose import Diagnosis
from vnav.estimators import NoEstimate
from vnav.methods import Method, extended, method
from vnav.observation import Observation
from vnav.plugin import (
    USER_PREFIX,
    Failure,
    Failures,
    PluginEstimator,
    PluginObservation,
    function_method,
    load_estimator,
    observation_for,
    second_pass_methods,
)

__all__ = [
    "ErrorAt",
    "FunctionFailure",
    "Judge",
    "RunCache",
    "StoredRun",
    "Verdict",
    "judge_function",
    "judged_builtins",
    "scenario_spec",
    "store_run",
]

STAND_IN = f"{USER_PREFIX}stored-observations"
"""The stand-in method's name in a stored run (never a function's: a function's name is an
identifier)."""

Given = tuple[tuple[PluginObservation | None, ...], ...]
"""Per tick, per detection: what a function is given there, or None where it is not called."""


class _Keeper:
    """The stand-in method's estimator: keeps each detection's ``PluginObservation`` (by the
    detection object, which the run's records hold) and gives no estimate. ``phase`` says
    whether the run flies (``"flight"``) or estimates again with a recovered mount
    (``"recovered"``)."""

    def __init__(self) -> None:
        self.phase = "flight"
        self.given: dict[str, dict[int, PluginObservation]] = {"flight": {}, "recovered": {}}
        self.failures = Failures()

    def reset(self) -> None:
        """Nothing to forget: a keeper serves one run."""

    def second_pass(self) -> _Keeper:
        """The keeper itself: what the second pass is given is kept by ``phase``."""
        return self

    def diagnosis(self) -> None:
        return None

    def estimate(
        self,
        obs: Observation,
        p_w_depth: np.ndarray,
        t_s: float,
        T_w_b_newest: np.ndarray | None = None,
    ) -> NoEstimate:
        kept = self.given[self.phase]
        kept.setdefault(id(obs.view.detection), observation_for(obs, p_w_depth, t_s, T_w_b_newest))
        return NoEstimate.FUNCTION_NONE

    def covariance(self, obs: Observation, p_w: np.ndarray) -> np.ndarray:
        return np.zeros((3, 3))  # never asked: no estimate is given


def _stand_in(keeper: _Keeper) -> Method:
    m = Method(
        STAND_IN,
        "what a user's function is given, kept",
        (255, 255, 255),
        "white",
        method("depth_image").bound,
        "scenarios.grading.verdict:_Keeper",
        images="user",
    )
    m.__dict__["estimator"] = keeper  # as vnav.plugin.plugin_method gives a function's
    return m


@dataclass(frozen=True)
class StoredRun:
    """One flight of a scenario and what a user's function would be given in it.

    Attributes
    ----------
    spec : ScenarioSpec
    seed : int
    result : RunResult
        The run (calibrated if its checks ask), its records holding the stand-in method
        ``STAND_IN``: ``no_estimate[STAND_IN]`` is why a function gets nothing there
        (``FUNCTION_NONE`` where it is called). Not to be changed.
    given : Given
        What a function is given at each detection of ``result.ticks``.
    given_recovered : Given or None
        The same on the ticks estimated again with the recovered mount
        (``CalibrationRecord.ticks_recovered``), or None.
    """

    spec: ScenarioSpec
    seed: int
    result: RunResult
    given: Given
    given_recovered: Given | None


def _given(ticks: list[TickRecord], kept: dict[int, PluginObservation]) -> Given:
    return tuple(tuple(kept.get(id(d.detection)) for d in t.detections) for t in ticks)


def store_run(spec: ScenarioSpec, seed: int) -> StoredRun:
    """Fly ``spec`` once, as ``scenarios.pipeline.run`` does (and calibrate it if its checks
    ask), keeping what a user's function is given at each detection.

    Raises
    ------
    sim.world.SimulationError
        If the flight diverges.
    """
    keeper = _Keeper()
    with extended([_stand_in(keeper)]):
        result = run_scenario(spec, seed=seed)
        if spec.checks_calibration:
            from scenarios.judge.calibration import calibrate_run

            keeper.phase = "recovered"
            result.calibration = calibrate_run(result)
    given = _given(result.ticks, keeper.given["flight"])
    recovered = None if result.calibration is None else result.calibration.ticks_recovered
    given_recovered = None if recovered is None else _given(recovered, keeper.given["recovered"])
    return StoredRun(spec, seed, result, given, given_recovered)


# ------------------------------------------------------------------------------ verdict


@dataclass(frozen=True)
class ErrorAt:
    """The function's estimate of one matched detection, against the truth and against the
    correct chain on the inputs the function was given.

    Attributes
    ----------
    tick : int
        The camera tick.
    t_s : float
        The image's exposure stamp, seconds (the ``t_s`` the function was given).
    cone : int
        The true cone it was matched to.
    error_m : float
        Distance of the estimate from that cone, metres.
    range_m : float
        Distance of the cone from the camera, metres.
    allowed_m : float
        The accuracy bound at that range (``depth_image``'s, ``vnav.methods``), metres.
    in_contract : bool
        Whether the detection is in the contract's domain, where the bound is judged against
        the truth.
    chain_m : float
        Distance of the estimate from the correct chain's on the same inputs (the
        ``depth_image`` estimate, ``vnav.plugin.reference_estimate``), metres: what the
        ``chain_agreement`` check judges, at every matched detection.
    """

    tick: int
    t_s: float
    cone: int
    error_m: float
    range_m: float
    allowed_m: float
    in_contract: bool
    chain_m: float

    @property
    def ratio(self) -> float:
        """The error over the bound (1: at the bound)."""
        return self.error_m / self.allowed_m

    @property
    def chain_ratio(self) -> float:
        """The distance from the correct chain's estimate over the bound (1: at the bound)."""
        return self.chain_m / self.allowed_m


@dataclass(frozen=True)
class FunctionFailure:
    """One kind of failure of the function (``vnav.plugin.Failure``) over the run.

    Attributes
    ----------
    kind : Failure
    count : int
    first_message : str
    stamps_s : tuple of float
        The exposure stamps of the images it failed on, seconds.
    """

    kind: Failure
    count: int
    first_message: str
    stamps_s: tuple[float, ...]


@dataclass(frozen=True)
class Verdict:
    """A user's function judged on one scenario: what ``vnav-demo run --estimator`` reports.

    Attributes
    ----------
    function : str
        The method's name, ``user:<function>``.
    scenario : str
    seed : int
    duration_s : float
        The run's length, seconds.
    passed : bool
        Whether every check passed (the run's exit status 0).
    checks : tuple of CheckResult
        Every check, the scenario's then the function's own (``own_checks``;
        ``CheckResult.shown`` gives the figure against its limit).
    errors : tuple of ErrorAt
        The function's estimate at each matched detection, in the run's order.
    calls, returned_none : int
        How many times the function was called, and returned None (no estimate).
    failures : tuple of FunctionFailure
        How it failed, by kind (empty when it never did).
    diagnosis : vnav.diagnose.Diagnosis or None
        The frame-bug doctor on its estimates; None without any.
    report : dict
        The JSON report ``vnav-demo run`` writes (without ``recording``).
    """

    function: str
    scenario: str
    seed: int
    duration_s: float
    passed: bool
    # The long fields stay out of the repr (pytest prints it under a failed assert).
    checks: tuple[CheckResult, ...] = field(repr=False)
    errors: tuple[ErrorAt, ...] = field(repr=False)
    calls: int
    returned_none: int
    failures: tuple[FunctionFailure, ...] = field(repr=False)
    diagnosis: Diagnosis | None = field(repr=False)
    report: dict[str, Any] = field(repr=False, compare=False)

    @property
    def own_checks(self) -> tuple[CheckResult, ...]:
        """The function's own checks (``scenarios.scenario.check_kinds.user_checks``): its
        agreement with the correct chain (``chain_agreement``), then, where the scenario holds
        ``depth_image`` to it, the accuracy bound against the truth (``error_bound``)."""
        return tuple(c for c in self.checks if c.name.startswith(f"{self.function} "))

    @property
    def check(self) -> CheckResult:
        """The function's check every scenario has: its agreement with the correct chain."""
        return next(c for c in self.own_checks if c.kind == "chain_agreement")

    @property
    def farthest_from_chain(self) -> ErrorAt | None:
        """The estimate farthest from the correct chain's for its bound; None without any."""
        return max(self.errors, key=lambda e: e.chain_ratio, default=None)

    @property
    def max_error_m(self) -> float | None:
        """The largest error of the function over the matched detections, metres."""
        return max((e.error_m for e in self.errors), default=None)

    @property
    def worst(self) -> ErrorAt | None:
        """The estimate farthest beyond its bound where the bound is judged (in the contract's
        domain), else the largest error; None without any."""
        judged = [e for e in self.errors if e.in_contract]
        if judged:
            return max(judged, key=lambda e: e.ratio)
        return max(self.errors, key=lambda e: e.error_m, default=None)

    def explain(self) -> str:
        """What a student needs: the checks that failed and by how much, the estimate farthest
        from the correct chain and the worst error and when, what the frame-bug doctor found,
        how the function failed."""
        status = "PASSED" if self.passed else "FAILED"
        lines = [
            f"{self.function} on {self.scenario} (seed {self.seed}, {self.duration_s:g} s): "
            f"{status}"
        ]
        lines += [_check_line(c, c.name.startswith(f"{self.function} ")) for c in self.checks]
        worst, farthest = self.worst, self.farthest_from_chain
        if worst is not None and farthest is not None:
            lines.append(
                f"farthest from the correct chain: {_m(farthest.chain_m)} at t = "
                f"{farthest.t_s:.3f} s ({_where(farthest)}): {farthest.chain_ratio:.3g}x the bound"
            )
            judged = any(c.kind == "error_bound" for c in self.own_checks)
            lines.append(
                f"worst error against the truth: {_m(worst.error_m)} at t = {worst.t_s:.3f} s "
                f"({_where(worst)}): {worst.ratio:.3g}x the bound"
                + ("" if worst.in_contract else " (outside the contract's domain)")
                + (
                    ""
                    if judged
                    else " (not a check here: the scenario does not hold depth_image to it)"
                )
            )
            lines.append(
                f"  {len(self.errors)} estimates of matched cones, "
                f"{sum(e.in_contract for e in self.errors)} in the contract's domain; "
                f"largest error {_m(self.max_error_m or 0.0)}"
            )
        elif not self.failures:
            lines.append("no estimate of a matched cone to compare with the truth")
        lines.append(
            "frame-bug doctor: "
            + ("no estimate to diagnose" if self.diagnosis is None else self.diagnosis.message)
        )
        if self.failures:
            lines.append(f"your function failed ({self.calls} calls):")
            for f in self.failures:
                stamps = ", ".join(f"{t:.3f}" for t in f.stamps_s[:5])
                more = f" and {len(f.stamps_s) - 5} more" if len(f.stamps_s) > 5 else ""
                lines.append(
                    f"  {f.kind.value.replace('_', ' ')} {f.count}x, first: {f.first_message} "
                    f"(at t = {stamps}{more} s)"
                )
        if self.returned_none:
            lines.append(f"it returned None (no estimate) {self.returned_none} of {self.calls}x")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.explain()


def _m(x: float) -> str:
    return f"{x:.3g} m"


def _where(e: ErrorAt) -> str:
    return f"tick {e.tick}, cone {e.cone}, range {_m(e.range_m)}, bound {_m(e.allowed_m)}"


def _check_line(c: CheckResult, yours: bool) -> str:
    who = "  (your function)" if yours else ""
    return f"  {c.outcome.value.upper():<8} {c.name}: {c.shown}{who}"


def _filled(ticks: list[TickRecord], given: Given, user: Method, cones_w: np.ndarray) -> list:
    """``ticks`` with the function's estimate at each detection in place of the stand-in's,
    the function called in the run's order (new records; ``ticks`` are left as they were)."""
    estimator: PluginEstimator = user.estimator
    out = []
    for t, given_t in zip(ticks, given, strict=True):
        records = []
        for d, g in zip(t.detections, given_t, strict=True):
            estimate = d.no_estimate[STAND_IN] if g is None else estimator.estimate_given(g)
            cov_w = None if isinstance(estimate, NoEstimate) else np.zeros((3, 3))
            records.append(with_method(d, user.name, estimate, cov_w, cones_w, drop=STAND_IN))
        out.append(dataclasses.replace(t, detections=records))
    return out


def judge_function(
    stored: StoredRun, fn: Callable[[PluginObservation], Any], spec: str, name: str
) -> Verdict:
    """``fn`` judged on ``stored`` as ``vnav-demo run --estimator`` judges it in that run.

    Parameters
    ----------
    stored : StoredRun
    fn : callable
        ``fn(obs: PluginObservation) -> p_w`` (``vnav.plugin``).
    spec : str
        Where it came from (the report's ``estimators.<name>.spec``).
    name : str
        Its name: the method is ``user:<name>``.
    """
    user = function_method(fn, spec, name)
    run = stored.result
    ticks = _filled(run.ticks, stored.given, user, run.cones_w)
    calibration = run.calibration
    if calibration is not None and stored.given_recovered is not None:
        assert calibration.ticks_recovered is not None
        # As in the run: the recovered mount's pass calls the function through a second
        # estimator of its own (``PluginEstimator.second_pass``), its tallies kept apart.
        (again,) = second_pass_methods((user,))
        recovered = _filled(calibration.ticks_recovered, stored.given_recovered, again, run.cones_w)
        calibration = dataclasses.replace(calibration, ticks_recovered=recovered)
    result = dataclasses.replace(
        run, ticks=ticks, timing_s=dict(run.timing_s), calibration=calibration
    )
    with extended([user]):
        judged = pipeline.judge(stored.spec, result)
        rep = report.build(result, judged)
    return _verdict(stored, user, result, judged, rep)


def _verdict(
    stored: StoredRun, user: Method, result: RunResult, judged: list[CheckResult], rep: dict
) -> Verdict:
    bound = user.bound
    assert bound is not None
    errors = tuple(
        ErrorAt(
            t.tick,
            g.t_s,
            d.cone_index,
            d.errors_m[user.name],
            d.range_m,
            float(bound.allowed_m(d.range_m)),
            d.in_contract,
            float(np.linalg.norm(d.estimates_w[user.name] - d.estimates_w[CHAIN])),
        )
        for t, given_t in zip(result.ticks, stored.given, strict=True)
        for d, g in zip(t.detections, given_t, strict=True)
        if user.name in d.errors_m and g is not None and d.range_m is not None
    )
    estimator: PluginEstimator = user.estimator
    f = estimator.failures
    failures = tuple(
        FunctionFailure(kind, f.count[kind], f.first_message[kind], tuple(f.stamps_s[kind]))
        for kind in f.count
    )
    return Verdict(
        function=user.name,
        scenario=stored.spec.name,
        seed=stored.seed,
        duration_s=stored.spec.end_s,
        passed=bool(rep["passed"]),
        checks=tuple(judged),
        errors=errors,
        calls=f.calls,
        returned_none=f.returned_none,
        failures=failures,
        diagnosis=estimator.diagnosis(),
        report=rep,
    )


# ----------------------------------------------------------------------------- the cache


def _is_file(scenario: str | Path) -> bool:
    text = str(scenario)
    return isinstance(scenario, Path) or text.endswith(".toml") or "/" in text


def scenario_spec(scenario: str | Path, duration_s: float | None = None) -> ScenarioSpec:
    """The scenario a name or a file names, as ``vnav-demo run`` reads it: a bare name is a
    built-in, a path (a ``/`` or a ``.toml`` suffix, or a ``Path``) a file; ``duration_s``
    shortens it (``--duration``: never beyond its own end).

    Raises
    ------
    ValueError
        For an unknown name, a file that is no valid scenario (``ScenarioError``), or a
        duration that is not a positive number of seconds.
    """
    text = str(scenario)
    spec = load_toml(text) if _is_file(scenario) else builtin.load(text)
    if duration_s is None:
        return spec
    if isinstance(duration_s, bool) or not (
        isinstance(duration_s, int | float) and math.isfinite(duration_s) and duration_s > 0
    ):
        raise ValueError(f"duration_s must be a positive number of seconds, got {duration_s!r}")
    return dataclasses.replace(spec, duration_s=min(float(duration_s), spec.end_s))


def judged_builtins() -> list[str]:
    """The built-ins a user's function can be judged on, in teaching order: those with a cone
    to detect (a run adds the function's checks to any scenario's,
    ``check_kinds.user_checks``). Read from the specs; nothing is run."""
    return [name for name in builtin.names() if builtin.load(name).scene.cones_w]


class RunCache:
    """Stored runs by (scenario, seed, duration): each flown once (``store_run``).

    Attributes
    ----------
    flights : int
        How many flights were run (one per key asked for).
    """

    def __init__(self) -> None:
        self._runs: dict[tuple[str, int, float], StoredRun] = {}
        self.flights = 0

    def get(self, scenario: str | Path, seed: int, duration_s: float | None = None) -> StoredRun:
        """The stored run of ``scenario`` (``scenario_spec``) with ``seed``, flown now if it
        was not yet.

        Raises
        ------
        ValueError
            As ``scenario_spec``, or for a seed outside [0, 2**63 - 1].
        """
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
            raise ValueError(f"seed must be an integer in [0, 2**63 - 1], got {seed!r}")
        spec = scenario_spec(scenario, duration_s)
        where = str(Path(scenario).resolve()) if _is_file(scenario) else str(scenario)
        key = (where, seed, spec.end_s)
        if key not in self._runs:
            self._runs[key] = store_run(spec, seed)
            self.flights += 1
        return self._runs[key]


class Judge:
    """``judge(fn, scenario="frame-problem", seed=1, duration_s=None) -> Verdict``: a user's
    function judged on a scenario, its flight taken from ``cache`` (the pytest fixture
    ``vnav_judge``, ``scenarios.grading.pytest_plugin``)."""

    def __init__(self, cache: RunCache | None = None) -> None:
        self.cache = RunCache() if cache is None else cache

    @property
    def flights(self) -> int:
        """How many flights the cache has run."""
        return self.cache.flights

    def __call__(
        self,
        fn: Callable[[PluginObservation], Any] | str,
        scenario: str | Path = "frame-problem",
        seed: int = 1,
        duration_s: float | None = None,
    ) -> Verdict:
        """Judge ``fn`` (a callable, or a SPEC ``package.module:function`` or
        ``path/to/file.py:function``) on ``scenario`` (a built-in's name or a TOML file).

        Raises
        ------
        ValueError
            For a SPEC that does not load (``vnav.plugin.load_estimator``), an ``fn`` that is
            neither a callable nor a string, or a bad scenario, seed or duration
            (``RunCache.get``).
        """
        if isinstance(fn, str):
            spec_text, function = fn, load_estimator(fn)
            name = getattr(function, "__name__", None) or fn.rpartition(":")[2]
        elif callable(fn):
            function = fn
            name = getattr(fn, "__name__", None) or type(fn).__name__
            spec_text = f"{getattr(fn, '__module__', None) or '?'}:{name}"
        else:
            raise ValueError(
                f"fn must be a function fn(obs) -> p_w or a SPEC string "
                f"(package.module:function or path/to/file.py:function), got {fn!r}"
            )
        stored = self.cache.get(scenario, seed, duration_s)
        return judge_function(stored, function, spec_text, name)
