"""From cone detections to the cones' base-centre positions in the world, by every method.

``localize`` validates its inputs once, builds one ``vnav.observation.Observation`` of the
detection and runs each single-image method's estimator on it, then the methods built from
the best of those (``vnav.methods``: the methods, their estimators and their accuracy
contract are declared there; nothing here names one). ``Localizer`` does the same image
after image and adds the methods that need several images, with the state they keep over a
run; it also re-estimates a detection with another pose (the newest one received when the
image arrived, as a pipeline ignoring stamps would).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from vnav import se3
from vnav.camera import PinholeCamera, check_depth_image
from vnav.cone import TRAFFIC_CONE, ConeModel
from vnav.detect import ConeDetection, check_detection
from vnav.estimators import NoEstimate, depth_under_mask
from vnav.methods import METHOD_NAMES, METHODS, PREFERENCE, Method, active_methods, method
from vnav.noise_model import NOISELESS, NoiseModel
from vnav.observation import Exposure, Observation
from vnav.silhouette import SilhouetteView
from vnav.uncertainty import check_covariance

_ZERO_6 = np.zeros((6, 6))
_ZERO_6.flags.writeable = False

__all__ = ["ConeEstimates", "Localizer", "localize"]


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
    method_names: tuple[str, ...] = METHOD_NAMES

    def __post_init__(self) -> None:
        names = self.method_names
        unknown = sorted((set(self.p_w_by_method) | set(self.no_estimate)) - set(names))
        if unknown:
            raise ValueError(f"unknown methods {unknown}; valid: {list(names)}")
        object.__setattr__(self, "p_w_by_method", {m: self.p_w_by_method.get(m) for m in names})
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
        """``{method name: p_w or None}`` in the order of ``method_names``."""
        return dict(self.p_w_by_method)

    def covariance(self, name: str) -> np.ndarray | None:
        """The 3x3 world covariance of method ``name``'s estimate, m^2, or None without one."""
        if name not in self.method_names:
            raise ValueError(f"unknown method {name!r}; valid: {list(self.method_names)}")
        return self.cov_w_by_method.get(name)

    def with_result(
        self, name: str, result: tuple[np.ndarray, np.ndarray] | NoEstimate
    ) -> ConeEstimates:
        """A copy with method ``name``'s estimate replaced: ``(p_w, cov_w)`` or the reason
        there is none (a several-image method's result, ``Localizer``)."""
        points, reasons = dict(self.p_w_by_method), dict(self.no_estimate)
        covs = dict(self.cov_w_by_method)
        reasons.pop(name, None)
        points.pop(name, None)
        covs.pop(name, None)
        if isinstance(result, NoEstimate):
            reasons[name] = result
        else:
            points[name], covs[name] = result
        return ConeEstimates(points, reasons, covs, self.apex_uv, self.method_names)

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
    noise: NoiseModel = NOISELESS,
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
    noise : NoiseModel
        The sensors' noise (``vnav.noise_model``): its image and depth figures; default none.
    cov_T_w_b, cov_T_b_c : ndarray, shape (6, 6), optional
        Left-perturbation covariances of the body pose and of the camera mount
        (docs/CONVENTIONS.md, "Uncertainty"); default zero (known exactly).
    with_covariance : bool
        False skips the covariances (``cov_w_by_method`` then empty), for the points alone.

    Returns
    -------
    ConeEstimates
        A method's entry is None when it gives no estimate (see each ``estimate_from_*`` in
        ``vnav.estimators``), and ``no_estimate`` says why. Every entry is None when the detection
        touches the image border (``touches_border``, ``NoEstimate.BORDER``): part of the cone may
        be outside the image (apex or base missing, the depth-image axis fit unconstrained), and no
        estimate is better than a wrong one; inputs are still validated first. The naive estimate is
        built from the best one (``ConeEstimates.best``) in camera coordinates. Every estimate has
        its covariance (``cov_w_by_method``): the camera pose's (``cov_T_w_b`` and ``cov_T_b_c``
        composed), the keypoints' and the depth's, first order (``vnav.covariance``).

    Raises
    ------
    ValueError
        On malformed transforms, a depth image of the wrong dtype or size, or non-finite depth
        under the detection's mask.
    """
    exposure = _exposure(
        camera, T_w_b, T_b_c, cone, far_m, noise=noise, cov_T_w_b=cov_T_w_b, cov_T_b_c=cov_T_b_c
    )
    return _localize(_observation(exposure, detection, depth), detection, with_covariance)


def _exposure(
    camera: PinholeCamera,
    T_w_b: np.ndarray,
    T_b_c: np.ndarray,
    cone: ConeModel,
    far_m: float,
    *,
    noise: NoiseModel,
    cov_T_w_b: np.ndarray | None,
    cov_T_b_c: np.ndarray | None,
) -> Exposure:
    """One image's poses and noise, validated."""
    T_w_b = se3.check_pose(T_w_b, "T_w_b")
    T_b_c = se3.check_pose(T_b_c, "T_b_c")
    return Exposure(
        T_w_b=T_w_b,
        T_b_c=T_b_c,
        # The product of two checked rigid transforms is rigid to rounding: not checked again.
        T_w_c=T_w_b @ T_b_c,
        cov_T_w_b=_ZERO_6
        if cov_T_w_b is None
        else check_covariance(cov_T_w_b, (6, 6), "cov_T_w_b"),
        cov_T_b_c=_ZERO_6
        if cov_T_b_c is None
        else check_covariance(cov_T_b_c, (6, 6), "cov_T_b_c"),
        noise=noise,
        camera=camera,
        cone=cone,
        far_m=far_m,
    )


