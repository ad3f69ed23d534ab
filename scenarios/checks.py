"""Pass/fail checks of a finished run against ground truth.

Each check kind computes one figure from the run and compares it with the scenario's limit
(see ``scenarios.spec.CHECK_KINDS``). The accuracy bounds are those of the perception contract
(issue 4): per detection, with the depth image, ``max(5 cm, 1 % of range)``; median with the
ground plane ``max(10 cm, 2 % of range)``; median with the known height ``5 % of range``.
"""

from __future__ import annotations

import operator
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from scenarios.runner import RunResult
from scenarios.spec import CHECK_KINDS, Check

ERROR_BOUNDS_M: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "depth_image": lambda r: np.maximum(0.05, 0.01 * r),
    "ground_plane": lambda r: np.maximum(0.10, 0.02 * r),
    "known_height": lambda r: 0.05 * r,
}
"""Allowed position error as a function of range, metres (issue 4's accuracy contract)."""


@dataclass(frozen=True)
class CheckResult:
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


def _max(x: np.ndarray) -> float | None:
    return float(np.max(x)) if x.size else None


def _median(x: np.ndarray) -> float | None:
    return float(np.median(x)) if x.size else None


def _error_bound(run: RunResult, method: str) -> float | None:
    """Worst (depth image) or median (others) ratio of error to its allowed bound.

    Only detections in the contract's domain count (cone fully in view, >= 12 px tall, 2-25 m
    away): that is where the bound is promised. The report's statistics keep every detection.
    """
    if method not in ERROR_BOUNDS_M:
        return None
    errors = run.errors(method, contract_only=True)
    ratio = errors / ERROR_BOUNDS_M[method](run.ranges_for(method, contract_only=True))
    return _max(ratio) if method == "depth_image" else _median(ratio)


def _detection_rate(run: RunResult, method: str) -> float | None:
    seen = detected = 0
    for f in run.frames:
        matched = {d.cone_index for d in f.detections if d.cone_index is not None}
        seen += len(f.cones_in_view)
        detected += len(set(f.cones_in_view) & matched)
    return detected / seen if seen else None


def _per_cone(run: RunResult, attr: str, method: str) -> dict[int, np.ndarray]:
    out: dict[int, list[np.ndarray]] = {}
    for f in run.frames:
        for d in f.detections:
            if d.cone_index is None:
                continue
            value = d.estimates_w.get(method) if attr == "estimate" else d.p_c_true
            if value is not None:
                out.setdefault(d.cone_index, []).append(value)
    return {i: np.array(v) for i, v in out.items()}


def _world_spread(run: RunResult, method: str) -> float | None:
    spreads = [
        float(np.max(np.linalg.norm(p - p.mean(axis=0), axis=1)))
        for p in _per_cone(run, "estimate", method).values()
    ]
    return max(spreads) if spreads else None


def _camera_span(run: RunResult, method: str) -> float | None:
    spans = [
        float(np.linalg.norm(np.ptp(p, axis=0))) for p in _per_cone(run, "camera", method).values()
    ]
    return max(spans) if spans else None


def _naive_worse(run: RunResult, method: str) -> float | None:
    naive, ref = _median(run.errors("naive")), _median(run.errors(method))
    if naive is None or ref is None:
        return None
    return naive / max(ref, 1e-6)


def _gimbal_lock(run: RunResult, method: str) -> float | None:
    return float(sum(f.gimbal_locked for f in run.frames))


def _tracking(run: RunResult, method: str) -> float | None:
    errors = [f.reference_error_m for f in run.frames if f.reference_error_m is not None]
    return max(errors) if errors else None


def _matched_cones(run: RunResult, method: str) -> float | None:
    return float(
        len({d.cone_index for f in run.frames for d in f.detections if d.cone_index is not None})
    )


_KINDS: dict[str, tuple[Callable[[RunResult, str], float | None], Callable]] = {
    "max_error": (lambda run, m: _max(run.errors(m)), operator.le),
    "median_error": (lambda run, m: _median(run.errors(m)), operator.le),
    "error_bound": (_error_bound, operator.le),
    "detection_rate": (_detection_rate, operator.ge),
    "world_estimate_spread": (_world_spread, operator.le),
    "camera_coords_span": (_camera_span, operator.ge),
    "naive_worse": (_naive_worse, operator.ge),
    "gimbal_lock_seen": (_gimbal_lock, operator.ge),
    "tracking_error": (_tracking, operator.le),
    "matched_cones": (_matched_cones, operator.ge),
}


def evaluate(check: Check, run: RunResult) -> CheckResult:
    """Compute ``check``'s figure on ``run``; a check with no data to judge fails."""
    compute, compare = _KINDS[check.kind]
    value = compute(run, check.method)
    passed = value is not None and bool(compare(value, check.limit))
    return CheckResult(check.label, check.kind, value, check.limit, passed)


def default_checks() -> tuple[Check, ...]:
    """Checks for a scenario file that declares none: the accuracy contract and detection."""
    return (
        Check("error_bound", 1.0, "depth_image", "depth_image error within max(5 cm, 1% range)"),
        Check(
            "error_bound",
            1.0,
            "ground_plane",
            "ground_plane median error within max(10 cm, 2% range)",
        ),
        Check("error_bound", 1.0, "known_height", "known_height median error within 5% range"),
        Check("detection_rate", 0.95, name="cones in view detected (fraction)"),
    )


if set(_KINDS) != set(CHECK_KINDS):  # the spec documents the kinds, this module computes them
    raise ImportError(f"check kinds diverged: {sorted(set(_KINDS) ^ set(CHECK_KINDS))}")
