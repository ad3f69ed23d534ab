"""Pass/fail checks of a finished run against ground truth.

The check kinds are declared as data in ``scenarios.scenario.check_kinds`` (``KINDS``: what each
asserts, its unit, its direction). Here each kind's figure is computed from the run's records
(``scenarios.run.records``), registered under the kind's name with ``@figure`` (``FIGURES``),
and compared with the scenario's limit. The accuracy bounds are those of the perception
contract (docs/ACCURACY.md, declared in ``vnav.methods``).

A check has one of four outcomes (``Outcome``):

- ``passed`` / ``failed``: the figure met its limit, or did not;
- ``no data``: the run holds nothing the check could judge (no estimate by its method, no cone
  in view, a yaw check on a run with no yaw); the reason is given, and it **fails** the run:
  a check that was asked for and judged nothing has not passed;
- ``skipped``: only a default check (a scenario without ``[[checks]]``) whose method cannot
  apply to the scenario's geometry by design, e.g. ``known_height`` seen from steeper than its
  triangle can be measured (``vnav.estimators.NoEstimate.geometric``); the reason is given and
  the run is not failed for it.
"""

from __future__ import annotations

import enum
import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from scenarios.run.records import DetectionRecord, NavigationRecord, RunResult
from scenarios.scenario.check_kinds import KINDS, Check, CheckKind, Unit
from vnav.estimators import NoEstimate
from vnav.methods import CONTRACT_DOMAIN, NAIVE, method
from vnav.uncertainty import nees_band, nees_p_value

__all__ = [
    "FIGURES",
    "MOTION_FLOOR_M",
    "CheckResult",
    "NoData",
    "Outcome",
    "detection_counts",
    "figure",
    "judge",
]

# Below this predicted error (metres) the body held still between an image's exposure and its
# newest pose: the prediction is rounding noise, and a ratio over it means nothing.
MOTION_FLOOR_M = 1e-6


class Outcome(enum.Enum):
    """What judging a check gave (the module's docstring says what each means)."""

    PASSED = "passed"
    FAILED = "failed"
    NO_DATA = "no data"
    SKIPPED = "skipped"

    @property
    def fails_run(self) -> bool:
        """Whether this outcome fails the run (exit status 1): ``failed`` and ``no data``."""
        return self in (Outcome.FAILED, Outcome.NO_DATA)


@dataclass(frozen=True)
class NoData:
    """A figure that could not be computed: why, in words.

    ``geometric``: the reason is that the check's method cannot apply to the view's geometry
    by design (``vnav.estimators.NoEstimate.geometric``); a default check then is skipped.
    """

    reason: str
    geometric: bool = False


Figure = Callable[[RunResult, Check], "float | NoData"]

FIGURES: dict[str, Figure] = {}
"""Each check kind's figure, by the kind's name (``scenarios.scenario.check_kinds.KINDS``)."""


def figure(kind: str) -> Callable[[Figure], Figure]:
    """Register the decorated function as the figure of the declared check kind ``kind``."""
    if kind not in KINDS:
        raise ValueError(f"no check kind {kind!r} is declared; declared: {sorted(KINDS)}")

    def register(compute: Figure) -> Figure:
        FIGURES[kind] = compute
        return compute

    return register


@dataclass(frozen=True)
class CheckResult:
    """A check's outcome: its figure (None without data), the limit, the verdict and why.

    Attributes
    ----------
    name, kind : str
    value : float or None
        The figure in ``unit`` (an int for counts); None for ``no data`` and ``skipped``.
    limit : float
    outcome : Outcome
    unit : Unit
    shown : str
        The figure next to its limit, with units, e.g. ``0.012 m (must be <= 0.1 m)``; for
        ``no data`` and ``skipped``, the reason.
    """

    name: str
    kind: str
    value: float | None
    limit: float
    outcome: Outcome
    unit: Unit
    shown: str

    @property
    def passed(self) -> bool:
        """Whether the check was judged and met its limit."""
        return self.outcome is Outcome.PASSED

    @property
    def reason(self) -> str | None:
        """Why the check judged nothing, or None when it was judged."""
        return self.shown if self.value is None else None

    def as_dict(self) -> dict:
        return {
            "name": self.name,
            "kind": self.kind,
            "outcome": self.outcome.value,
            "passed": self.passed,
            "value": self.value,
            "limit": self.limit,
            "unit": self.unit.value,
            "shown": self.shown,
            "reason": self.reason,
        }


