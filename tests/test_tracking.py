"""``vnav.tracking.ApexTracker``: cone apexes followed over a moving camera's images and
triangulated, against the cones they were projected from."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vnav import se3
from vnav.camera import PinholeCamera
from vnav.cone import TRAFFIC_CONE
from vnav.tracking import ApexTracker

CAMERA = PinholeCamera.from_fovy(60.0, 640, 480)
CONES_W = np.array([[10.0, 0.0, 0.0], [12.0, 2.0, 0.0], [11.0, -2.5, 0.0]])
APEX_W = CONES_W + np.array([0.0, 0.0, TRAFFIC_CONE.height_m])


def _pose(y_m: float) -> np.ndarray:
    """A camera at (0, y, 2) looking along world x, level (optical: x right = -y_w, y down)."""
    R_w_c = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    return se3.make(R_w_c, [0.0, y_m, 2.0])


def _images(rng, noise_px: float, n: int = 21, span_m: float = 2.0):
    for i in range(n):
        T = _pose(-span_m / 2 + span_m * i / (n - 1))
        T_c_w = se3.invert(T)
        uv = CAMERA.project(APEX_W @ T_c_w[:3, :3].T + T_c_w[:3, 3])
        order = rng.permutation(len(uv))  # the detector's order means nothing
        yield 0.1 * i, T, uv[order] + rng.normal(0.0, noise_px, uv.shape), order


def test_exact_pixels_give_the_cones_once_the_parallax_suffices() -> None:
    """Exact apex pixels from a camera sliding 2 m sideways: each detection keeps its track
    whatever the detector's order, and every estimate (once the rays cross at 3 deg) is its
    cone's base centre to 1e-9 m; before that, none."""
    rng = np.random.default_rng(0)
    tracker = ApexTracker(CAMERA)
    track_of_cone: dict[int, int] = {}
    estimated = 0
    for t_s, T, uv, order in _images(rng, 0.0):
        for k, tracked in enumerate(tracker.update(t_s, T, uv)):
            cone = int(order[k])
            assert track_of_cone.setdefault(cone, tracked.track) == tracked.track
            if tracked.p_w is None:
                assert tracked.parallax_deg < 3.0
            else:
                np.testing.assert_allclose(tracked.p_w, CONES_W[cone], atol=1e-9)
                estimated += 1
    assert len(set(track_of_cone.values())) == 3 and estimated > 30


def test_noisy_pixels_within_the_target() -> None:
    """0.4 px of apex noise: at the last image (parallax 10-11 deg over 21 views) each cone
    within max(5 cm, 1% of range) (the triangulated method's accuracy bound, ``vnav.methods``)."""
    rng = np.random.default_rng(1)
    tracker = ApexTracker(CAMERA)
    last = None
    for t_s, T, uv, order in _images(rng, 0.4):
        last = (tracker.update(t_s, T, uv), order, T)
    tracked, order, T = last
    for k, est in enumerate(tracked):
        cone = CONES_W[order[k]]
        range_m = np.linalg.norm(cone - T[:3, 3])
        assert np.linalg.norm(est.p_w - cone) <= max(0.05, 0.01 * range_m)


def test_old_rays_leave_the_window_and_time_cannot_go_back() -> None:
    tracker = ApexTracker(CAMERA, window_s=0.25)
    rng = np.random.default_rng(2)
    results = [tracker.update(t, T, uv) for t, T, uv, _ in _images(rng, 0.0)]
    assert max(r.views for r in results[-1]) <= 3  # 0.1 s apart: 3 images in 0.25 s
    with pytest.raises(ValueError, match="back in time"):
        tracker.update(0.0, _pose(0.0), np.zeros((1, 2)))
    with pytest.raises(ValueError):
        ApexTracker(CAMERA, gate_deg=0.0)


def test_rendered_flight_triangulates_each_cone_within_the_target() -> None:
    """The simulator renders three cones while the drone slides 3 m sideways at 3 m height;
    the detector's blobs and the unbiased apex fit (``SilhouetteView.apex_keypoint``) feed the
    tracker: at the end each cone's estimate is within max(5 cm, 1% of range) of the truth
    (its accuracy bound, once the parallax exceeds a few degrees)."""
    from sim.config import CameraConfig, SceneConfig
    from sim.render import Renderer
    from sim.world import World
    from vnav.detect import detect_cones
    from vnav.silhouette import SilhouetteView

    world = World.from_config(
        SceneConfig(cones_w=tuple(map(tuple, CONES_W)), camera=CameraConfig(pitch_down_deg=15.0))
    )
    tracker = ApexTracker(world.camera)
    with Renderer(world) as renderer:
        for i in range(31):
            world.set_pose(se3.make(np.eye(3), [0.0, -1.5 + 0.1 * i, 3.0]))
            T_w_c = world.T_w_c
            dets = [
                d for d in detect_cones(renderer.render(depth=False).rgb) if not d.touches_border
            ]
            uv = [SilhouetteView(d, world.camera, T_w_c).apex_keypoint(TRAFFIC_CONE) for d in dets]
            tracked = tracker.update(0.1 * i, T_w_c, np.array([u for u in uv if u is not None]))
    assert len(tracked) == 3
    for est in tracked:
        assert est.p_w is not None and est.parallax_deg > 3.0
        cone = CONES_W[np.argmin(np.linalg.norm(CONES_W - est.p_w, axis=1))]
        range_m = np.linalg.norm(cone - T_w_c[:3, 3])
        assert np.linalg.norm(est.p_w - cone) <= max(0.05, 0.01 * range_m)


