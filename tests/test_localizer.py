"""``vnav.localize.Localizer`` and the methods' declared behaviour (``vnav.methods``).

The oracles: each estimator called alone (``vnav.estimators``), the apex tracker driven by
hand (``vnav.tracking.ApexTracker``), the simulator's true cones, and numpy's rank of the
covariances each method returns.
"""

from __future__ import annotations

import numpy as np
import pytest

from sim.config import CameraConfig, SceneConfig
from sim.render import Renderer
from sim.world import World
from vnav import se3, so3
from vnav.cone import TRAFFIC_CONE
from vnav.detect import detect_cones
from vnav.estimators import NoEstimate, estimate_from_depth
from vnav.localize import ConeEstimates, Localizer, localize
from vnav.methods import METHOD_NAMES, METHODS, NEWEST_POSE_METHOD, method
from vnav.noise_model import NoiseModel
from vnav.sensor_noise import body_pose_covariance
from vnav.silhouette import SilhouetteView
from vnav.tracking import ApexTracker

CONES_W = np.array([[10.0, 0.0, 0.0], [12.0, 2.0, 0.0], [11.0, -2.5, 0.0]])


@pytest.mark.parametrize("m", METHODS, ids=lambda m: m.name)
def test_every_method_names_an_estimator_of_its_kind(m) -> None:
    wanted = {"one": ("estimate", "covariance"), "from_best": ("estimate", "covariance")}
    for attribute in wanted.get(m.images, ("start",)):
        assert callable(getattr(m.estimator, attribute)), (m.name, attribute)
    assert m.needs_several_images == (m.images == "several")
    assert 1 <= m.dof <= 3


def test_each_single_image_covariance_has_the_declared_degrees_of_freedom(one_view) -> None:
    """With pose and image noise every covariance is the method's ``dof`` rank: 3, but 2 for
    ground_plane, whose estimate lies on z = 0 whatever the noise."""
    world, frame, detection = one_view["world"], one_view["frame"], one_view["detection"]
    noise = NoiseModel(
        position_std_m=0.05,
        attitude_std_deg=1.0,
        intensity_std_grey=4.0,
        depth_std_m=0.01,
        depth_std_per_m2=0.0002,
    )
    cov_T_w_b = body_pose_covariance(world.T_w_b, noise)
    estimates = localize(
        detection,
        world.camera,
        world.T_w_b,
        world.T_b_c,
        frame.depth,
        far_m=one_view["far_m"],
        noise=noise,
        cov_T_w_b=cov_T_w_b,
    )
    checked = [m for m in METHODS if not m.needs_several_images]
    for m in checked:
        cov = estimates.covariance(m.name)
        assert cov is not None, m.name
        eig = np.linalg.eigvalsh(cov)
        assert int(np.sum(eig > 1e-9 * eig[-1])) == m.dof, (m.name, eig)


def _flight():
    """A drone sliding 3 m sideways at 3 m height past three cones, 31 images at 10 Hz:
    ``(world, [(t_s, T_w_b, detections, depth)])``."""
    world = World.from_config(
        SceneConfig(cones_w=tuple(map(tuple, CONES_W)), camera=CameraConfig(pitch_down_deg=15.0))
    )
    images = []
    with Renderer(world) as renderer:
        for i in range(31):
            world.set_pose(se3.make(np.eye(3), [0.0, -1.5 + 0.1 * i, 3.0]))
            frame = renderer.render(depth=True)
            images.append((0.1 * i, world.T_w_b, detect_cones(frame.rgb), frame.depth))
    return world, images


def test_the_localizer_is_localize_with_the_apex_tracker_driven_by_hand() -> None:
    world, images = _flight()
    far_m = 0.99 * world.model.vis.map.zfar * world.model.stat.extent
    localizer = Localizer(world.camera, far_m=far_m)
    tracker = ApexTracker(world.camera)
    for t_s, T_w_b, detections, depth in images:
        got = localizer.update(t_s, detections, depth, T_w_b, world.T_b_c)
        single = [
            localize(d, world.camera, T_w_b, world.T_b_c, depth, far_m=far_m) for d in detections
        ]
        T_w_c = T_w_b @ world.T_b_c
        clear = [i for i, d in enumerate(detections) if not d.touches_border]
        uv = [
            SilhouetteView(detections[i], world.camera, T_w_c).apex_keypoint(TRAFFIC_CONE)
            for i in clear
        ]
        tracked = dict(
            zip(clear, tracker.update(t_s, T_w_c, np.array(uv).reshape(-1, 2)), strict=True)
        )
        for i, (g, s) in enumerate(zip(got, single, strict=True)):
            for name in METHOD_NAMES:
                if method(name).needs_several_images:
                    continue
                p, q = g[name], s[name]
                assert (p is None) == (q is None), name
                if p is not None:
                    np.testing.assert_array_equal(p, q)
            if i not in tracked:
                assert g.triangulated is None
                continue
            t = tracked[i]
            if t.p_w is None:
                assert (
                    g.triangulated is None and g.no_estimate["triangulated"] is NoEstimate.PARALLAX
                )
            else:
                np.testing.assert_array_equal(g.triangulated, t.p_w)
    # At the end every cone is triangulated within max(5 cm, 1% of range) of the truth.
    final = [e.triangulated for e in got if e.triangulated is not None]
    assert len(final) == 3
    for p_w in final:
        cone = CONES_W[np.argmin(np.linalg.norm(CONES_W - p_w, axis=1))]
        range_m = np.linalg.norm(cone - (T_w_b @ world.T_b_c)[:3, 3])
        assert np.linalg.norm(p_w - cone) <= max(0.05, 0.01 * range_m)