def judge(check: Check, run: RunResult) -> CheckResult:
    """Compute ``check``'s figure on ``run`` and compare it with the limit.

    A figure the run cannot give is ``no data`` (a failure), except for a default check whose
    method cannot apply to the geometry: ``skipped``.
    """
    kind = KINDS[check.kind]
    computed = FIGURES[check.kind](run, check)
    if isinstance(computed, NoData):
        skipped = check.default and computed.geometric
        outcome = Outcome.SKIPPED if skipped else Outcome.NO_DATA
        return CheckResult(
            check.label, check.kind, None, check.limit, outcome, kind.unit, computed.reason
        )
    value: float = round(computed) if kind.unit is Unit.COUNT else float(computed)
    outcome = Outcome.PASSED if kind.passes(value, check.limit) else Outcome.FAILED
    shown = _shown(kind, check, value, run)
    return CheckResult(check.label, check.kind, value, check.limit, outcome, kind.unit, shown)


# ------------------------------------------------------------------- figures shown in words


def _number(x: float, digits: int = 3) -> str:
    """``x`` to ``digits`` significant digits (whole numbers in full, at most 6 decimals),
    without exponent or trailing zeros: 0.000788, 0.05, 20.5, 25988, 0 for 6e-18."""
    if x == 0.0 or not math.isfinite(x):
        return f"{x:g}"
    # At most 6 decimals: a micrometre, a millionth of a percent, reads as 0.
    decimals = min(6, max(0, digits - 1 - math.floor(math.log10(abs(x)))))
    text = f"{x:.{decimals}f}"
    return text.rstrip("0").rstrip(".") if "." in text else text


def _percent(fraction: float) -> str:
    return f"{_number(100.0 * fraction)}%"


def _in_unit(x: float, unit: Unit) -> str:
    if unit is Unit.METRES:
        return f"{_number(x)} m"
    if unit is Unit.FRACTION:
        return _percent(x)
    if unit is Unit.RATIO:
        return f"{_number(x)}x"
    if unit is Unit.DEGREES:
        return f"{_number(x)} deg"
    if unit is Unit.SECONDS:
        return f"{_number(1e3 * x)} ms"
    if unit is Unit.RELATIVE:
        return f"{x:.2g}"  # 4.2e-15: the decimals of _number would show 0
    return _number(x)  # counts (integers print as integers)


def _shown(kind: CheckKind, check: Check, value: float, run: RunResult) -> str:
    op = "<=" if kind.at_most else ">="
    if kind.unit is Unit.BOUND:
        return _shown_bound(check, value, op, run)
    if kind.name == "consistent":
        return _shown_consistent(check, value, op, run)
    return f"{_in_unit(value, kind.unit)} (must be {op} {_in_unit(check.limit, kind.unit)})"


def _function_failures(run: RunResult, method_name: str) -> int:
    """How many detections a user's function failed on (``vnav.plugin``; 0 for a built-in)."""
    return sum(
        d.no_estimate.get(method_name) is NoEstimate.FUNCTION_ERROR for d in _detections(run)
    )


def _shown_bound(check: Check, value: float, op: str, run: RunResult) -> str:
    """An ``error_bound`` or ``chain_agreement`` figure (distance / bound) in the bound's own
    unit where it has one.

    The bound is ``max(floor, fraction x range)``: where every judged detection lies beyond
    the crossover range (``floor / fraction``) it is ``fraction x range`` and the figure is the
    error in % of range; where every one lies within, it is the floor and the figure is the
    error in metres; for a mix, the error in % of the bound.
    """
    failed = _function_failures(run, check.method)
    if failed:
        stopped = sum(
            d.no_estimate.get(check.method) is NoEstimate.FUNCTION_STOPPED for d in _detections(run)
        )
        after = f", and was not called on {stopped} after its time limit" if stopped else ""
        return (
            f"the function failed on {failed} of {len(_detections(run))} detections{after} "
            "(the report's estimators say where and how)"
        )
    chain = check.kind == "chain_agreement"
    bound = method(CHAIN if chain else check.method).bound
    assert bound is not None  # the parser refuses error_bound on a method without one
    if chain:  # every distance, over every matched detection
        statistic, ranges_m = "worst", _chain_distances(run, check.method)[1]
        what = f" from {CHAIN}'s estimate"
    else:
        statistic = "worst" if bound.statistic == "max" else "median"
        ranges_m, what = run.ranges_for(check.method, contract_only=True), ""
    if bound.fraction_of_range > 0.0 and np.all(
        bound.fraction_of_range * ranges_m >= bound.floor_m
    ):
        scale, unit = 100.0 * bound.fraction_of_range, "% of range"
    elif bound.floor_m > 0.0 and np.all(bound.fraction_of_range * ranges_m <= bound.floor_m):
        scale, unit = bound.floor_m, " m"
    else:
        scale, unit = 100.0, "% of the bound"
    return (
        f"{statistic} {_number(value * scale)}{unit}{what} "
        f"(must be {op} {_number(check.limit * scale)}{unit})"
    )