def _observation(
    exposure: Exposure, detection: ConeDetection, depth: np.ndarray | None
) -> Observation | None:
    """One detection in ``exposure``'s image, validated; None for a detection that touches the
    image border (after validating it all the same)."""
    check_detection(detection, exposure.camera)
    if depth is not None:
        check_depth_image(depth, exposure.camera)
    z_c = None if depth is None else depth_under_mask(detection, depth)
    if detection.touches_border:
        return None
    return Observation(exposure, SilhouetteView(detection, exposure.camera, exposure.T_w_c), z_c)


USER_INPUT = "depth_image"
"""The method whose estimate a user's function is given, in the camera frame (``vnav.plugin``)."""

_GROUPED: dict[int, tuple[tuple[Method, ...], tuple[tuple, tuple, tuple, tuple]]] = {}
"""``_by_kind``'s answers by the identity of the tuple of methods (hashing the methods
themselves on every detection cost 7 us of localize's 0.55 ms)."""


def _by_kind(methods: tuple[Method, ...]) -> tuple[tuple, tuple, tuple, tuple]:
    """``methods``' ``(name, estimator)`` pairs by what they estimate from: one image, from
    the best single-image estimate, several images, a user's function given the
    ``depth_image`` estimate (resolved once, not per detection)."""
    known = _GROUPED.get(id(methods))
    if known is not None and known[0] is methods:
        return known[1]
    grouped = tuple(
        tuple((m.name, m.estimator) for m in methods if m.images == kind)
        for kind in ("one", "from_best", "several", "user")
    )
    _GROUPED[id(methods)] = (methods, grouped)  # type: ignore[assignment]
    return grouped  # type: ignore[return-value]


_NAMES: dict[int, tuple[tuple[Method, ...], tuple[str, ...]]] = {}
"""``_names``' answers by the identity of the tuple of methods, as ``_GROUPED``."""


def _names(methods: tuple[Method, ...]) -> tuple[str, ...]:
    """``methods``' names, in order (``METHOD_NAMES`` itself for ``METHODS``)."""
    if methods is METHODS:
        return METHOD_NAMES
    known = _NAMES.get(id(methods))
    if known is not None and known[0] is methods:
        return known[1]
    names = tuple(m.name for m in methods)
    _NAMES[id(methods)] = (methods, names)
    return names