def test_midpoint_covariance_matches_monte_carlo() -> None:
    """21 views of one apex from a 2 m baseline, each believed pose off by exp(xi^) (5 cm, 0.3
    deg) and each pixel by 0.4 px: 3000 draws of the midpoint against ``midpoint_covariance``
    (first order: traces within 10% and mean NEES within 10% of 3, the draws' sampling error
    being about 3%)."""
    from helpers import se3_exp_stack  # the draws a stack at a time

    from vnav.multiview import _midpoint
    from vnav.tracking import midpoint_covariance

    rng = np.random.default_rng(5)
    apex = APEX_W[0]
    T = np.array([_pose(-1.0 + 0.1 * i) for i in range(21)])
    uv = np.array(
        [CAMERA.project((se3.invert(t)[:3, :3] @ apex + se3.invert(t)[:3, 3])[None])[0] for t in T]
    )
    cov_T = np.diag([0.05**2] * 3 + [np.radians(0.3) ** 2] * 3)
    cov_uv = 0.4**2 * np.eye(2)
    predicted = midpoint_covariance(CAMERA, T, uv, apex, [cov_T] * 21, [cov_uv] * 21)
    L = np.linalg.cholesky(cov_T)
    # Each draw takes 21 x 6 standard normals for the poses (exp(L z) each), then 21 x 2 for
    # the pixels (0.4 px each): the numbers of a draw-by-draw loop, drawn at once.
    z = rng.standard_normal((3000, 21 * 8))
    xi = z[:, : 21 * 6].reshape(3000, 21, 6) @ L.T
    T_b = se3_exp_stack(xi.reshape(-1, 6)).reshape(3000, 21, 4, 4) @ T
    uv_b = uv + 0.4 * z[:, 21 * 6 :].reshape(3000, 21, 2)
    rays_c = CAMERA.rays(uv_b.reshape(-1, 2)).reshape(3000, 21, 3)
    rays = np.einsum("knij,knj->kni", T_b[..., :3, :3], rays_c)
    draws = np.array([_midpoint(c, d) for c, d in zip(T_b[..., :3, 3], rays, strict=True)])
    sample = np.cov(draws.T)
    assert np.trace(sample) / np.trace(predicted) == pytest.approx(1.0, abs=0.10)
    err = draws - apex
    nees = np.einsum("ni,ij,nj->n", err, np.linalg.inv(predicted), err).mean()
    assert nees / 3.0 == pytest.approx(1.0, abs=0.10)


def test_midpoint_covariance_is_its_view_by_view_form() -> None:
    """All views at once against ``_midpoint_covariance_reference`` (the derivation, one view
    at a time), with some views' pose or pixel exact (None) and different covariances."""
    from vnav.tracking import _midpoint_covariance_reference, midpoint_covariance

    rng = np.random.default_rng(6)
    apex = APEX_W[0]
    T = np.array([_pose(-1.0 + 0.15 * i) for i in range(9)])
    uv = np.array(
        [CAMERA.project((se3.invert(t)[:3, :3] @ apex + se3.invert(t)[:3, 3])[None])[0] for t in T]
    )
    covs_T = [None if i % 4 == 1 else np.diag(rng.uniform(1e-4, 1e-2, 6)) for i in range(9)]
    covs_uv = [None if i % 3 == 2 else rng.uniform(0.1, 0.5) * np.eye(2) for i in range(9)]
    for cov_T, cov_uv in [(covs_T, covs_uv), ([None] * 9, covs_uv), (covs_T, [None] * 9)]:
        got = midpoint_covariance(CAMERA, T, uv, apex, cov_T, cov_uv)
        ref = _midpoint_covariance_reference(CAMERA, T, uv, apex, cov_T, cov_uv)
        np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-16)


def _relative_difference(a: np.ndarray, b: np.ndarray) -> float:
    """The largest difference of ``a`` from ``b`` relative to ``b``'s largest entry."""
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def _compare_with_reference(tracker: ApexTracker, tracked: list) -> tuple[int, float]:
    """Each ``TrackedApex`` of the latest image against ``_estimate_reference`` (the
    triangulation and ``midpoint_covariance`` of every view of the window again): the same
    track, views and decisions; how many had a covariance and the largest relative
    difference of the parallaxes, points and covariances."""
    by_id = {tr.id: tr for tr in tracker._tracks}
    compared, worst = 0, 0.0
    for got in tracked:
        ref = tracker._estimate_reference(by_id[got.track])
        assert (got.track, got.views) == (ref.track, ref.views)
        worst = max(worst, abs(got.parallax_deg - ref.parallax_deg) / max(ref.parallax_deg, 1e-3))
        for a, b in ((got.p_w, ref.p_w), (got.apex_w, ref.apex_w), (got.cov_w, ref.cov_w)):
            assert (a is None) == (b is None)
            if a is not None:
                worst = max(worst, _relative_difference(a, b))
        compared += got.cov_w is not None
    return compared, worst


