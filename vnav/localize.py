"""From a cone detection to the cone's base-centre position in the world, by every method.

``localize`` validates its inputs once, builds one ``vnav.silhouette.SilhouetteView``
of the detection and runs each estimator of ``vnav.estimators`` on it; the methods and
their accuracy contract are declared in ``vnav.methods``.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field

import numpy as np

from vnav import covariance, se3
from vnav.camera import PinholeCamera, check_depth_image
from vnav.cone import TRAFFIC_CONE, ConeModel
from vnav.detect import ConeDetection, check_detection
from vnav.estimators import (
    NoEstimate,
    depth_image_from_view,
    depth_under_mask,
    ground_plane_from_view,
    known_height_from_view,
    naive,
)
from vnav.methods import METHOD_NAMES, PREFERENCE
from vnav.sensor_noise import NOISELESS, SensorNoise
from vnav.silhouette import SilhouetteView
from vnav.uncertainty import check_covariance, compose_covariance

_ZERO_6 = np.zeros((6, 6))
_ZERO_6.flags.writeable = False

__all__ = ["ConeEstimates", "localize"]


@dataclass(frozen=True)
class ConeEstimates(Mapping[str, "np.ndarray | None"]):
    """The base-centre position of one cone in the world frame by each method, metres.

    A read-only mapping from method name (``vnav.methods.METHOD_NAMES``, in that order) to a
    (3,) float64 array, or None when the method gives no estimate; each method is also an
    attribute (``estimates.depth_image``).

    Parameters
    ----------
    p_w_by_method : mapping of str to ndarray, shape (3,), or None
        One entry per method; a method left out gives no estimate.
    no_estimate : mapping of str to NoEstimate, optional
        Why a method gave no estimate (``vnav.estimators.NoEstimate``), for methods whose
        estimate is None; ``localize`` gives one for each.
    cov_w_by_method : mapping of str to ndarray, shape (3, 3), optional
        The covariance of each estimate in the world frame, m^2 (``vnav.covariance``);
        ``localize`` gives one for every estimate.
    apex_uv : ndarray, shape (2,), optional
        The apex pixel the estimators fitted (``SilhouetteView.apex_keypoint``), or None:
        what a tracker over several images follows (``vnav.tracking``).

    Raises
    ------
    ValueError
        On a name that is not a method, a reason given beside an estimate, or a covariance
        given for a method without an estimate.
    """

    p_w_by_method: Mapping[str, np.ndarray | None]
    no_estimate: Mapping[str, NoEstimate] = field(default_factory=dict)
    cov_w_by_method: Mapping[str, np.ndarray] = field(default_factory=dict)
    apex_uv: np.ndarray | None = None

    def __post_init__(self) -> None:
        unknown = sorted((set(self.p_w_by_method) | set(self.no_estimate)) - set(METHOD_NAMES))
        if unknown:
            raise ValueError(f"unknown methods {unknown}; valid: {list(METHOD_NAMES)}")
        object.__setattr__(
            self, "p_w_by_method", {m: self.p_w_by_method.get(m) for m in METHOD_NAMES}
        )
        both = [m for m in self.no_estimate if self.p_w_by_method[m] is not None]
        if both:
            raise ValueError(f"no_estimate gives a reason for methods with an estimate: {both}")
        object.__setattr__(self, "no_estimate", dict(self.no_estimate))
        stray = [m for m in self.cov_w_by_method if self.p_w_by_method.get(m) is None]
        if stray:
            raise ValueError(f"cov_w_by_method gives a covariance for methods without one: {stray}")
        object.__setattr__(self, "cov_w_by_method", dict(self.cov_w_by_method))

    def __getitem__(self, name: str) -> np.ndarray | None:
        return self.p_w_by_method[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self.p_w_by_method)

    def __len__(self) -> int:
        return len(self.p_w_by_method)

    def __getattr__(self, name: str) -> np.ndarray | None:
        if name in METHOD_NAMES:
            return self.p_w_by_method[name]
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def as_dict(self) -> dict[str, np.ndarray | None]:
        """``{method name: p_w or None}`` in the order of ``METHOD_NAMES``."""
        return dict(self.p_w_by_method)

    def covariance(self, name: str) -> np.ndarray | None:
        """The 3x3 world covariance of method ``name``'s estimate, m^2, or None without one."""
        if name not in METHOD_NAMES:
            raise ValueError(f"unknown method {name!r}; valid: {list(METHOD_NAMES)}")
        return self.cov_w_by_method.get(name)

    @property
    def best(self) -> np.ndarray | None:
        """The first available estimate in ``vnav.methods.PREFERENCE`` order, or None."""
        return _best(self.p_w_by_method)