def _localize(
    obs: Observation | None,
    detection: ConeDetection,
    with_covariance: bool,
    methods: tuple[Method, ...] = METHODS,
    t_s: float = 0.0,
    T_w_b_newest: np.ndarray | None = None,
) -> ConeEstimates:
    """Every single-image method on ``obs``, then those built from the best estimate, then
    the users' functions (given the ``depth_image`` estimate, the exposure stamp ``t_s`` and
    the newest pose received when the image arrived, ``T_w_b_newest``)."""
    names = _names(methods)
    if obs is None:
        return ConeEstimates({}, dict.fromkeys(names, NoEstimate.BORDER), method_names=names)
    single, from_best, several, user = _by_kind(methods)
    found = {name: estimator.estimate(obs) for name, estimator in single}
    found.update((name, NoEstimate.ONE_IMAGE) for name, _ in several)  # Localizer's work
    no_estimate = {m: r for m, r in found.items() if isinstance(r, NoEstimate)}
    p_w_by_method = {m: p for m, p in found.items() if m not in no_estimate}
    apex_uv = obs.view.apex_keypoint(obs.exposure.cone)  # memoised: fitted by the estimators
    if not p_w_by_method:
        no_estimate.update((name, NoEstimate.NO_OTHER_ESTIMATE) for name, _ in from_best)
        no_estimate.update(
            (name, no_estimate.get(USER_INPUT, NoEstimate.NO_OTHER_ESTIMATE)) for name, _ in user
        )
        return ConeEstimates({}, no_estimate, apex_uv=apex_uv, method_names=names)
    best = next(m for m in PREFERENCE if m in p_w_by_method)
    for name, estimator in from_best:
        p_w_by_method[name] = estimator.estimate(obs, p_w_by_method[best])
    for name, estimator in user:
        # The user's p_c is the depth_image estimate: without it, the user's function is not
        # called and gives no estimate for depth_image's reason.
        p_w_depth = p_w_by_method.get(USER_INPUT)
        result = (
            no_estimate[USER_INPUT]
            if p_w_depth is None
            else estimator.estimate(obs, p_w_depth, t_s, T_w_b_newest)
        )
        if isinstance(result, NoEstimate):
            no_estimate[name] = result
        else:
            p_w_by_method[name] = result
    if not with_covariance:
        return ConeEstimates(p_w_by_method, no_estimate, apex_uv=apex_uv, method_names=names)
    cov_w = {
        name: estimator.covariance(obs, p_w_by_method[name])
        for name, estimator in single
        if name in p_w_by_method
    }
    for name, estimator in from_best:
        cov_w[name] = estimator.covariance(obs, cov_w[best])
    for name, estimator in user:
        if name in p_w_by_method:
            cov_w[name] = estimator.covariance(obs, p_w_by_method[name])
    return ConeEstimates(p_w_by_method, no_estimate, cov_w, apex_uv, names)