def test_a_localizer_without_covariances_gives_the_same_estimates() -> None:
    """``Localizer(with_covariance=False)`` (the calibrated run's second pass): every method's
    estimate and reason equal to the last bit to those of a localizer with them, on noisy
    poses; no covariance but the several-image methods', equal to the other's."""
    world, images = _flight()
    far_m = 0.99 * world.model.vis.map.zfar * world.model.stat.extent
    noise = NoiseModel(position_std_m=0.02, attitude_std_deg=0.2)
    full = Localizer(world.camera, far_m=far_m, noise=noise)
    bare = Localizer(world.camera, far_m=far_m, noise=noise, with_covariance=False)
    several = {m.name for m in METHODS if m.needs_several_images}
    triangulated = 0
    for t_s, T_w_b, detections, depth in images:
        args = (t_s, detections, depth, T_w_b, world.T_b_c)
        cov_T_w_b = body_pose_covariance(T_w_b, noise)
        for a, b in zip(
            full.update(*args, cov_T_w_b=cov_T_w_b),
            bare.update(*args, cov_T_w_b=cov_T_w_b),
            strict=True,
        ):
            assert a.no_estimate == b.no_estimate
            for name in METHOD_NAMES:
                assert (a[name] is None) == (b[name] is None), name
                if a[name] is not None:
                    np.testing.assert_array_equal(a[name], b[name])
            assert set(b.cov_w_by_method) == set(a.cov_w_by_method) & several
            for name, cov_w in b.cov_w_by_method.items():
                np.testing.assert_array_equal(cov_w, a.cov_w_by_method[name])
            triangulated += b.triangulated is not None
    assert triangulated > 0


def test_estimate_with_another_pose_is_the_estimator_alone(one_view) -> None:
    world, frame, detection = one_view["world"], one_view["frame"], one_view["detection"]
    far_m = one_view["far_m"]
    localizer = Localizer(world.camera, far_m=far_m)
    T_w_b_other = se3.make(so3.from_rpy(0.0, 0.0, 0.02), world.T_w_b[:3, 3] + [0.1, 0.0, 0.0])
    got = localizer.estimate_with_pose(
        NEWEST_POSE_METHOD, detection, frame.depth, T_w_b_other, world.T_b_c
    )
    expected = estimate_from_depth(
        detection, frame.depth, world.camera, T_w_b_other @ world.T_b_c, far_m=far_m
    )
    np.testing.assert_array_equal(got, expected)
    several = next(m.name for m in METHODS if m.needs_several_images)
    with pytest.raises(ValueError, match="does not estimate from one image"):
        localizer.estimate_with_pose(several, detection, frame.depth, world.T_w_b, world.T_b_c)


def test_a_result_replaces_one_methods_estimate_only() -> None:
    p, cov = np.array([1.0, 2.0, 0.0]), np.eye(3)
    e = ConeEstimates(
        {"depth_image": p}, {"triangulated": NoEstimate.ONE_IMAGE}, {"depth_image": cov}
    )
    with_it = e.with_result("triangulated", (p + 1.0, 2.0 * cov))
    np.testing.assert_array_equal(with_it.triangulated, p + 1.0)
    np.testing.assert_array_equal(with_it.covariance("triangulated"), 2.0 * cov)
    assert "triangulated" not in with_it.no_estimate
    np.testing.assert_array_equal(with_it.depth_image, p)
    refused = with_it.with_result("triangulated", NoEstimate.PARALLAX)
    assert refused.triangulated is None and refused.covariance("triangulated") is None
    assert refused.no_estimate["triangulated"] is NoEstimate.PARALLAX
