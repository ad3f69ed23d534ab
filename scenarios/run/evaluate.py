"""Evaluate one camera tick: localise every detection and compare it with the truth.

This is where a tick's estimates meet the ground truth; it needs the truth as numbers, not
the simulator that produced them (``scenarios.run.runner`` reads them out of MuJoCo). The
estimating is all ``vnav``'s (``vnav.localize.Localizer``); here it is fed what the estimator
was told and its output is compared::

    estimate p_w per method   <- Localizer.update(t, detections, depth, T_w_b_est, T_b_c_est)
             and its covariance  (with the noise and pose covariances the estimator is told)
    match                     <- each detection's best estimate to the nearest true cone,
                                 on the ground plane (vnav.metrics.match_nearest)
    compare  error = |p_w - truth|, its NEES against the covariance, range, contract domain
             (vnav.methods.CONTRACT_DOMAIN)
    latest   the NEWEST_POSE_METHOD estimate again with the newest pose received when the
             image arrived (what a pipeline ignoring stamps does; Localizer.estimate_with_pose),
             its error and the first-order prediction of that error from the body's true
             motion, |dp| + range |dtheta|

``reevaluate`` runs a finished run's ticks through a new ``Localizer`` again, with another
camera mount (the one calibration recovered), on the same detections, depth and poses.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from scenarios.run.records import DetectionRecord, ImageTiming, TickRecord
from vnav import metrics, se3, so3
from vnav.camera import PinholeCamera
from vnav.cone import cones_fully_in_view
from vnav.detect import ConeDetection
from vnav.estimators import NoEstimate
from vnav.localize import ConeEstimates, Localizer
from vnav.methods import CONTRACT_DOMAIN, NEWEST_POSE_METHOD
from vnav.uncertainty import nees, nees_many

__all__ = ["MATCH_GATE_M", "TickTruth", "evaluate_tick", "reevaluate", "with_method"]

MATCH_GATE_M = 3.0
"""An estimate farther than this from every true cone is reported unmatched."""


@dataclass(frozen=True)
class TickTruth:
    """The ground truth at one camera tick, in vnav's conventions.

    Attributes
    ----------
    tick : int
    t_s : float
        Simulated time, seconds.
    T_w_b : ndarray, shape (4, 4)
        True body pose in the world.
    T_b_c : ndarray, shape (4, 4)
        The camera mount.
    quat_xyzw : ndarray, shape (4,)
        The body attitude, scalar last (as the simulator reports it).
    cones_w : ndarray, shape (N, 3)
        True base centres of the cones, metres.
    reference_error_m : float or None
        Distance of the body from the flight's reference position, if it has one.
    v_w_b_mps : ndarray, shape (3,), or None
        The body origin's true velocity in the world, m/s, if known.
    """

    tick: int
    t_s: float
    T_w_b: np.ndarray
    T_b_c: np.ndarray
    quat_xyzw: np.ndarray
    cones_w: np.ndarray
    reference_error_m: float | None = None
    v_w_b_mps: np.ndarray | None = None


def evaluate_tick(
    truth: TickTruth,
    detections: list[ConeDetection],
    depth_m: np.ndarray | None,
    localizer: Localizer,
    T_w_b_est: np.ndarray,
    timing: ImageTiming | None = None,
    *,
    T_b_c_est: np.ndarray | None = None,
    cov_T_w_b: np.ndarray | None = None,
    cov_T_b_c: np.ndarray | None = None,
    keep_depth: bool = False,
    T_w_b_newest: np.ndarray | None = None,
    seen: TickRecord | None = None,
) -> TickRecord:
    """Localise every detection with what the estimator was told and compare with the truth.

    Parameters
    ----------
    truth : TickTruth
    detections : list of ConeDetection
        From ``vnav.detect.detect_cones`` on this tick's image.
    depth_m : ndarray, shape (H, W), or None
        This tick's planar depth image, metres.
    localizer : vnav.localize.Localizer
        The run's estimator (its camera, far plane, the sensor noise it is told, and the
        several-image methods' state).
    T_w_b_est : ndarray, shape (4, 4)
        The body pose the estimator looked up at the exposure stamp (the truth plus any pose
        noise, interpolated in the pose stream).
    timing : ImageTiming, optional
        The image's stamps and the newest pose received when it arrived: with it, every matched
        detection also gets the ``NEWEST_POSE_METHOD`` estimate made with that pose
        (``DetectionRecord.latest_w``), its error and its predicted error; and the estimator's
        clock stamps the image (else the simulator's time does).
    T_b_c_est : ndarray, shape (4, 4), optional
        The camera mount the estimator is told (the truth's, ``truth.T_b_c``, by default).
    cov_T_w_b, cov_T_b_c : ndarray, shape (6, 6), optional
        The covariances the estimator is told for ``T_w_b_est`` and ``T_b_c_est``.
    keep_depth : bool
        Keep each detection's depth under its mask (``DetectionRecord.depth_under_mask_m``), so
        that ``reevaluate`` can estimate the tick again (a calibrated run's).
    T_w_b_newest : ndarray, shape (4, 4), optional
        The newest pose received when the image arrived, as users' functions are shown it
        (``vnav.plugin``); default ``timing.T_w_b_latest``.
    seen : TickRecord, optional
        A record of this tick with this truth (``reevaluate``'s): its attitude, gimbal-lock flag
        and cones in view, which depend on the truth alone, are taken from it, not recomputed.

    Returns
    -------
    TickRecord
    """
    told = _Told.of(truth, timing, T_w_b_est, T_b_c_est, cov_T_w_b, cov_T_b_c, T_w_b_newest)
    view = _truth_view(truth, localizer.camera, seen)
    estimates = told.update(localizer, detections, depth_m)
    records = _detection_records(truth, detections, estimates, view.cones_in_view)
    records = _with_newest_pose(records, truth, told, timing, localizer, depth_m)
    records = _with_depth_kept(records, depth_m) if keep_depth else records
    return _tick_record(truth, told, view, records, timing)


@dataclass(frozen=True)
class _Told:
    """What the estimator is told with one image (``evaluate_tick``'s defaults resolved).

    Attributes
    ----------
    t_s : float
        The image's stamp: its exposure on the pose clock, or the simulator's time without
        timing.
    T_w_b_est, T_b_c_est : ndarray, shape (4, 4)
        The body pose at that stamp and the camera mount.
    cov_T_w_b, cov_T_b_c : ndarray, shape (6, 6), or None
        Their covariances.
    T_w_b_newest : ndarray, shape (4, 4), or None
        The newest pose received when the image arrived.
    """

    t_s: float
    T_w_b_est: np.ndarray
    T_b_c_est: np.ndarray
    cov_T_w_b: np.ndarray | None
    cov_T_b_c: np.ndarray | None
    T_w_b_newest: np.ndarray | None

    @classmethod
    def of(
        cls,
        truth: TickTruth,
        timing: ImageTiming | None,
        T_w_b_est: np.ndarray,
        T_b_c_est: np.ndarray | None,
        cov_T_w_b: np.ndarray | None,
        cov_T_b_c: np.ndarray | None,
        T_w_b_newest: np.ndarray | None,
    ) -> _Told:
        """``evaluate_tick``'s arguments with its defaults: the true mount, the newest pose
        of ``timing``, the simulator's time."""
        T_b_c_est = truth.T_b_c if T_b_c_est is None else T_b_c_est
        # The estimator stamps the image with its exposure time, not the simulator's.
        t_s = truth.t_s if timing is None else timing.exposure_pose_s
        if T_w_b_newest is None and timing is not None:
            # A user's function is shown the newest pose too (the stale-pose mistake, vnav.plugin).
            T_w_b_newest = timing.T_w_b_latest
        return cls(t_s, T_w_b_est, T_b_c_est, cov_T_w_b, cov_T_b_c, T_w_b_newest)

    def update(
        self, localizer: Localizer, detections: list[ConeDetection], depth_m: np.ndarray | None
    ) -> list[ConeEstimates]:
        """Every estimate of each detection, from ``localizer`` told this (``Localizer.update``)."""
        return localizer.update(
            self.t_s,
            detections,
            depth_m,
            self.T_w_b_est,
            self.T_b_c_est,
            cov_T_w_b=self.cov_T_w_b,
            cov_T_b_c=self.cov_T_b_c,
            T_w_b_newest=self.T_w_b_newest,
        )


@dataclass(frozen=True)
class _TruthView:
    """What a tick's record holds that depends on the truth alone.

    Attributes
    ----------
    gimbal_locked : bool
        Whether ``rpy_rad`` is at the gimbal lock.
    rpy_rad : ndarray, shape (3,)
        Roll, pitch, yaw of ``R_w_b`` (``vnav.so3.to_rpy``), radians.
    cones_in_view : list of int
        True cones fully in view and tall enough to count (``CONTRACT_DOMAIN``).
    """

    gimbal_locked: bool
    rpy_rad: np.ndarray
    cones_in_view: list[int]


def _truth_view(truth: TickTruth, camera: PinholeCamera, seen: TickRecord | None) -> _TruthView:
    """The attitude, gimbal-lock flag and cones in view at ``truth``: ``seen``'s if given."""
    if seen is not None:
        return _TruthView(seen.gimbal_locked, seen.rpy_rad, seen.cones_in_view)
    R_w_b = truth.T_w_b[:3, :3]
    T_w_c = truth.T_w_b @ truth.T_b_c
    # One tolerance for the flag and for the angles (so3's default): a tick flagged
    # locked is exactly one whose angles to_rpy computed with roll = 0.
    locked = bool(so3.gimbal_locked(R_w_b))
    rpy_rad = so3.to_rpy(R_w_b, warn=False)
    in_view = cones_fully_in_view(truth.cones_w, camera, T_w_c, CONTRACT_DOMAIN.min_height_px)
    return _TruthView(locked, rpy_rad, in_view)


def _detection_records(
    truth: TickTruth,
    detections: list[ConeDetection],
    estimates: list[ConeEstimates],
    in_view: list[int],
) -> list[DetectionRecord]:
    """Each detection's estimates matched to the nearest true cone and compared with it."""
    cone_of = _match(estimates, truth.cones_w)
    T_c_w = se3.invert(truth.T_w_b @ truth.T_b_c)
    estimates_w = [{m: p for m, p in e.items() if p is not None} for e in estimates]
    scores = _nees_by_detection(estimates, estimates_w, cone_of, truth.cones_w)
    return [
        _compare(d, e, est_w, cone_of.get(i), truth.cones_w, T_c_w, in_view, scores[i])
        for i, (d, e, est_w) in enumerate(zip(detections, estimates, estimates_w, strict=True))
    ]


def _with_newest_pose(
    records: list[DetectionRecord],
    truth: TickTruth,
    told: _Told,
    timing: ImageTiming | None,
    localizer: Localizer,
    depth_m: np.ndarray | None,
) -> list[DetectionRecord]:
    """``records`` with the newest-pose estimate (``_with_latest``) when ``timing`` has that
    pose."""
    if timing is None or timing.T_w_b_latest is None:
        return records
    return [
        _with_latest(r, timing, told.T_w_b_est, told.T_b_c_est, truth, localizer, depth_m)
        for r in records
    ]


def _with_depth_kept(
    records: list[DetectionRecord], depth_m: np.ndarray | None
) -> list[DetectionRecord]:
    """``records`` with each detection's depth under its mask, when there is a depth image."""
    if depth_m is None:
        return records
    return [
        dataclasses.replace(r, depth_under_mask_m=_under_mask(r.detection, depth_m))
        for r in records
    ]


def _tick_record(
    truth: TickTruth,
    told: _Told,
    view: _TruthView,
    records: list[DetectionRecord],
    timing: ImageTiming | None,
) -> TickRecord:
    """The tick's record: the truth, what the estimator was told, and its detections."""
    return TickRecord(
        tick=truth.tick,
        t_s=truth.t_s,
        T_w_b=truth.T_w_b,
        T_w_b_est=told.T_w_b_est,
        T_b_c=truth.T_b_c,
        T_b_c_est=told.T_b_c_est,
        quat_xyzw=truth.quat_xyzw,
        rpy_rad=view.rpy_rad,
        gimbal_locked=view.gimbal_locked,
        cones_in_view=view.cones_in_view,
        detections=records,
        reference_error_m=truth.reference_error_m,
        v_w_b_mps=truth.v_w_b_mps,
        timing=timing,
        cov_T_w_b_est=told.cov_T_w_b,
    )


def _under_mask(detection: ConeDetection, depth_m: np.ndarray) -> np.ndarray:
    """The depth image's values under ``detection``'s mask, in its dtype (a copy)."""
    x0, y0, w, h = detection.bbox
    return depth_m[y0 : y0 + h, x0 : x0 + w][detection.mask]


def _depth_of(record: TickRecord, camera_shape: tuple[int, int]) -> np.ndarray | None:
    """A depth image holding the tick's kept depth under every detection's mask (NaN
    elsewhere, which no method reads: ``vnav.estimators.depth_under_mask`` refuses a NaN under
    a mask); None if the tick kept none (no depth, or not kept)."""
    kept = [d.depth_under_mask_m for d in record.detections]
    if not kept or any(k is None for k in kept):
        return None
    depth_m = np.full(camera_shape, np.nan, dtype=kept[0].dtype)
    for d, values in zip(record.detections, kept, strict=True):
        x0, y0, w, h = d.detection.bbox
        depth_m[y0 : y0 + h, x0 : x0 + w][d.detection.mask] = values
    return depth_m


def reevaluate(
    ticks: list[TickRecord],
    cones_w: np.ndarray,
    localizer: Localizer,
    T_b_c_est: np.ndarray,
    cov_T_b_c: np.ndarray | None = None,
) -> list[TickRecord]:
    """A run's ticks estimated again with the camera mount ``T_b_c_est`` (``evaluate_tick``).

    Each tick is given what it was given in the run: its detections, the depth under their
    masks (kept by ``evaluate_tick(keep_depth=True)``; a tick without it has no depth), the
    body pose looked up at its exposure stamp and that pose's covariance. Only the mount
    differs. The newest-pose estimate (``DetectionRecord.latest_w``) is not made again, nor
    what depends on the truth alone (the attitude, the cones in view: ``evaluate_tick``'s
    ``seen``).

    Parameters
    ----------
    ticks : list of TickRecord
        The run's ticks, in the order they were evaluated.
    cones_w : ndarray, shape (N, 3)
        True base centres of the cones, metres.
    localizer : vnav.localize.Localizer
        A new estimator, configured as the run's (its camera, far plane and noise).
    T_b_c_est : ndarray, shape (4, 4)
        The mount to estimate with, in place of each tick's ``T_b_c_est``.
    cov_T_b_c : ndarray, shape (6, 6), optional
        Its covariance.

    Returns
    -------
    list of TickRecord
        One per tick, in order, with ``T_b_c_est`` the given mount.
    """
    shape = (localizer.camera.height, localizer.camera.width)
    out = []
    for t in ticks:
        truth = TickTruth(
            t.tick, t.t_s, t.T_w_b, t.T_b_c, t.quat_xyzw, cones_w, t.reference_error_m, t.v_w_b_mps
        )
        timing = None if t.timing is None else dataclasses.replace(t.timing, T_w_b_latest=None)
        out.append(
            evaluate_tick(
                truth,
                [d.detection for d in t.detections],
                _depth_of(t, shape),
                localizer,
                t.T_w_b_est,
                timing,
                T_b_c_est=T_b_c_est,
                cov_T_w_b=t.cov_T_w_b_est,
                cov_T_b_c=cov_T_b_c,
                # Users' functions are shown what they were in the run (vnav.plugin).
                T_w_b_newest=None if t.timing is None else t.timing.T_w_b_latest,
                # The same truth: its attitude and cones in view are the run's.
                seen=t,
            )
        )
    return out


def _with_latest(
    record: DetectionRecord,
    timing: ImageTiming,
    T_w_b_est: np.ndarray,
    T_b_c_est: np.ndarray,
    truth: TickTruth,
    localizer: Localizer,
    depth_m: np.ndarray | None,
) -> DetectionRecord:
    """``record`` with its latest-pose estimate (``NEWEST_POSE_METHOD``), error and prediction.

    The prediction is first order: a pose older by ``dt`` is off by the body's motion over
    ``dt``, ``|v| dt`` in position and ``|omega| dt`` in attitude, and the attitude error
    swings a point at ``range`` by ``range |omega| dt`` (an upper bound: the part of the
    lever arm along the rotation axis does not move).
    """
    if record.cone_index is None or depth_m is None or record.range_m is None:
        return record
    T_w_b_latest = timing.T_w_b_latest
    assert T_w_b_latest is not None
    if np.array_equal(T_w_b_latest, T_w_b_est):  # the same pose: the same estimate
        p_w = record.estimates_w.get(NEWEST_POSE_METHOD)
    else:
        p_w = localizer.estimate_with_pose(
            NEWEST_POSE_METHOD, record.detection, depth_m, T_w_b_latest, T_b_c_est
        )
    if p_w is None:
        return record
    return dataclasses.replace(
        record,
        latest_w=p_w,
        latest_error_m=float(metrics.position_error(truth.cones_w[record.cone_index], p_w)[0]),
        predicted_latest_error_m=timing.true_motion_m + record.range_m * timing.true_motion_rad,
    )


def _match(estimates: list[ConeEstimates], cones_w: np.ndarray) -> dict[int, int]:
    """Detection index -> true cone index, matched on the ground plane by the best estimate."""
    anchors = [e.best for e in estimates]
    usable = [i for i, a in enumerate(anchors) if a is not None]
    if not usable:
        return {}
    pairs = metrics.match_nearest(
        cones_w[:, :2], np.array([anchors[i][:2] for i in usable]), max_distance=MATCH_GATE_M
    )
    return {usable[j]: i for i, j in pairs}


def _error_m(p_true_w: np.ndarray, p_w: np.ndarray) -> float:
    """The distance of an estimate from the true cone, metres."""
    return float(metrics.position_error(p_true_w, p_w)[0])


def _errors_m(p_true_w: np.ndarray, estimates_w: dict[str, np.ndarray]) -> dict[str, float]:
    """``_error_m`` of every method's estimate, in one call (each row's distance is summed as
    a single point's is: the same number)."""
    if not estimates_w:
        return {}
    p_w = np.array(list(estimates_w.values()))
    errors = metrics.position_error(np.broadcast_to(p_true_w, p_w.shape), p_w)
    return dict(zip(estimates_w, map(float, errors), strict=True))


def _has_nees(scored: tuple[float, int]) -> bool:
    """Whether a NEES counts: a covariance of rank 0 claims an exact estimate, it has no NEES
    (0 degrees of freedom), and counting it would make the band's count differ from its
    degrees of freedom."""
    return scored[1] > 0


def _without(by_method: dict, drop: str | None) -> dict:
    """A copy of ``by_method`` without the key ``drop``."""
    return {m: v for m, v in by_method.items() if m != drop}


def with_method(
    record: DetectionRecord,
    name: str,
    estimate: np.ndarray | NoEstimate,
    cov_w: np.ndarray | None,
    cones_w: np.ndarray,
    *,
    drop: str | None = None,
) -> DetectionRecord:
    """``record`` with one more method's estimate (or its reason for none), compared with the
    truth as ``evaluate_tick`` compares every method's: its error and NEES against the matched
    cone. What judging another function on a finished run's detections needs
    (``scenarios.grading``); the record itself is left as it was.

    Parameters
    ----------
    record : DetectionRecord
    name : str
        The method's name; it must not be in ``record`` already.
    estimate : ndarray, shape (3,), or NoEstimate
    cov_w : ndarray, shape (3, 3), or None
        The estimate's world covariance, m^2 (None with a NoEstimate).
    cones_w : ndarray, shape (N, 3)
        True base centres of the cones, metres (those the run matched against).
    drop : str, optional
        A method whose entries are left out of the new record.
    """
    estimates_w = _without(record.estimates_w, drop)
    no_estimate = _without(record.no_estimate, drop)
    covariances_w = _without(record.covariances_w, drop)
    errors_m = _without(record.errors_m, drop)
    scored = _without(record.nees, drop)
    if isinstance(estimate, NoEstimate):
        no_estimate[name] = estimate
    else:
        estimates_w[name] = estimate
        covariances_w[name] = cov_w
        if record.cone_index is not None:
            p_true_w = cones_w[record.cone_index]
            errors_m[name] = _error_m(p_true_w, estimate)
            value = nees(estimate - p_true_w, cov_w)
            if _has_nees(value):
                scored[name] = value
    return dataclasses.replace(
        record,
        estimates_w=estimates_w,
        no_estimate=no_estimate,
        covariances_w=covariances_w,
        errors_m=errors_m,
        nees=scored,
    )


def _nees_by_detection(
    estimates: list[ConeEstimates],
    estimates_w: list[dict[str, np.ndarray]],
    cone_of: dict[int, int],
    cones_w: np.ndarray,
) -> list[list[tuple[float, int]] | None]:
    """Each matched detection's ``nees_many`` of its estimates (in ``estimates_w``'s order)
    against its true cone, None for an unmatched one: every detection's as one stack (the
    same numbers as a call per detection: ``nees_many`` scores a stack matrix by matrix).
    None too for a detection estimated without its covariances (a ``Localizer`` made
    ``with_covariance=False``, the calibrated run's second pass: its errors alone are
    read), whose records then have no NEES."""
    errors, covs, counts = [], [], []
    for i, (e, est_w) in enumerate(zip(estimates, estimates_w, strict=True)):
        cone_index = cone_of.get(i)
        covariances = e.cov_w_by_method
        if cone_index is None or not all(m in covariances for m in est_w):
            counts.append(None)
            continue
        p_true_w = cones_w[cone_index]
        errors.extend(p - p_true_w for p in est_w.values())
        covs.extend(e.cov_w_by_method[m] for m in est_w)
        counts.append(len(est_w))
    scored = nees_many(np.array(errors).reshape(-1, 3), np.array(covs).reshape(-1, 3, 3))
    out: list[list[tuple[float, int]] | None] = []
    start = 0
    for n in counts:
        out.append(None if n is None else scored[start : start + n])
        start += n or 0
    return out


def _compare(
    detection: ConeDetection,
    estimates: ConeEstimates,
    estimates_w: dict[str, np.ndarray],
    cone_index: int | None,
    cones_w: np.ndarray,
    T_c_w: np.ndarray,
    in_view: list[int],
    scores: list[tuple[float, int]] | None,
) -> DetectionRecord:
    """One detection's record: its estimates (``estimates_w``, those ``estimates`` gives)
    and, if matched, their errors, NEES (``scores``, in ``estimates_w``'s order,
    ``_nees_by_detection``; None: not scored) and the range."""
    no_estimate = dict(estimates.no_estimate)
    covariances_w = dict(estimates.cov_w_by_method)
    if cone_index is None:
        return DetectionRecord(
            detection, estimates_w, no_estimate=no_estimate, covariances_w=covariances_w
        )
    p_true_w = cones_w[cone_index]
    p_c_true = se3.apply(T_c_w, p_true_w)
    range_m = float(np.linalg.norm(p_c_true))
    errors_m = _errors_m(p_true_w, estimates_w)
    scored = {} if scores is None else dict(zip(estimates_w, scores, strict=True))
    nees_by_method = {m: v for m, v in scored.items() if _has_nees(v)}
    in_contract = cone_index in in_view and CONTRACT_DOMAIN.contains_range(range_m)
    return DetectionRecord(
        detection,
        estimates_w,
        cone_index,
        errors_m,
        range_m,
        p_c_true,
        in_contract,
        no_estimate,
        covariances_w=covariances_w,
        nees=nees_by_method,
    )