class Localizer:
    """Every method's estimates of the cones one camera sees, image after image.

    The single-image methods and those built from their best estimate run on each detection
    as ``localize`` runs them; the methods that need several images (``vnav.methods``,
    ``images == "several"``) keep their state over the run here and add their estimates.

    Parameters
    ----------
    camera : PinholeCamera
    cone : ConeModel
    far_m : float
        Depth at or beyond which a pixel has no return.
    noise : NoiseModel
        The image and depth noise the estimators are told (``vnav.noise_model``).
    methods : tuple of Method, optional
        The methods to run, ``vnav.methods.active_methods()`` by default (the built-ins, and a
        run's user functions within ``vnav.methods.extended``).
    with_covariance : bool
        False skips the covariances of the methods that estimate from one image (and of
        those built from them, and the users'), as ``localize``'s ``with_covariance``, for
        the points alone; the estimates are the same. The several-image methods still give
        theirs (the apex tracker refuses an estimate by its covariance).
    """

    def __init__(
        self,
        camera: PinholeCamera,
        cone: ConeModel = TRAFFIC_CONE,
        far_m: float = np.inf,
        *,
        noise: NoiseModel = NOISELESS,
        methods: tuple[Method, ...] | None = None,
        with_covariance: bool = True,
    ) -> None:
        self.camera, self.cone, self.far_m, self.noise = camera, cone, far_m, noise
        self.methods = active_methods() if methods is None else methods
        self.with_covariance = bool(with_covariance)
        self._tracks = {
            name: estimator.start(camera, cone) for name, estimator in _by_kind(self.methods)[2]
        }

    def update(
        self,
        t_s: float,
        detections: Sequence[ConeDetection],
        depth: np.ndarray | None,
        T_w_b: np.ndarray,
        T_b_c: np.ndarray,
        *,
        cov_T_w_b: np.ndarray | None = None,
        cov_T_b_c: np.ndarray | None = None,
        T_w_b_newest: np.ndarray | None = None,
    ) -> list[ConeEstimates]:
        """Every estimate of each detection in one image, with its covariance (unless the
        localizer was made ``with_covariance=False``).

        Parameters
        ----------
        t_s : float
            The image's exposure time on the estimator's clock, seconds; never earlier than
            the previous image's.
        detections : sequence of ConeDetection
            From ``vnav.detect.detect_cones`` on this image.
        depth : ndarray, shape (H, W), or None
            Planar z-depth, metres.
        T_w_b, T_b_c : ndarray, shape (4, 4)
            The body pose at the exposure and the camera mount, as the estimator knows them.
        cov_T_w_b, cov_T_b_c : ndarray, shape (6, 6), optional
            Their left-perturbation covariances; default zero.
        T_w_b_newest : ndarray, shape (4, 4), optional
            The newest body pose received when the image arrived, for the users' functions
            (``vnav.plugin.PluginObservation.T_w_b_newest``); default ``T_w_b``.

        Returns
        -------
        list of ConeEstimates
            One per detection, in order (as ``localize`` gives, with the several-image
            methods' estimates or reasons).

        Raises
        ------
        ValueError
            As ``localize``, or for a time earlier than the previous image's.
        """
        exposure = self._exposure(T_w_b, T_b_c, cov_T_w_b, cov_T_b_c)
        if T_w_b_newest is not None:
            T_w_b_newest = se3.check_pose(T_w_b_newest, "T_w_b_newest")
        observations = [_observation(exposure, d, depth) for d in detections]
        estimates = [
            _localize(o, d, self.with_covariance, self.methods, t_s, T_w_b_newest)
            for o, d in zip(observations, detections, strict=True)
        ]
        for name, track in self._tracks.items():
            for i, result in track.update(t_s, exposure, observations).items():
                estimates[i] = estimates[i].with_result(name, result)
        return estimates

    def _exposure(
        self,
        T_w_b: np.ndarray,
        T_b_c: np.ndarray,
        cov_T_w_b: np.ndarray | None,
        cov_T_b_c: np.ndarray | None,
    ) -> Exposure:
        return _exposure(
            self.camera,
            T_w_b,
            T_b_c,
            self.cone,
            self.far_m,
            noise=self.noise,
            cov_T_w_b=cov_T_w_b,
            cov_T_b_c=cov_T_b_c,
        )

    def estimate_with_pose(
        self,
        method_name: str,
        detection: ConeDetection,
        depth: np.ndarray | None,
        T_w_b: np.ndarray,
        T_b_c: np.ndarray,
    ) -> np.ndarray | None:
        """One single-image method's estimate of ``detection`` made with another body pose
        (e.g. the newest one received when the image arrived), (3,), or None without one.

        Raises
        ------
        ValueError
            For a method that does not estimate from one image, or as ``localize``.
        """
        m = method(method_name)
        if m.images != "one":
            raise ValueError(f"{method_name} does not estimate from one image ({m.images!r})")
        obs = _observation(self._exposure(T_w_b, T_b_c, None, None), detection, depth)
        p_w = None if obs is None else m.estimator.estimate(obs)
        return None if p_w is None or isinstance(p_w, NoEstimate) else p_w
