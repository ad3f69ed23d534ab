"""What an estimator is given: one image's exposure (``Exposure``: the poses the estimator was
told, their covariances, the sensors' noise) and one detection in it (``Observation``).

``vnav.localize`` validates the inputs once and builds these; each method (``vnav.methods``)
then reads what it needs without validating again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vnav.camera import PinholeCamera
from vnav.cone import ConeModel
from vnav.detect import ConeDetection
from vnav.noise_model import NoiseModel
from vnav.silhouette import SilhouetteView
from vnav.uncertainty import compose_covariance

__all__ = ["Exposure", "Observation"]


@dataclass(frozen=True, init=False)
class Exposure:
    """One image as the estimator knows it (inputs already validated).

    Attributes
    ----------
    T_w_b : ndarray, shape (4, 4)
        The body pose the estimator was given for the image's exposure.
    T_b_c : ndarray, shape (4, 4)
        The camera mount the estimator was given.
    T_w_c : ndarray, shape (4, 4)
        ``T_w_b @ T_b_c``.
    cov_T_w_b, cov_T_b_c : ndarray, shape (6, 6)
        Left-perturbation covariances of the body pose and of the mount (docs/CONVENTIONS.md,
        "Uncertainty"); zero for a pose known exactly.
    noise : NoiseModel
        The image and depth noise (``vnav.noise_model``).
    camera : PinholeCamera
    cone : ConeModel
    far_m : float
        Depth at or beyond which a pixel has no return.
    """

    T_w_b: np.ndarray
    T_b_c: np.ndarray
    T_w_c: np.ndarray
    cov_T_w_b: np.ndarray
    cov_T_b_c: np.ndarray
    noise: NoiseModel
    camera: PinholeCamera
    cone: ConeModel
    far_m: float

    def __init__(
        self,
        *,
        T_w_b: np.ndarray,
        T_b_c: np.ndarray,
        T_w_c: np.ndarray,
        cov_T_w_b: np.ndarray,
        cov_T_b_c: np.ndarray,
        noise: NoiseModel,
        camera: PinholeCamera,
        cone: ConeModel,
        far_m: float,
    ) -> None:
        # One dict update instead of the frozen dataclass's nine object.__setattr__ calls:
        # an Exposure is built for every localised detection. Still frozen after this.
        self.__dict__.update(
            T_w_b=T_w_b,
            T_b_c=T_b_c,
            T_w_c=T_w_c,
            cov_T_w_b=cov_T_w_b,
            cov_T_b_c=cov_T_b_c,
            noise=noise,
            camera=camera,
            cone=cone,
            far_m=far_m,
        )

    @property
    def cov_T_w_c(self) -> np.ndarray:
        """The camera pose's covariance, (6, 6): the body pose's and the mount's composed
        (Barfoot & Furgale 2014, eq. 38), or the body pose's alone for a mount known exactly.
        Composed on first use, once."""
        # Memoised by hand: functools.cached_property takes a lock on every first access in
        # Python 3.11, which localize would pay per detection.
        cached = self.__dict__.get("_cov_T_w_c")
        if cached is None:
            if not self.cov_T_b_c.any():
                cached = self.cov_T_w_b
            else:
                cached = compose_covariance(self.T_w_b, self.cov_T_w_b, self.cov_T_b_c)
            self.__dict__["_cov_T_w_c"] = cached  # a frozen dataclass's own memo
        return cached


@dataclass(frozen=True)
class Observation:
    """One detected cone in one image, as the estimators see it.

    Attributes
    ----------
    exposure : Exposure
        The image's poses, covariances and noise.
    view : SilhouetteView
        The detection seen from ``exposure.T_w_c``: its pixels, rays and fitted keypoints
        (memoised: methods that fit the same keypoint share it).
    depth_under_mask_m : ndarray, shape (N,), or None
        The planar depth of the mask's pixels (``vnav.estimators.depth_under_mask``), metres;
        None without a depth image.
    """

    exposure: Exposure
    view: SilhouetteView
    depth_under_mask_m: np.ndarray | None

    @property
    def detection(self) -> ConeDetection:
        """The detection this observation is of."""
        return self.view.detection

    @property
    def n_depth_points(self) -> int:
        """The depth samples the ``depth_image`` covariance credits the axis fit with
        (``vnav.covariance.depth_image_cov``): half the mask's pixels."""
        return self.view.detection.area_px // 2
