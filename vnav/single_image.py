"""The built-in single-image methods' estimators, as ``vnav.methods`` declares them: each
pairs its estimate (``vnav.estimators``) with its first-order covariance
(``vnav.covariance``) on one ``vnav.observation.Observation``; and the naive mistake, built
from the best of them.

A new single-image method is a module like this one with an object that has ``estimate`` and
``covariance`` (``vnav.methods.SingleImageEstimator``), and a line in ``vnav.methods.METHODS``
naming it.
"""

from __future__ import annotations

import numpy as np

from vnav import covariance
from vnav.estimators import (
    NoEstimate,
    depth_image_from_view,
    ground_plane_from_view,
    known_height_from_view,
    naive,
)
from vnav.observation import Observation

__all__ = ["DEPTH_IMAGE", "GROUND_PLANE", "KNOWN_HEIGHT", "NAIVE"]


class _DepthImage:
    """``depth_image``: the depth image under the mask, fitted to the cone's shape."""

    def estimate(self, obs: Observation) -> np.ndarray | NoEstimate:
        if obs.depth_under_mask_m is None:
            return NoEstimate.NO_DEPTH
        e = obs.exposure
        return depth_image_from_view(obs.view, obs.depth_under_mask_m, e.cone, e.far_m)

    def covariance(self, obs: Observation, p_w: np.ndarray) -> np.ndarray:
        e = obs.exposure
        return covariance.depth_image_cov(e.T_w_c, e.cov_T_w_c, p_w, obs.n_depth_points, e.noise)


class _GroundPlane:
    """``ground_plane``: the ray through the cone's base meets z = 0."""

    def estimate(self, obs: Observation) -> np.ndarray | NoEstimate:
        return ground_plane_from_view(obs.view, obs.exposure.cone)

    def covariance(self, obs: Observation, p_w: np.ndarray) -> np.ndarray:
        e = obs.exposure
        return covariance.ground_plane_cov(
            obs.view, e.camera, e.T_w_c, e.cov_T_w_c, p_w, e.noise, e.cone
        )


class _KnownHeight:
    """``known_height``: the cone's height in pixels (similar triangles)."""

    def estimate(self, obs: Observation) -> np.ndarray | NoEstimate:
        return known_height_from_view(obs.view, obs.exposure.cone)

    def covariance(self, obs: Observation, p_w: np.ndarray) -> np.ndarray:
        e = obs.exposure
        return covariance.known_height_cov(
            obs.view, e.camera, e.T_w_c, e.cov_T_w_c, p_w, e.noise, e.cone
        )


class _Naive:
    """``naive``: the best estimate's camera coordinates added to the body's position (the
    lecture's mistake, chapter 0)."""

    def estimate(self, obs: Observation, p_w_best: np.ndarray) -> np.ndarray:
        p_c = np.array(obs.view.camera_coordinates(p_w_best))
        return naive(p_c, obs.exposure.T_w_b[:3, 3])

    def covariance(self, obs: Observation, cov_w_best: np.ndarray) -> np.ndarray:
        e = obs.exposure
        return covariance.naive_cov(e.T_w_b, e.cov_T_w_b, e.T_w_c[:3, :3].T, cov_w_best)


DEPTH_IMAGE = _DepthImage()
GROUND_PLANE = _GroundPlane()
KNOWN_HEIGHT = _KnownHeight()
NAIVE = _Naive()
