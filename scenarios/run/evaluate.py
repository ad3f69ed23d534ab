"""Evaluate one camera tick: localise every detection and compare it with the truth.

This is where a tick's estimates meet the ground truth; it needs the truth as numbers, not
the simulator that produced them (``scenarios.run.runner`` reads them out of MuJoCo)::

    estimate p_w per method   <- vnav.localize.localize(det, camera, T_w_b_est, T_b_c_est, depth)
             and its covariance  (with the noise and pose covariances the estimator is told)
    match                     <- each detection's best estimate to the nearest true cone,
                                 on the ground plane (vnav.metrics.match_nearest)
    compare  error = |p_w - truth|, its NEES against the covariance, range, contract domain
             (vnav.methods.CONTRACT_DOMAIN)
    latest   the depth_image estimate again with the newest pose received when the image
             arrived (what a pipeline ignoring stamps does), its error and the first-order
             prediction of that error from the body's true motion, |dp| + range |dtheta|
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
from vnav.estimators import NoEstimate, estimate_from_depth
from vnav.localize import ConeEstimates, localize
from vnav.methods import CONTRACT_DOMAIN
from vnav.noise_model import NOISELESS, NoiseModel
from vnav.sensor_noise import keypoint_std_px
from vnav.tracking import ApexTracker
from vnav.uncertainty import compose, nees

__all__ = ["MATCH_GATE_M", "TickTruth", "evaluate_tick"]

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
    """

    tick: int
    t_s: float
    T_w_b: np.ndarray
    T_b_c: np.ndarray
    quat_xyzw: np.ndarray
    cones_w: np.ndarray
    reference_error_m: float | None = None


def evaluate_tick(
    truth: TickTruth,
    detections: list[ConeDetection],
    depth_m: np.ndarray | None,
    camera: PinholeCamera,
    T_w_b_est: np.ndarray,
    far_m: float,
    timing: ImageTiming | None = None,
    *,
    T_b_c_est: np.ndarray | None = None,
    noise: NoiseModel = NOISELESS,
    cov_T_w_b: np.ndarray | None = None,
    cov_T_b_c: np.ndarray | None = None,
    tracker: ApexTracker | None = None,
) -> TickRecord:
    """Localise every detection with the estimator's pose and compare with the truth.

    Parameters
    ----------
    truth : TickTruth
    detections : list of ConeDetection
        From ``vnav.detect.detect_cones`` on this tick's image.
    depth_m : ndarray, shape (H, W), or None
        This tick's planar depth image, metres.
    camera : PinholeCamera
    T_w_b_est : ndarray, shape (4, 4)
        The body pose the estimator looked up at the exposure stamp (the truth plus any pose
        noise, interpolated in the pose stream).
    far_m : float
        Depth at or beyond which a pixel has no return.
    timing : ImageTiming, optional
        The image's stamps and the newest pose received when it arrived: with it, every
        matched detection also gets the ``depth_image`` estimate made with that pose
        (``DetectionRecord.latest_w``), its error and its predicted error.
    T_b_c_est : ndarray, shape (4, 4), optional
        The camera mount the estimator is told (the truth's, ``truth.T_b_c``, by default).
    noise : NoiseModel
        The sensors' noise the estimator is told (its image and depth figures here).
    cov_T_w_b, cov_T_b_c : ndarray, shape (6, 6), optional
        The covariances the estimator is told for ``T_w_b_est`` and ``T_b_c_est``
        (``vnav.localize``).
    tracker : ApexTracker, optional
        The run's apex tracks (``vnav.tracking``): with it, each detection's apex joins its
        track and the ``triangulated`` estimate comes from the track's rays.

    Returns
    -------
    TickRecord
    """
    T_w_c = truth.T_w_b @ truth.T_b_c
    R_w_b = truth.T_w_b[:3, :3]
    # One tolerance for the flag and for the angles (so3's default): a tick flagged locked is
    # exactly one whose angles to_rpy computed with roll = 0.
    locked = bool(so3.gimbal_locked(R_w_b))
    rpy_rad = so3.to_rpy(R_w_b, warn=False)
    in_view = cones_fully_in_view(truth.cones_w, camera, T_w_c, CONTRACT_DOMAIN.min_height_px)
    T_b_c_est = truth.T_b_c if T_b_c_est is None else T_b_c_est
    told = {"noise": noise, "cov_T_w_b": cov_T_w_b, "cov_T_b_c": cov_T_b_c}
    estimates = [
        localize(d, camera, T_w_b_est, T_b_c_est, depth_m, far_m=far_m, **told) for d in detections
    ]
    if tracker is not None:
        # The tracker stamps each ray with the estimator's exposure time, not the simulator's.
        t_s = truth.t_s if timing is None else timing.exposure_pose_s
        estimates = _triangulated(tracker, t_s, estimates, T_w_b_est, T_b_c_est, **told)
    cone_of = _match(estimates, truth.cones_w)
    T_c_w = se3.invert(T_w_c)
    records = [
        _compare(d, e, cone_of.get(i), truth.cones_w, T_c_w, in_view)
        for i, (d, e) in enumerate(zip(detections, estimates, strict=True))
    ]
    if timing is not None and timing.T_w_b_latest is not None:
        records = [
            _with_latest(r, timing, T_w_b_est, T_b_c_est, truth, camera, depth_m, far_m)
            for r in records
        ]
    return TickRecord(
        tick=truth.tick,
        t_s=truth.t_s,
        T_w_b=truth.T_w_b,
        T_w_b_est=T_w_b_est,
        T_b_c=truth.T_b_c,
        T_b_c_est=T_b_c_est,
        quat_xyzw=truth.quat_xyzw,
        rpy_rad=rpy_rad,
        gimbal_locked=locked,
        cones_in_view=in_view,
        detections=records,
        reference_error_m=truth.reference_error_m,
        timing=timing,
    )