def test_estimate_from_the_window_sums_is_the_reference() -> None:
    """``ApexTracker._estimate`` (each view's terms computed once, when it joins, and the
    window's sums kept as views join and leave) against ``_estimate_reference`` (the
    triangulation and ``midpoint_covariance`` of every view of the window again) at every
    image: the same decisions, the points and covariances equal but for rounding (1e-9
    relative, the bound a replaced exact algorithm is held to), while rays leave the window
    by count and by time (the buffers compacted and the sums made again several times), with
    pose covariances on some views only and pixels noisy."""
    from vnav import so3

    rng = np.random.default_rng(5)
    tracker = ApexTracker(CAMERA, max_views=6, window_s=1.0)
    compared, worst = 0, 0.0
    for i, (t_s, T, _, _) in enumerate(_images(rng, 0.0, n=61, span_m=18.0)):
        # A wobbling camera (every coordinate a full-mantissa number: the sums' order shows).
        T = se3.make(
            so3.exp(rng.normal(0.0, 0.01, 3)) @ T[:3, :3], T[:3, 3] + rng.normal(0.0, 0.05, 3)
        )
        T_c_w = se3.invert(T)
        uv = CAMERA.project(APEX_W @ T_c_w[:3, :3].T + T_c_w[:3, 3])
        uv += rng.normal(0.0, 0.3, uv.shape)
        A = rng.normal(size=(6, 6)) * 1e-3
        # Every view's pose uncertain in the last third, only some before.
        cov_T = A @ A.T if i % 3 or i > 40 else None
        # After image 20 a pause of 0.8 s: rays leave the window by time.
        t_s += 0.8 * (i > 20)
        tracked = tracker.update(t_s, T, uv, cov_T_w_c=cov_T, cov_uv=0.16 * np.eye(2))
        n, w = _compare_with_reference(tracker, tracked)
        compared, worst = compared + n, max(worst, w)
    assert compared > 100
    assert worst < 1e-9


def test_window_sums_do_not_drift_over_a_long_track() -> None:
    """A cone followed for 1500 images, 300 m from the world's origin, its first 100 views'
    poses a hundred million times as uncertain as the rest: each view that leaves takes its
    terms out of the window's sums by a subtraction, which would leave the rounding of the
    large terms behind in the small sums for good; the sums made again as the window turns
    over keep every estimate once it has turned over after they left (every tenth compared)
    within 1e-9 of the reference's (without that: 2e-6)."""
    rng = np.random.default_rng(11)
    offset_w = np.array([300.0, -200.0, 0.0])
    apex_w = APEX_W[0] + offset_w
    tracker = ApexTracker(CAMERA, max_views=40, window_s=1e6)
    compared, worst = 0, 0.0
    for i in range(1500):
        # Sliding sideways, back and forth over 4 m, 10 m from the cone.
        y_m = 2.0 * math.sin(0.05 * i)
        T = _pose(y_m)
        T[:3, 3] += offset_w
        T_c_w = se3.invert(T)
        uv = CAMERA.project(apex_w @ T_c_w[:3, :3].T + T_c_w[:3, 3])[None]
        uv = uv + rng.normal(0.0, 0.3, uv.shape)
        # Centimetres and a twentieth of a milliradian, then metres and half a radian.
        A = rng.normal(size=(6, 6)) * np.repeat([1e-2, 5e-5], 3)[:, None]
        A *= 1.0 if i >= 100 else 1e4
        tracked = tracker.update(0.1 * i, T, uv, cov_T_w_c=A @ A.T, cov_uv=0.16 * np.eye(2))
        assert len(tracker._tracks) == 1
        if i >= 200 and i % 10 == 0:  # the large views gone, the window turned over
            n, w = _compare_with_reference(tracker, tracked)
            compared, worst = compared + n, max(worst, w)
    assert compared > 120
    assert worst < 1e-9


def test_angle_to_a_track_is_its_reference() -> None:
    """The association's angle from a ray to each track, with what depends on the track alone
    computed once (``_angle_to_track``), against ``_angle_to_track_reference`` (per pair):
    equal, for tracks with and without an apex, in front of and behind the camera."""
    from vnav.tracking import _angle_to_track, _angle_to_track_reference

    rng = np.random.default_rng(7)
    tracker = ApexTracker(CAMERA)
    for t_s, T, uv, _ in _images(rng, 0.3):
        tracker.update(t_s, T, uv)
    tracks = tracker._tracks
    tracks[0].apex_w = None
    tracks[1].apex_w = np.array([-50.0, 0.0, 1.0])  # behind the camera below
    for _ in range(200):
        centre = rng.normal(0.0, 2.0, 3)
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        for tr in tracks:
            v = None if tr.apex_w is None else tr.apex_w - centre
            n = None if v is None else float(np.linalg.norm(v))
            assert _angle_to_track(d, tr, v, n) == _angle_to_track_reference(centre, d, tr)