def _shown_consistent(check: Check, value: float, op: str, run: RunResult) -> str:
    """A ``consistent`` figure with the mean NEES it comes from and its band."""
    values, dofs = run.nees(check.method)
    dof = float(np.mean(dofs))
    low, high = nees_band(dof, values.size, 1.0 - check.limit)
    return (
        f"mean NEES {_number(float(np.mean(values)))} over {values.size} ({_number(dof)} dof; "
        f"band {_number(low)}-{_number(high)}): p = {_number(value)} "
        f"(must be {op} {_number(check.limit)})"
    )


# ------------------------------------------------------------------- why there is no data


def _detections(run: RunResult) -> list[DetectionRecord]:
    return [d for t in run.ticks for d in t.detections]


def _no_detection(run: RunResult) -> NoData | None:
    """Why no detection was matched to a true cone, or None if one was."""
    detections = _detections(run)
    if not detections:
        return NoData("no cone was detected in any camera image")
    if any(d.cone_index is not None for d in detections):
        return None
    border = sum(d.detection.touches_border for d in detections)
    cut = f" ({border} touch the image border)" if border else ""
    return NoData(f"none of the {len(detections)} detections was matched to a true cone{cut}")


def _no_estimates(run: RunResult, method_name: str, *, contract_only: bool) -> NoData:
    """Why ``method_name`` has no error to judge: no detection, none matched, none in the
    contract's domain, or the method's own reasons (``vnav.estimators.NoEstimate``)."""
    missing = _no_detection(run)
    if missing is not None:
        return missing
    pool = [d for d in _detections(run) if d.cone_index is not None]
    where = "matched detections"
    if contract_only:
        pool = [d for d in pool if d.in_contract]
        where = "detections in the contract's domain"
        if not pool:
            # Nothing is promised outside the domain: the geometry rules the bound out.
            return NoData(
                f"no matched detection in the contract's domain ({CONTRACT_DOMAIN.text})",
                geometric=True,
            )
    reasons = Counter(d.no_estimate.get(method_name) for d in pool)
    parts = [
        f"{n} {'no reason recorded' if r is None else r.text}" for r, n in reasons.most_common()
    ]
    if len(parts) == 1:
        parts = [f"all {parts[0]}" if len(pool) > 1 else parts[0]]
    return NoData(
        f"no {method_name} estimates for the {len(pool)} {where}: {'; '.join(parts)}",
        geometric=all(r is not None and r.geometric for r in reasons),
    )


# ------------------------------------------------------------------------------ the kinds


def _max(x: np.ndarray) -> float:
    return float(np.max(x))


def _median(x: np.ndarray) -> float:
    return float(np.median(x))


@figure("max_error")
def _max_error(run: RunResult, check: Check) -> float | NoData:
    """largest position error of ``method`` over all matched detections <= limit_m"""
    errors = run.errors(check.method)
    return _max(errors) if errors.size else _no_estimates(run, check.method, contract_only=False)


@figure("median_error")
def _median_error(run: RunResult, check: Check) -> float | NoData:
    """median position error of ``method`` <= limit_m"""
    errors = run.errors(check.method)
    if not errors.size:
        return _no_estimates(run, check.method, contract_only=False)
    return _median(errors)


