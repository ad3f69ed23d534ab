"""Pass/fail checks of a finished run against ground truth.

Each check kind computes one figure from the run's records (``scenarios.records``) and
compares it with the scenario's limit. Kinds are registered where they are defined, with
``@check_kind`` (as dm_control registers its tasks): the registry ``KINDS`` is what the
scenario parser accepts, what ``Check.label`` reads and what the README points to. The accuracy
bounds are those of the perception contract (docs/ACCURACY.md, declared in ``vnav.methods``).
"""

from __future__ import annotations

import operator
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from scenarios.records import RunResult
from vnav.methods import METHODS, method

__all__ = ["KINDS", "Check", "CheckKind", "CheckResult", "check_kind", "default_checks", "judge"]

Figure = Callable[[RunResult, str], float | None]


@dataclass(frozen=True)
class CheckKind:
    """One kind of check: the figure it computes and how that figure meets the limit.

    Attributes
    ----------
    name : str
        The ``kind`` a scenario file gives.
    figure : callable(run, method) -> float or None
        The figure; None when the run holds nothing to judge (the check then fails).
    passes : callable(figure, limit) -> bool
        ``operator.le`` (at most the limit) or ``operator.ge`` (at least).
    uses_method : bool
        Whether the figure depends on the check's ``method``.
    doc : str
        What the check asserts, one line.
    """

    name: str
    figure: Figure
    passes: Callable[[float, float], bool]
    uses_method: bool
    doc: str


KINDS: dict[str, CheckKind] = {}
"""Every check kind, by name, in the order they are defined."""


def check_kind(name: str, passes: Callable, *, uses_method: bool = True) -> Callable:
    """Register the decorated figure as the check kind ``name``; its docstring's first line
    is what the check asserts."""

    def register(figure: Figure) -> Figure:
        doc = (figure.__doc__ or "").strip().splitlines()[0]
        KINDS[name] = CheckKind(name, figure, passes, uses_method, doc)
        return figure

    return register


@dataclass(frozen=True)
class Check:
    """One pass/fail criterion evaluated on a finished run (a kind from ``KINDS``)."""

    kind: str
    limit: float
    method: str = "depth_image"
    name: str = ""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown check {self.kind!r}; valid: {sorted(KINDS)}")
        method(self.method)  # raises ValueError naming the valid methods

    @property
    def label(self) -> str:
        """The check's name, or one made of its method and kind."""
        if self.name:
            return self.name
        return f"{self.method} {self.kind}" if KINDS[self.kind].uses_method else self.kind


@dataclass(frozen=True)
class CheckResult:
    """A check's outcome: its figure (None: nothing to judge), the limit and the verdict."""

    name: str
    kind: str
    value: float | None
    limit: float
    passed: bool

    def as_dict(self) -> dict:
        return {
            "name": self.name,
            "kind": self.kind,
            "value": self.value,
            "limit": self.limit,
            "passed": self.passed,
        }


def judge(check: Check, run: RunResult) -> CheckResult:
    """Compute ``check``'s figure on ``run``; a check with no data to judge fails."""
    kind = KINDS[check.kind]
    value = kind.figure(run, check.method)
    passed = value is not None and bool(kind.passes(value, check.limit))
    return CheckResult(check.label, check.kind, value, check.limit, passed)


def default_checks() -> tuple[Check, ...]:
    """Checks for a scenario that declares none: every method's bound and the detection rate."""
    return (
        *(Check("error_bound", 1.0, m.name, f"{m.name} {m.promise}") for m in METHODS if m.bound),
        Check("detection_rate", 0.95, name="cones in view detected (fraction)"),
    )


# ------------------------------------------------------------------------------ the kinds


def _max(x: np.ndarray) -> float | None:
    return float(np.max(x)) if x.size else None


def _median(x: np.ndarray) -> float | None:
    return float(np.median(x)) if x.size else None