def _best(p_w_by_method: Mapping[str, np.ndarray | None]) -> np.ndarray | None:
    return next((p for m in PREFERENCE if (p := p_w_by_method.get(m)) is not None), None)


def localize(
    detection: ConeDetection,
    camera: PinholeCamera,
    T_w_b: np.ndarray,
    T_b_c: np.ndarray,
    depth: np.ndarray | None = None,
    cone: ConeModel = TRAFFIC_CONE,
    far_m: float = np.inf,
    *,
    noise: SensorNoise = NOISELESS,
    cov_T_w_b: np.ndarray | None = None,
    cov_T_b_c: np.ndarray | None = None,
    with_covariance: bool = True,
) -> ConeEstimates:
    """Every estimate of one detected cone's base centre in the world frame.

    Parameters
    ----------
    detection : ConeDetection
        From ``vnav.detect.detect_cones``.
    camera : PinholeCamera
    T_w_b : ndarray, shape (4, 4)
        Body (FLU) pose in the world.
    T_b_c : ndarray, shape (4, 4)
        Camera (optical frame) pose on the body; ``T_w_c = T_w_b @ T_b_c``.
    depth : ndarray, shape (H, W), float32/float64, optional
        Planar z-depth, metres; without it ``depth_image`` is None.
    cone : ConeModel
    far_m : float
        Depth at or beyond which a pixel has no return.
    noise : SensorNoise
        The image and depth noise (``vnav.sensor_noise``); default none.
    cov_T_w_b, cov_T_b_c : ndarray, shape (6, 6), optional
        Left-perturbation covariances of the body pose and of the camera mount
        (docs/CONVENTIONS.md, "Uncertainty"); default zero (known exactly).
    with_covariance : bool
        False skips the covariances (``cov_w_by_method`` is then empty): for a caller that
        only wants the points.

    Returns
    -------
    ConeEstimates
        A method's entry is None when it gives no estimate (see each ``estimate_from_*`` in
        ``vnav.estimators``), and ``no_estimate`` says why. Every entry is None when the
        detection touches the image border (``touches_border``, ``NoEstimate.BORDER``): part of
        the cone may be outside the image (apex or base missing, the depth-image axis fit
        unconstrained), and no estimate is better than a wrong one. Inputs are still validated
        first. The naive estimate is built from the best one (``ConeEstimates.best``) in camera
        coordinates. Every estimate comes with its covariance (``cov_w_by_method``): the
        camera pose's (``cov_T_w_b`` and ``cov_T_b_c`` composed), the keypoints' and the
        depth's, first order (``vnav.covariance``).

    Raises
    ------
    ValueError
        On malformed transforms, a depth image of the wrong dtype or size, or non-finite depth
        under the detection's mask.
    """
    # Validate once, in the order the estimators would (detection, depth, T_w_c), then run
    # their unvalidated cores on one shared view.
    T_w_b = se3.check_pose(T_w_b, "T_w_b")
    T_b_c = se3.check_pose(T_b_c, "T_b_c")
    check_detection(detection, camera)
    if depth is not None:
        check_depth_image(depth, camera)
    T_w_c = se3.check_pose(T_w_b @ T_b_c, "T_w_c")
    cov_T_w_b = _ZERO_6 if cov_T_w_b is None else check_covariance(cov_T_w_b, (6, 6), "cov_T_w_b")
    cov_T_b_c = _ZERO_6 if cov_T_b_c is None else check_covariance(cov_T_b_c, (6, 6), "cov_T_b_c")
    z_c = None if depth is None else depth_under_mask(detection, depth)
    if detection.touches_border:
        return ConeEstimates({}, dict.fromkeys(METHOD_NAMES, NoEstimate.BORDER))
    view = SilhouetteView(detection, camera, T_w_c)
    from_depth = (
        NoEstimate.NO_DEPTH if z_c is None else depth_image_from_view(view, z_c, cone, far_m)
    )
    found = {
        "depth_image": from_depth,
        "ground_plane": ground_plane_from_view(view, cone),
        "known_height": known_height_from_view(view, cone),
        # Several images' work (vnav.tracking): scenarios.evaluate fills it in.
        "triangulated": NoEstimate.ONE_IMAGE,
    }
    no_estimate = {m: r for m, r in found.items() if isinstance(r, NoEstimate)}
    p_w_by_method = {m: p for m, p in found.items() if m not in no_estimate}
    apex_uv = view.apex_keypoint(cone)  # memoised: ground_plane's bottom pixel fitted it
    if not p_w_by_method:
        no_estimate["naive"] = NoEstimate.NO_OTHER_ESTIMATE
        return ConeEstimates({}, no_estimate, apex_uv=apex_uv)
    best_method = next(m for m in PREFERENCE if m in p_w_by_method)
    p_c = np.array(view.camera_coordinates(p_w_by_method[best_method]))
    p_w_by_method["naive"] = naive(p_c, T_w_b[:3, 3])
    if not with_covariance:
        return ConeEstimates(p_w_by_method, no_estimate, apex_uv=apex_uv)
    cov_w = _covariances(
        p_w_by_method,
        view,
        camera,
        T_w_b=T_w_b,
        cov_T_w_b=cov_T_w_b,
        T_w_c=T_w_c,
        cov_T_w_c=compose_covariance(T_w_b, cov_T_w_b, cov_T_b_c) if cov_T_b_c.any() else cov_T_w_b,
        n_depth_points=detection.area_px // 2,
        noise=noise,
        cone=cone,
    )
    return ConeEstimates(p_w_by_method, no_estimate, cov_w, apex_uv)