@figure("error_bound")
def _error_bound(run: RunResult, check: Check) -> float | NoData:
    """error / accuracy bound of ``method`` (worst or median, as the bound says) <= limit

    Over the detections in the contract's domain (docs/ACCURACY.md)."""
    bound = method(check.method).bound
    if bound is None:
        return NoData(f"{check.method} has no accuracy bound")
    if _function_failures(run, check.method):
        return math.inf  # a user's function that failed passes no bound
    errors = run.errors(check.method, contract_only=True)
    if not errors.size:
        return _no_estimates(run, check.method, contract_only=True)
    ratio = errors / bound.allowed_m(run.ranges_for(check.method, contract_only=True))
    return _max(ratio) if bound.statistic == "max" else _median(ratio)


CHAIN = "depth_image"
"""The method whose estimate is the correct chain's on the inputs a user's function is given
(``vnav.plugin.PluginObservation``: its ``p_c`` is this estimate in the camera frame)."""


def _chain_distances(run: RunResult, method_name: str) -> tuple[np.ndarray, np.ndarray]:
    """Over the matched detections with estimates by both ``method_name`` and ``CHAIN``: the
    distance between the two, and the range, metres, shapes (K,) and (K,)."""
    pairs = [
        (float(np.linalg.norm(d.estimates_w[method_name] - d.estimates_w[CHAIN])), d.range_m)
        for d in _detections(run)
        if d.range_m is not None and method_name in d.estimates_w and CHAIN in d.estimates_w
    ]
    a = np.array(pairs, dtype=np.float64).reshape(-1, 2)
    return a[:, 0], a[:, 1]


@figure("chain_agreement")
def _chain_agreement(run: RunResult, check: Check) -> float | NoData:
    """largest distance of ``method``'s estimate from depth_image's / depth_image's bound <= limit

    Each distance over depth_image's bound at that detection's range (docs/ACCURACY.md), over
    every matched detection (in the contract's domain or not) where both gave one. A
    user's function (``vnav.plugin``) is given depth_image's estimate in the camera frame with
    the estimator's pose and mount, so the correct chain gives depth_image's estimate back
    (to about 1e-15 m) whatever the sensors' noise or the mount's error: this judges the
    function's frame chain on the inputs it was given, not the inputs."""
    bound = method(CHAIN).bound
    assert bound is not None  # the perception contract bounds depth_image
    if _function_failures(run, check.method):
        return math.inf  # a user's function that failed agrees with nothing
    distances_m, ranges_m = _chain_distances(run, check.method)
    if not distances_m.size:
        return _no_estimates(run, check.method, contract_only=False)
    return _max(distances_m / bound.allowed_m(ranges_m))


@figure("consistent")
def _consistent(run: RunResult, check: Check) -> float | NoData:
    """chi-square probability of ``method``'s mean NEES, two-sided, >= limit (0.05: in the 95% band)

    The normalised estimation error squared of each matched estimate against its covariance
    (``vnav.uncertainty.nees``); their sum is chi-square with the sum of their degrees of
    freedom when the covariances are right, and the figure is the probability of a mean at
    least this far from its expected value (Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4)."""
    values, dofs = run.nees(check.method)
    if not values.size:
        return _no_estimates(run, check.method, contract_only=False)
    return nees_p_value(float(np.mean(values)), float(np.mean(dofs)), values.size)


def _calibration_error(run: RunResult, key: str) -> float | NoData:
    c = run.calibration
    if c is None:
        return NoData("the run was not calibrated (a calibration check asks for it)")
    if c.refused is not None:
        return NoData(f"calibration refused: {c.refused}")
    return c.errors[key]


def _imu_calibration_error(run: RunResult, key: str) -> float | NoData:
    c = run.imu_calibration
    if c is None:
        return NoData(
            "the run's camera-IMU calibration was not made (a calibration_imu check asks for it)"
        )
    if c.refused is not None:
        return NoData(f"camera-IMU calibration refused: {c.refused}")
    return c.errors[key]


@figure("calibration_imu_rotation")
def _calibration_imu_rotation(run: RunResult, check: Check) -> float | NoData:
    """rotation between the camera-IMU rotation R_i_c recovered from the images and the gyro
    and the true one <= limit (degrees)

    Recovered from the camera's images and the IMU's readings alone
    (``vnav.imu_calibration``), never from the declared mounts."""
    return _imu_calibration_error(run, "rotation_deg")