@check_kind("max_error", operator.le)
def _max_error(run: RunResult, method: str) -> float | None:
    """largest position error of ``method`` over all matched detections <= limit_m"""
    return _max(run.errors(method))


@check_kind("median_error", operator.le)
def _median_error(run: RunResult, method: str) -> float | None:
    """median position error of ``method`` <= limit_m"""
    return _median(run.errors(method))


@check_kind("error_bound", operator.le)
def _error_bound(run: RunResult, method_name: str) -> float | None:
    """error / accuracy bound of ``method`` <= limit: worst or median as the bound states,
    over the contract's domain (docs/ACCURACY.md)"""
    bound = method(method_name).bound
    if bound is None:
        return None
    errors = run.errors(method_name, contract_only=True)
    ratio = errors / bound.allowed_m(run.ranges_for(method_name, contract_only=True))
    return _max(ratio) if bound.statistic == "max" else _median(ratio)


@check_kind("detection_rate", operator.ge, uses_method=False)
def _detection_rate(run: RunResult, method: str) -> float | None:
    """detections / cones fully in view (summed over camera ticks) >= limit"""
    seen = detected = 0
    for t in run.ticks:
        matched = {d.cone_index for d in t.detections if d.cone_index is not None}
        seen += len(t.cones_in_view)
        detected += len(set(t.cones_in_view) & matched)
    return detected / seen if seen else None


def _per_cone(run: RunResult, method: str | None) -> dict[int, np.ndarray]:
    """Per matched cone: ``method``'s estimates (world), or with None its true camera coords."""
    out: dict[int, list[np.ndarray]] = {}
    for t in run.ticks:
        for d in t.detections:
            if d.cone_index is None:
                continue
            value = d.p_c_true if method is None else d.estimates_w.get(method)
            if value is not None:
                out.setdefault(d.cone_index, []).append(value)
    return {i: np.array(v) for i, v in out.items()}


@check_kind("world_estimate_spread", operator.le)
def _world_spread(run: RunResult, method: str) -> float | None:
    """largest distance of ``method``'s estimates of a cone from their mean <= limit_m"""
    spreads = [
        float(np.max(np.linalg.norm(p - p.mean(axis=0), axis=1)))
        for p in _per_cone(run, method).values()
    ]
    return max(spreads) if spreads else None


@check_kind("camera_coords_span", operator.ge, uses_method=False)
def _camera_span(run: RunResult, method: str) -> float | None:
    """the cone's camera-frame coordinates move by >= limit_m"""
    spans = [float(np.linalg.norm(np.ptp(p, axis=0))) for p in _per_cone(run, None).values()]
    return max(spans) if spans else None


@check_kind("naive_worse", operator.ge)
def _naive_worse(run: RunResult, method: str) -> float | None:
    """median naive error >= limit x the median error of ``method``"""
    naive, ref = _median(run.errors("naive")), _median(run.errors(method))
    if naive is None or ref is None:
        return None
    return naive / max(ref, 1e-6)


@check_kind("gimbal_lock_seen", operator.ge, uses_method=False)
def _gimbal_lock(run: RunResult, method: str) -> float | None:
    """camera ticks whose roll/pitch/yaw flag gimbal lock >= limit"""
    return float(sum(t.gimbal_locked for t in run.ticks))


@check_kind("tracking_error", operator.le, uses_method=False)
def _tracking(run: RunResult, method: str) -> float | None:
    """largest distance of the body from its reference (controlled flights) <= limit_m"""
    errors = [t.reference_error_m for t in run.ticks if t.reference_error_m is not None]
    return max(errors) if errors else None


@check_kind("matched_cones", operator.ge, uses_method=False)
def _matched_cones(run: RunResult, method: str) -> float | None:
    """number of distinct true cones matched at least once >= limit"""
    return float(
        len({d.cone_index for t in run.ticks for d in t.detections if d.cone_index is not None})
    )