def _with_latest(
    record: DetectionRecord,
    timing: ImageTiming,
    T_w_b_est: np.ndarray,
    T_b_c_est: np.ndarray,
    truth: TickTruth,
    camera: PinholeCamera,
    depth_m: np.ndarray | None,
    far_m: float,
) -> DetectionRecord:
    """``record`` with its latest-pose ``depth_image`` estimate, error and prediction.

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
        p_w = record.estimates_w.get("depth_image")
    else:
        p_w = estimate_from_depth(
            record.detection, depth_m, camera, T_w_b_latest @ T_b_c_est, far_m=far_m
        )
    if p_w is None:
        return record
    return dataclasses.replace(
        record,
        latest_w=p_w,
        latest_error_m=float(metrics.position_error(truth.cones_w[record.cone_index], p_w)[0]),
        predicted_latest_error_m=timing.true_motion_m + record.range_m * timing.true_motion_rad,
    )


_ZERO_6 = np.zeros((6, 6))


def _triangulated(
    tracker: ApexTracker,
    t_s: float,
    estimates: list[ConeEstimates],
    T_w_b: np.ndarray,
    T_b_c: np.ndarray,
    *,
    noise: NoiseModel,
    cov_T_w_b: np.ndarray | None,
    cov_T_b_c: np.ndarray | None,
) -> list[ConeEstimates]:
    """Each detection's ``triangulated`` estimate from its apex track (``vnav.tracking``),
    merged into its ``ConeEstimates``: the apex fitted along the image vertical the pose gives
    (``ConeEstimates.apex_uv``), its noise the keypoint table's along-figure in every
    direction (``vnav.sensor_noise``), the camera pose's covariance composed as
    ``vnav.localize`` composes it."""
    T_w_c = T_w_b @ T_b_c
    cov_T_w_c = _ZERO_6 if cov_T_w_b is None else cov_T_w_b
    if cov_T_b_c is not None:
        cov_T_w_c = compose(T_w_b, cov_T_w_c, T_b_c, cov_T_b_c)[1]
    apexes = {i: e.apex_uv for i, e in enumerate(estimates) if e.apex_uv is not None}
    std_px = keypoint_std_px("apex", noise.intensity_std_grey)[0]
    tracked = tracker.update(
        t_s,
        T_w_c,
        np.array(list(apexes.values())).reshape(-1, 2),
        cov_T_w_c=cov_T_w_c,
        cov_uv=std_px**2 * np.eye(2),
    )
    out = list(estimates)
    for i, t in zip(apexes, tracked, strict=True):
        e = estimates[i]
        points = dict(e.p_w_by_method)
        reasons = {m: r for m, r in e.no_estimate.items() if m != "triangulated"}
        covs = dict(e.cov_w_by_method)
        if t.p_w is None:
            reasons["triangulated"] = NoEstimate.PARALLAX
        else:
            points["triangulated"] = t.p_w
            covs["triangulated"] = t.cov_w
        out[i] = ConeEstimates(points, reasons, covs, e.apex_uv)
    return out


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


def _compare(
    detection: ConeDetection,
    estimates: ConeEstimates,
    cone_index: int | None,
    cones_w: np.ndarray,
    T_c_w: np.ndarray,
    in_view: list[int],
) -> DetectionRecord:
    """One detection's record: its estimates and, if matched, their errors and the range."""
    estimates_w = {m: p for m, p in estimates.items() if p is not None}
    no_estimate = dict(estimates.no_estimate)
    covariances_w = dict(estimates.cov_w_by_method)
    if cone_index is None:
        return DetectionRecord(
            detection, estimates_w, no_estimate=no_estimate, covariances_w=covariances_w
        )
    p_true_w = cones_w[cone_index]
    p_c_true = se3.apply(T_c_w, p_true_w)
    range_m = float(np.linalg.norm(p_c_true))
    errors_m = {m: float(metrics.position_error(p_true_w, p)[0]) for m, p in estimates_w.items()}
    # A covariance of rank 0 claims an exact estimate: it has no NEES (0 degrees of freedom),
    # and counting it would make the band's count differ from its degrees of freedom.
    scored = {m: nees(p - p_true_w, covariances_w[m]) for m, p in estimates_w.items()}
    nees_by_method = {m: v for m, v in scored.items() if v[1] > 0}
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