@figure("calibration_imu_translation")
def _calibration_imu_translation(run: RunResult, check: Check) -> float | NoData:
    """distance between the camera's origin in the IMU frame recovered (t_i_c, from the
    accelerometer's lever arm) and the true one <= limit_m"""
    return _imu_calibration_error(run, "translation_m")


@figure("calibration_imu_time_offset")
def _calibration_imu_time_offset(run: RunResult, check: Check) -> float | NoData:
    """error of the recovered camera-IMU clock offset (Kalibr's timeshift_cam_imu) <= limit
    (seconds)"""
    return _imu_calibration_error(run, "time_offset_s")


@figure("calibration_rotation")
def _calibration_rotation(run: RunResult, check: Check) -> float | NoData:
    """rotation between the recovered camera mount and the true one <= limit (degrees)

    The mount recovered from the whole flight (``vnav.calibration``), not the declared one."""
    return _calibration_error(run, "rotation_deg")


@figure("calibration_translation")
def _calibration_translation(run: RunResult, check: Check) -> float | NoData:
    """distance between the recovered camera mount's origin and the true one <= limit_m"""
    return _calibration_error(run, "translation_m")


@figure("calibration_time_offset")
def _calibration_time_offset(run: RunResult, check: Check) -> float | NoData:
    """error of the recovered camera clock offset <= limit (seconds)"""
    return _calibration_error(run, "time_offset_s")


def detection_counts(run: RunResult) -> tuple[int, int]:
    """Cones detected (matched) while fully in view, and cones fully in view, summed over the
    camera ticks: the detection rate's numerator and denominator."""
    seen = detected = 0
    for t in run.ticks:
        matched = {d.cone_index for d in t.detections if d.cone_index is not None}
        seen += len(t.cones_in_view)
        detected += len(set(t.cones_in_view) & matched)
    return detected, seen


@figure("detection_rate")
def _detection_rate(run: RunResult, check: Check) -> float | NoData:
    """detections / cones fully in view (summed over camera ticks) >= limit"""
    detected, seen = detection_counts(run)
    if seen:
        return detected / seen
    border = sum(d.detection.touches_border for d in _detections(run))
    cut = f"; {border} detections touch the image border" if border else ""
    return NoData(
        f"no cone was fully in view and >= {CONTRACT_DOMAIN.min_height_px:g} px tall at any "
        f"camera tick{cut}"
    )


def _per_cone(run: RunResult, method: str | None) -> dict[int, list[DetectionRecord]]:
    """Per matched cone: its detections with an estimate by ``method`` (any with None)."""
    out: dict[int, list[DetectionRecord]] = {}
    for d in _detections(run):
        if d.cone_index is not None and (method is None or method in d.estimates_w):
            out.setdefault(d.cone_index, []).append(d)
    return out


def _span_m(points: np.ndarray) -> float:
    """Length of the diagonal of the points' bounding box, metres."""
    return float(np.linalg.norm(np.ptp(points, axis=0)))


@figure("world_estimate_spread")
def _world_spread(run: RunResult, check: Check) -> float | NoData:
    """largest distance of ``method``'s estimates of a cone from their mean <= limit_m

    Over the cones whose camera coordinates moved by more than the limit: where nothing moved
    in the camera, a constant world estimate shows nothing (no data)."""
    per_cone = _per_cone(run, check.method)
    if not per_cone:
        return _no_estimates(run, check.method, contract_only=False)
    spreads, moved_m = [], []
    for records in per_cone.values():
        p_w = np.array([d.estimates_w[check.method] for d in records])
        moved_m.append(_span_m(np.array([d.p_c_true for d in records])))
        if moved_m[-1] > check.limit:
            spreads.append(float(np.max(np.linalg.norm(p_w - p_w.mean(axis=0), axis=1))))
    if spreads:
        return max(spreads)
    # Nothing moved in the camera: a constant world estimate shows nothing (the naive
    # estimate would be constant too).
    return NoData(
        f"the cone's camera coordinates moved {_number(max(moved_m))} m, not more than the "
        f"limit ({_number(check.limit)} m): nothing moved for the world estimate to follow"
    )


@figure("camera_coords_span")
def _camera_span(run: RunResult, check: Check) -> float | NoData:
    """the cone's camera-frame coordinates move by >= limit_m"""
    per_cone = _per_cone(run, None)
    if not per_cone:
        missing = _no_detection(run)
        assert missing is not None  # no matched detection is exactly what it explains
        return missing
    return max(_span_m(np.array([d.p_c_true for d in r])) for r in per_cone.values())