def _covariances(
    p_w_by_method: dict[str, np.ndarray],
    view: SilhouetteView,
    camera: PinholeCamera,
    *,
    T_w_b: np.ndarray,
    cov_T_w_b: np.ndarray,
    T_w_c: np.ndarray,
    cov_T_w_c: np.ndarray,
    n_depth_points: int,
    noise: SensorNoise,
    cone: ConeModel,
) -> dict[str, np.ndarray]:
    """Each estimate's world covariance (``vnav.covariance``); the naive one's from the best
    estimate's (``PREFERENCE``), as its point is."""
    cov_w: dict[str, np.ndarray] = {}
    if "depth_image" in p_w_by_method:
        cov_w["depth_image"] = covariance.depth_image_cov(
            T_w_c, cov_T_w_c, p_w_by_method["depth_image"], n_depth_points, noise
        )
    if "ground_plane" in p_w_by_method:
        cov_w["ground_plane"] = covariance.ground_plane_cov(
            view, camera, T_w_c, cov_T_w_c, p_w_by_method["ground_plane"], noise, cone
        )
    if "known_height" in p_w_by_method:
        cov_w["known_height"] = covariance.known_height_cov(
            view, camera, T_w_c, cov_T_w_c, p_w_by_method["known_height"], noise, cone
        )
    best_method = next(m for m in PREFERENCE if m in cov_w)
    cov_w["naive"] = covariance.naive_cov(T_w_b, cov_T_w_b, T_w_c[:3, :3].T, cov_w[best_method])
    return cov_w
