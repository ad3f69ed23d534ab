"""scenarios.run.streams: sensor links with latency and jitter, and the estimator's receiver,
checked against the arrival times and poses computed here by hand."""

from __future__ import annotations

import numpy as np
import pytest

from scenarios.run.streams import Link, Receiver, Streams
from vnav import se3, so3


def _pose(t: float) -> np.ndarray:
    """A body moving at 2 m/s along x and yawing at 1 rad/s."""
    return se3.make(so3.rot_z(1.0 * t), [2.0 * t, 0.0, 1.0])


def test_link_adds_latency_and_never_reorders():
    rng = np.random.default_rng(0)
    plain = Link(0.05, 0.0, rng)
    assert [plain.arrival_s(t) for t in (0.0, 0.1, 0.2)] == [0.05, 0.1 + 0.05, 0.2 + 0.05]
    jittery = Link(0.01, 0.02, np.random.default_rng(1))
    sent = np.arange(0.0, 1.0, 0.005)
    arrived = np.array([jittery.arrival_s(t) for t in sent])
    assert np.all(np.diff(arrived) >= 0.0)  # first in, first out
    assert np.all(arrived >= sent)  # never before it was sent
    assert np.std(arrived - sent) > 0.005  # the jitter is there


def _run(streams: Streams, receiver: Receiver, pose_hz: float, image_times, until_s: float):
    """Send poses at pose_hz and images at image_times, delivering at every pose tick."""
    delivered = []
    images = list(image_times)
    for t in np.arange(0.0, until_s + 1e-9, 1.0 / pose_hz):
        t = float(t)
        streams.send_pose(t, _pose(t))
        while images and images[0] <= t + 1e-12:
            streams.send_image(images[0], {"exposure": images.pop(0)})
        delivered += streams.deliver(t, receiver)
    return delivered


def test_image_waits_for_its_pose_and_notes_the_latest():
    """Image latency 50 ms, pose latency 12 ms, offset 20 ms: the pose at exposure is
    interpolated at the converted stamp; the latest pose is the newest 200 Hz sample that
    arrived before the image (stamp + 12 ms <= exposure + 50 ms: 35 ms newer)."""
    streams = Streams(
        pose_latency_s=0.012,
        image_latency_s=0.05,
        jitter_s=0.0,
        camera_clock_offset_s=0.02,
        rng=np.random.default_rng(0),
    )
    receiver = Receiver(camera_clock_offset_s=0.02, cache_s=10.0)
    exposures = [0.1, 0.2, 0.3]
    delivered = _run(streams, receiver, 200.0, exposures, until_s=0.5)
    assert [d.payload["exposure"] for d in delivered] == exposures
    for d, t in zip(delivered, exposures, strict=True):
        assert d.stamp_cam_s == pytest.approx(t - 0.02)
        assert d.exposure_pose_s == pytest.approx(t)
        assert d.arrival_s == pytest.approx(t + 0.05)
        np.testing.assert_allclose(d.T_w_b_at_exposure, _pose(t), atol=1e-12)
        assert d.latest_stamp_s == pytest.approx(t + 0.035)
        np.testing.assert_allclose(d.T_w_b_latest, _pose(t + 0.035), atol=1e-12)


def test_image_before_its_pose_is_not_processed_until_the_pose_arrives():
    streams = Streams(
        pose_latency_s=0.08,
        image_latency_s=0.0,
        jitter_s=0.0,
        camera_clock_offset_s=0.0,
        rng=np.random.default_rng(0),
    )
    receiver = Receiver(camera_clock_offset_s=0.0, cache_s=10.0)
    streams.send_pose(0.0, _pose(0.0))
    streams.send_pose(0.1, _pose(0.1))
    streams.send_image(0.05, "image")
    assert streams.deliver(0.05, receiver) == [] and receiver.waiting == 1
    assert streams.deliver(0.08, receiver) == []  # the pose at 0.0 alone cannot bracket 0.05
    (d,) = streams.deliver(0.18, receiver)
    assert receiver.waiting == 0 and d.latest_stamp_s is None and d.T_w_b_latest is None
    np.testing.assert_allclose(d.T_w_b_at_exposure[:3, 3], _pose(0.05)[:3, 3], atol=1e-12)


def test_synchronous_streams_give_the_exact_pose_at_once():
    streams = Streams(
        pose_latency_s=0.0,
        image_latency_s=0.0,
        jitter_s=0.0,
        camera_clock_offset_s=0.0,
        rng=np.random.default_rng(0),
    )
    receiver = Receiver(camera_clock_offset_s=0.0, cache_s=10.0)
    delivered = _run(streams, receiver, 200.0, [0.0, 0.1, 0.2], until_s=0.2)
    assert len(delivered) == 3
    for d in delivered:
        t = d.payload["exposure"]
        assert d.latest_stamp_s == pytest.approx(t)
        np.testing.assert_allclose(d.T_w_b_latest, d.T_w_b_at_exposure, atol=1e-12)