@figure("naive_worse")
def _naive_worse(run: RunResult, check: Check) -> float | NoData:
    """median naive error >= limit x the median error of ``method``"""
    naive, ref = run.errors(NAIVE), run.errors(check.method)
    if not ref.size:
        return _no_estimates(run, check.method, contract_only=False)
    if not naive.size:
        return _no_estimates(run, NAIVE, contract_only=False)
    return _median(naive) / max(_median(ref), 1e-6)


@figure("gimbal_lock_seen")
def _gimbal_lock(run: RunResult, check: Check) -> float | NoData:
    """camera ticks whose roll/pitch/yaw flag gimbal lock >= limit"""
    return float(sum(t.gimbal_locked for t in run.ticks))


@figure("tracking_error")
def _tracking(run: RunResult, check: Check) -> float | NoData:
    """largest distance of the body from its reference (controlled flights) <= limit_m"""
    errors = [t.reference_error_m for t in run.ticks if t.reference_error_m is not None]
    if errors:
        return max(errors)
    return NoData("the flight has no reference to track (kinematic keyframes are exact)")


@figure("matched_cones")
def _matched_cones(run: RunResult, check: Check) -> float | NoData:
    """number of distinct true cones matched at least once >= limit"""
    return float(len(_per_cone(run, None)))


@figure("latency_prediction")
def _latency_prediction(run: RunResult, check: Check) -> float | NoData:
    """median |latest-pose error / predicted - 1| <= limit (depth_image with the newest pose)

    The ``depth_image`` estimate made with the newest pose received when the image arrived,
    against the first-order prediction of its error from the body's true motion between the
    exposure and that pose's stamp, ``|dp| + range |dtheta|`` (``scenarios.run.evaluate``); over
    the matched detections whose newest pose was not the exposure pose and whose predicted
    error exceeds ``MOTION_FLOOR_M`` (a body holding still predicts rounding noise, ~1e-15 m,
    and any error over it is an absurd ratio)."""
    latest, predicted = run.latest_pose_errors()
    moved = predicted > MOTION_FLOOR_M
    if np.any(moved):
        return _median(np.abs(latest[moved] / predicted[moved] - 1.0))
    missing = _no_detection(run)
    if missing is not None:
        return missing
    if latest.size:
        return NoData(
            "the body did not move between any image's exposure and the newest pose received "
            "when it arrived: no stale pose to judge"
        )
    return NoData("no matched detection has a depth_image estimate with the newest pose")


def _navigation(run: RunResult) -> NavigationRecord | NoData:
    """The run's navigation record, or why there is none."""
    if run.navigation is None:
        return NoData('the flight does not navigate (flight.mode is not "navigate")')
    return run.navigation


@figure("reached_goal")
def _reached_goal(run: RunResult, check: Check) -> float | NoData:
    """true distance of the body from the goal when a navigating flight ends <= limit_m"""
    nav = _navigation(run)
    return nav if isinstance(nav, NoData) else nav.final_distance_m


@figure("no_collision")
def _no_collision(run: RunResult, check: Check) -> float | NoData:
    """cones the drone touched (MuJoCo contacts) <= limit (0: none)"""
    nav = _navigation(run)
    return nav if isinstance(nav, NoData) else float(nav.collided)


@figure("collision")
def _collision(run: RunResult, check: Check) -> float | NoData:
    """cones the drone touched (MuJoCo contacts) >= limit (1: the run must collide)"""
    nav = _navigation(run)
    return nav if isinstance(nav, NoData) else float(nav.collided)


@figure("min_clearance")
def _min_clearance(run: RunResult, check: Check) -> float | NoData:
    """smallest true distance between the drone's and a cone's geometry >= limit_m"""
    nav = _navigation(run)
    return nav if isinstance(nav, NoData) else nav.min_clearance_m


@figure("imu_consistent")
def _imu_consistent(run: RunResult, check: Check) -> float | NoData:
    """largest relative difference, over every physics step, between MuJoCo's noise-free IMU
    sensors and vnav.imu's specific force and rate from the body's motion <= limit"""
    if run.imu is None:
        return NoData("the scenario declares no [imu]")
    return run.imu.max_discrepancy
