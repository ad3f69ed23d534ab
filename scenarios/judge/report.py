"""The JSON report of a run: error statistics per method, checks, timing.

Statistics follow evo (``vnav.metrics.error_stats``): rmse, mean, median, std, min, max, count,
all in metres, over all matched detections and per 5 m bin of range (``by_range``).
Statistics of an empty series are ``null``; ``nees`` says whether each method's covariances
match its errors (``nees_summary``); ``no_estimate`` counts, per method, the matched
detections it gave no estimate for, by reason (``vnav.estimators.NoEstimate``). Each check
has an ``outcome``: ``passed``, ``failed``, ``no data`` (nothing to judge, with its
``reason``: fails the run) or ``skipped`` (a default check whose method cannot apply to the
scenario's geometry, with its ``reason``); ``shown`` is the figure next to its limit in words.
Only ``timing_s`` depends on the machine; everything else is fixed by the scenario and the seed.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from collections import Counter
from typing import Any

import numpy as np

from scenarios.judge.checks import CheckResult
from scenarios.run.records import RunResult
from scenarios.scenario.check_kinds import Unit
from vnav import metrics, se3
from vnav.methods import NEWEST_POSE_METHOD, Method, active_methods
from vnav.uncertainty import nees_band

REPORT_VERSION = 8
"""2: ``camera_ticks`` (was ``frames``): the word frame means a coordinate frame only;
``recording`` names the ``.rrd`` file and its Rerun recording id.
3: each check has an ``outcome`` (passed, failed, no data, skipped), a ``unit``, the figure
``shown`` in words next to its limit, and the ``reason`` it has no data; ``passed`` is
whether no check failed or lacked data (``scenarios.judge.checks.Outcome``).
4: ``timing`` (the scenario's sensor clocks) and ``pose_lookup``: the ``depth_image`` errors with
the pose looked up at the exposure stamp and with the newest pose received when the image
arrived, the latter's first-order prediction, image latencies and the newest pose's lead.
5: per method ``nees``: the normalised estimation error squared of its estimates against their
covariances (count, mean, mean degrees of freedom, the 95% chi-square band of the mean and
whether the mean lies in it); ``noise``, the scenario's sensor noise.
6: ``calibration`` (null unless a check asks for it): the camera mount ``T_b_c`` and clock
offset recovered from the flight, their reprojection RMS, images used, errors against the
truth, or why the flight was refused; ``camera_mount_error``, the scenario's true mount's
error from the declared one.
7: ``noise`` holds ``intensity_std_grey`` (was ``pixel_std_px``, the same figure: the image
noise in 8-bit grey levels); its keys are ``vnav.noise_model.NoiseModel``'s fields.
8: ``calibration.position_error_m``: per method, the error statistics of the run's estimates
made with the declared mount (``declared_mount``, the same as ``methods``) and of the same
images estimated again with the recovered mount (``recovered_mount``): what calibrating
gives. ``timing_s`` adds ``calibrate`` (the calibration and that second estimate), ``judge``
(the checks), ``total`` (the whole run, from its start to its report, wall seconds) and
``total_cpu`` (the process's CPU time, user and system, over the same span, with its export
process's).
Also in 8, only in the report of a run with a user's function (``vnav.plugin``): ``estimators``,
per function its spec, its time limit (``timeout_s``, None without one), calls, how many
returned None, how many detections it was skipped on after timing out (``skipped``), its calls'
wall time (``time_s``: ``calls``, ``total``, ``mean``, ``max``, seconds), its failures by kind
(count, first message, camera ticks), the frame-bug doctor's ``diagnosis`` of its estimates
(``vnav.diagnose.Diagnosis.to_dict``, None without any) and, in a calibrated run, the same
for its second pass with the recovered mount (``recovered_mount``); its statistics are under
``methods`` as a built-in's. Only in the report of a navigating flight: ``navigation``
(``navigation``). Only in the report of a run with a ``calibration_imu_*`` check:
``imu_calibration`` (``imu_calibration_summary``)."""


def _calibration(run: RunResult) -> dict[str, Any] | None:
    c = run.calibration
    if c is None:
        return None
    if c.refused is not None:
        return {"refused": c.refused}
    recovered = run.with_recovered_mount()
    return {
        "T_b_c": [[round(float(v), 9) for v in row] for row in c.T_b_c],
        "time_offset_s": _finite_or_none(c.time_offset_s),
        "reprojection_rms_px": _finite_or_none(c.reprojection_rms_px),
        "frames_used": c.frames_used,
        "errors": {k: _finite_or_none(v) for k, v in c.errors.items()},
        "position_error_m": {
            "declared_mount": {m: _stats(run.errors(m)) for m in _names()},
            "recovered_mount": {
                m: None if recovered is None else _stats(recovered.errors(m)) for m in _names()
            },
        },
    }


def _finite_or_none(value: float) -> float | int | None:
    if isinstance(value, int):
        return value
    return None if not math.isfinite(value) else round(float(value), 9)


def _check_value(c: CheckResult) -> float | int | None:
    """A check's figure for the report: to 9 decimals, or to 9 significant digits for a
    relative error, whose meaning is its exponent (1e-15 would round to 0)."""
    if c.value is None:
        return None
    if c.unit is Unit.RELATIVE and math.isfinite(c.value):
        return float(f"{c.value:.9g}")
    return _finite_or_none(c.value)


RANGE_BINS_M = (0.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0, math.inf)
"""Edges of the range bins of the error-against-range statistics, metres."""


def _stats(errors) -> dict[str, float | int | None]:
    return {k: _finite_or_none(v) for k, v in metrics.error_stats(errors).items()}


def build(
    run: RunResult, checks: list[CheckResult], recording: dict[str, str] | None = None
) -> dict[str, Any]:
    """The report as a JSON-ready dict.

    ``recording`` (``{"file": ..., "id": ...}``) names the ``.rrd`` written with it and the
    Rerun recording id inside that file, so a reader can check that the two belong together.
    """
    spec = run.spec
    methods = {
        m: {
            "position_error_m": _stats(run.errors(m)),
            "by_range": _by_range(run, m),
            "no_estimate": _no_estimate(run, m),
            "nees": nees_summary(run, m),
        }
        for m in _names()
    }
    n_detections = sum(len(t.detections) for t in run.ticks)
    n_matched = sum(d.cone_index is not None for t in run.ticks for d in t.detections)
    out = {
        "report_version": REPORT_VERSION,
        "scenario": spec.name,
        "description": spec.description,
        "seed": run.seed,
        "passed": not any(c.outcome.fails_run for c in checks),
        "camera_ticks": len(run.ticks),
        "detections": n_detections,
        "matched_detections": n_matched,
        "simulated_s": round(run.ticks[-1].t_s, 9) if run.ticks else 0.0,
        "camera_rate_hz": spec.camera_rate_hz,
        "flight_mode": spec.flight.mode,
        "cones_w": [list(c) for c in spec.scene.cones_w],
        "methods": methods,
        "timing": dataclasses.asdict(spec.timing),
        "noise": dataclasses.asdict(spec.noise),
        "camera_mount_error": dataclasses.asdict(spec.scene.camera.mount_error),
        "pose_lookup": pose_lookup(run),
        "calibration": _calibration(run),
        "checks": [{**c.as_dict(), "value": _check_value(c)} for c in checks],
        "recording": recording,
        "timing_s": {k: round(v, 4) for k, v in run.timing_s.items()},
    }
    if run.navigation is not None:  # only a navigating flight: other reports are unchanged
        out["navigation"] = navigation(run)
    if run.imu is not None:  # only with an [imu]: other reports are unchanged
        out["imu"] = imu_summary(run)
    if run.imu_calibration is not None:  # only when a calibration_imu check asks for it
        out["imu_calibration"] = imu_calibration_summary(run)
    users = [m for m in active_methods() if m.images == "user"]
    if users:  # only with a user's function: a built-in run's report is unchanged
        out["estimators"] = {m.name: estimator_summary(run, m) for m in users}
    return out


def imu_summary(run: RunResult) -> dict[str, Any]:
    """The scenario's IMU (``[imu]``): its declared and true mounts, clock offset, rate and
    noise figures, the readings taken, and how closely MuJoCo's noise-free sensors followed
    ``vnav.imu``'s chain (``max_discrepancy``, relative, over ``steps_checked`` physics
    states)."""
    imu, record = run.spec.scene.imu, run.imu
    assert imu is not None and record is not None
    return {
        "rate_hz": imu.rate_hz,
        "readings": len(record.t_s),
        "time_offset_s": imu.time_offset_s,
        "noise": dataclasses.asdict(imu.noise),
        "mount_error": dataclasses.asdict(imu.mount_error),
        "T_b_i_declared": imu.T_b_i_declared.tolist(),
        "T_b_i": imu.T_b_i.tolist(),
        "max_discrepancy": record.max_discrepancy,
        "steps_checked": record.steps_checked,
    }


def imu_calibration_summary(run: RunResult) -> dict[str, Any]:
    """The camera-IMU calibration recovered from the run (``vnav.imu_calibration``): ``T_i_c``
    and Kalibr's ``T_cam_imu`` (its inverse), the clock offset (``timeshift_cam_imu``), the
    errors against the truth and the fit's standard errors, or why it was refused."""
    c = run.imu_calibration
    assert c is not None
    return {
        "refused": c.refused,
        "T_i_c": None if c.T_i_c is None else c.T_i_c.tolist(),
        "T_cam_imu": None if c.T_i_c is None else se3.invert(c.T_i_c).tolist(),
        "timeshift_cam_imu_s": c.time_offset_s,
        "T_i_c_true": None if c.T_i_c_true is None else c.T_i_c_true.tolist(),
        "reprojection_rms_px": c.reprojection_rms_px,
        "frames_used": c.frames_used,
        "errors": c.errors,
        "std": c.std,
    }


def _names() -> list[str]:
    """The run's methods' names, in report order (the built-ins, then users' functions)."""
    return [m.name for m in active_methods()]


def estimator_summary(run: RunResult, m: Method) -> dict[str, Any]:
    """A user's function over the run (``vnav.plugin``): its spec, calls, how many returned
    None, how many detections it was not called on after timing out (``skipped``), its calls'
    wall time (``time_s``), each kind of failure with its count, first message and the camera
    ticks, the doctor's diagnosis; in a calibrated run, the same tallies of its second pass
    with the recovered mount (``recovered_mount``)."""
    estimator = m.estimator
    tick_of = {(t.t_s if t.timing is None else t.timing.exposure_pose_s): t.tick for t in run.ticks}
    diagnosis = estimator.diagnosis()
    out = {
        "spec": m.implementation,
        "timeout_s": estimator.timeout_s,
        **_tallies(estimator, tick_of),
        "diagnosis": None if diagnosis is None else diagnosis.to_dict(),
    }
    if estimator.again is not None:
        again = estimator.again.diagnosis()
        out["recovered_mount"] = {
            **_tallies(estimator.again, tick_of),
            "diagnosis": None if again is None else again.to_dict(),
        }
    return out


def _tallies(estimator: Any, tick_of: dict[float, int]) -> dict[str, Any]:
    """A ``vnav.plugin.PluginEstimator``'s calls, times and failures, as the report has them."""
    f, times = estimator.failures, estimator.times
    return {
        "calls": f.calls,
        "returned_none": f.returned_none,
        "skipped": f.skipped,
        "time_s": {
            "calls": times.calls,
            "total": round(times.total_s, 6),
            "mean": round(times.mean_s, 6),
            "max": round(times.max_s, 6),
        },
        "failures": {
            kind.value: {
                "count": f.count[kind],
                "first_message": f.first_message[kind],
                "ticks": sorted({tick_of.get(t_s, -1) for t_s in f.stamps_s[kind]}),
            }
            for kind in f.count
        },
    }


def navigation(run: RunResult) -> dict[str, Any]:
    """A navigating flight's outcome: whether and when it reached its goal, whether it
    touched a cone (when, which, where), its smallest true clearance, the length flown and,
    per camera tick, the planned path's length and the smallest true clearance."""
    nav = run.navigation
    assert nav is not None
    contact = nav.contact
    return {
        "estimate": run.spec.flight.estimate,
        "clearance_m": run.spec.flight.clearance_m,
        "goal_w": list(run.spec.flight.goal_w),
        "reached_goal": nav.reached_goal,
        "time_to_goal_s": nav.reached_goal_s,
        "collided": nav.collided,
        "first_contact_s": None if contact is None else round(contact.t_s, 9),
        "first_contact_cone": None if contact is None else contact.cone_index,
        "first_contact_point_w": None if contact is None else contact.point_w.tolist(),
        "min_clearance_m": _finite_or_none(nav.min_clearance_m),
        "path_length_m": _finite_or_none(nav.path_length_m),
        "final_distance_to_goal_m": _finite_or_none(nav.final_distance_m),
        "per_tick": {
            "t_s": [round(k.t_s, 9) for k in nav.ticks],
            "plan_length_m": [_finite_or_none(k.plan_length_m) for k in nav.ticks],
            "min_clearance_true_m": [
                _finite_or_none(float(np.min(k.clearance_true_m))) for k in nav.ticks
            ],
            "mapped_cones": [len(k.obstacles_w) for k in nav.ticks],
        },
    }


def nees_summary(run: RunResult, method: str) -> dict[str, Any]:
    """``method``'s NEES over matched detections: count, mean, mean degrees of freedom, the
    95% chi-square band of the mean for that count and whether the mean lies in it."""
    values, dofs = run.nees(method)
    if not values.size:
        return {"count": 0, "mean": None, "dof": None, "band": None, "consistent": None}
    mean, dof = float(np.mean(values)), float(np.mean(dofs))
    low, high = nees_band(dof, values.size, 0.95)
    return {
        "count": int(values.size),
        "mean": _finite_or_none(mean),
        "dof": round(dof, 6),
        "band": [round(low, 6), round(high, 6)],
        "consistent": bool(low <= mean <= high),
    }


def _spread(values: list[float]) -> dict[str, float | None]:
    """Mean, min and max of a series (null when empty)."""
    if not values:
        return {"mean": None, "min": None, "max": None}
    a = np.array(values, dtype=np.float64)
    return {
        k: _finite_or_none(f(a)) for k, f in (("mean", np.mean), ("min", np.min), ("max", np.max))
    }


def pose_lookup(run: RunResult) -> dict[str, Any]:
    """The two ways of choosing the pose for an image, compared on ``depth_image``.

    ``at_exposure``: the pose looked up at the image's exposure stamp (what the methods use);
    ``latest_at_arrival``: the newest pose received when the image arrived, over the matched
    detections it gave an estimate for, with the first-order prediction of its error
    (``scenarios.run.evaluate``); ``image_latency_s`` (exposure to arrival) and
    ``latest_minus_exposure_s`` (the newest pose's stamp minus the exposure stamp: the ``dt`` of
    the prediction) over the camera ticks.
    """
    latest, predicted = run.latest_pose_errors()
    timed = [t.timing for t in run.ticks if t.timing is not None]
    return {
        "method": NEWEST_POSE_METHOD,
        "at_exposure": {"position_error_m": _stats(run.errors(NEWEST_POSE_METHOD))},
        "latest_at_arrival": {
            "position_error_m": _stats(latest),
            "predicted_error_m": _stats(predicted),
        },
        "image_latency_s": _spread([t.image_latency_s for t in timed]),
        "latest_minus_exposure_s": _spread(
            [t.latest_minus_exposure_s for t in timed if t.latest_minus_exposure_s is not None]
        ),
    }


def _no_estimate(run: RunResult, method: str) -> dict[str, int]:
    """How many matched detections ``method`` gave no estimate for, per reason, most first."""
    reasons = Counter(
        d.no_estimate[method].value
        for t in run.ticks
        for d in t.detections
        if d.cone_index is not None and method in d.no_estimate
    )
    return dict(reasons.most_common())


def _by_range(run: RunResult, method: str) -> list[dict[str, Any]]:
    """``method``'s error statistics per bin of range (``RANGE_BINS_M``), non-empty bins only."""
    errors, ranges = run.errors(method), run.ranges_for(method)
    out = []
    for lo, hi in itertools.pairwise(RANGE_BINS_M):
        in_bin = (ranges >= lo) & (ranges < hi)
        if in_bin.any():
            # The last bin is open: its upper edge is null.
            out.append(
                {
                    "range_m": [lo, hi if math.isfinite(hi) else None],
                    "position_error_m": _stats(errors[in_bin]),
                }
            )
    return out


def dumps(report: dict[str, Any]) -> str:
    """The report as indented JSON text (no NaN: missing values are null)."""
    return json.dumps(report, indent=2, allow_nan=False) + "\n"
