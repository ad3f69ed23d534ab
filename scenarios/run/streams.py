"""Sensor streams with time: stamped poses and images that arrive late, as on a real drone.

The simulator knows every state exactly; the estimator does not. Between the two:

- **the pose stream**: the body pose (truth plus the scenario's pose noise) sampled at
  ``pose_rate_hz``, each sample stamped on the pose clock and delivered ``pose_latency_s``
  later;
- **the camera**: each image stamped at exposure on the camera clock,
  ``t_cam = t_pose - camera_clock_offset_s``, delivered ``image_latency_s`` later;
- **jitter**: each delay is the link's latency plus a Gaussian draw of standard deviation
  ``jitter_s`` (the latency is the mean delay), clipped so that nothing arrives before it was
  sent; a link is first-in first-out, so jitter never lets a message overtake the one before.

``Receiver`` is the estimator's side (the pattern of tf2's ``MessageFilter``): poses go into a
``vnav.frames.FrameBuffer`` as they arrive; an image waits until the buffer can give the pose
at its exposure stamp, converted to the pose clock. When an image arrives the newest pose
received so far is noted too: what a pipeline that ignores stamps would use.

The pose clock is the simulator's clock. Everything here is plain numpy and vnav.
"""

from __future__ import annotations

import heapq
import itertools
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vnav.frames import FrameBuffer

__all__ = ["BODY", "WORLD", "Delivered", "Link", "Receiver", "Streams"]

WORLD, BODY = "world", "body"
"""The buffer's frames: the pose stream is ``T_world_body``."""


class Link:
    """One first-in first-out link: a fixed latency plus Gaussian jitter.

    Parameters
    ----------
    latency_s : float
        Seconds from sending to arrival, >= 0.
    jitter_s : float
        Standard deviation of the extra delay, seconds, >= 0.
    rng : numpy.random.Generator
        Draws the jitter (from the run's seed).
    """

    def __init__(self, latency_s: float, jitter_s: float, rng: np.random.Generator) -> None:
        self.latency_s = latency_s
        self.jitter_s = jitter_s
        self._rng = rng
        self._last_arrival_s = -np.inf

    def arrival_s(self, sent_s: float) -> float:
        """When a message sent at ``sent_s`` arrives (never before the previous one)."""
        delay_s = self.latency_s
        if self.jitter_s > 0.0:
            delay_s += float(self._rng.normal(0.0, self.jitter_s))
        arrival = max(sent_s + max(delay_s, 0.0), self._last_arrival_s)
        self._last_arrival_s = arrival
        return arrival


@dataclass
class Delivered:
    """An image the estimator can now process, with the poses it chose.

    Attributes
    ----------
    payload : Any
        What the runner sent with the image (its detections, depth, truth).
    stamp_cam_s : float
        The exposure stamp on the camera clock.
    arrival_s : float
        When the image reached the estimator, pose clock.
    exposure_pose_s : float
        The exposure stamp converted to the pose clock, where ``T_w_b_at_exposure`` was looked
        up.
    T_w_b_at_exposure : ndarray, shape (4, 4)
        The pose stream interpolated at ``exposure_pose_s``.
    latest_stamp_s : float or None
        Stamp of the newest pose received when the image arrived (None if none had).
    T_w_b_latest : ndarray, shape (4, 4), or None
        That newest pose: what a pipeline ignoring stamps would use.
    """

    payload: Any
    stamp_cam_s: float
    arrival_s: float
    exposure_pose_s: float
    T_w_b_at_exposure: np.ndarray
    latest_stamp_s: float | None
    T_w_b_latest: np.ndarray | None


@dataclass
class _Waiting:
    payload: Any
    stamp_cam_s: float
    arrival_s: float
    latest_stamp_s: float | None
    T_w_b_latest: np.ndarray | None


class Receiver:
    """The estimator's inputs: a frame buffer of arrived poses and a queue of images.

    Parameters
    ----------
    camera_clock_offset_s : float
        ``t_pose = t_cam + offset``: how a camera stamp is read on the pose clock.
    cache_s : float
        History the buffer keeps, seconds.
    """

    def __init__(self, camera_clock_offset_s: float, cache_s: float) -> None:
        self.offset_s = camera_clock_offset_s
        self.buffer = FrameBuffer(cache_s=cache_s)
        self._waiting: deque[_Waiting] = deque()

    @property
    def waiting(self) -> int:
        """Images received and not yet processed."""
        return len(self._waiting)

    def receive_poses(self, stamps_s: np.ndarray, T_w_b: np.ndarray) -> None:
        """Poses arriving (in stamp order) go into the buffer."""
        self.buffer.set_transform(WORLD, BODY, stamps_s, T_w_b)

    def receive_image(self, payload: Any, stamp_cam_s: float, arrival_s: float) -> None:
        """An image arrives: it waits for its pose; the newest pose received is noted."""
        latest_stamp = T_latest = None
        if BODY in self.buffer:
            latest_stamp = self.buffer.interval(WORLD, BODY)[1]
            T_latest = self.buffer.lookup(WORLD, BODY, latest_stamp)
        self._waiting.append(_Waiting(payload, stamp_cam_s, arrival_s, latest_stamp, T_latest))

    def ready(self) -> list[Delivered]:
        """The images, in arrival order, whose exposure pose the buffer can now give."""
        out = []
        while self._waiting:
            image = self._waiting[0]
            t_pose = image.stamp_cam_s + self.offset_s
            if not self.buffer.can_lookup(WORLD, BODY, t_pose):
                if BODY in self.buffer and t_pose < self.buffer.interval(WORLD, BODY)[0]:
                    raise ValueError(
                        f"an image exposed at t = {t_pose!r} s (pose clock) arrived after the "
                        f"pose buffer dropped that time (it holds "
                        f"{self.buffer.interval(WORLD, BODY)} s): latency beyond the cache"
                    )
                break
            self._waiting.popleft()
            out.append(
                Delivered(
                    image.payload,
                    image.stamp_cam_s,
                    image.arrival_s,
                    t_pose,
                    self.buffer.lookup(WORLD, BODY, t_pose),
                    image.latest_stamp_s,
                    image.T_w_b_latest,
                )
            )
        return out


@dataclass(order=True)
class _Message:
    arrival_s: float
    order: int  # sending order breaks ties: a pose sent before an image is received first
    kind: str = field(compare=False)
    stamp_s: float = field(compare=False)
    data: Any = field(compare=False)


class Streams:
    """The two links, carrying messages to a ``Receiver`` in arrival order.

    Parameters
    ----------
    pose_latency_s, image_latency_s, jitter_s : float
        See the module docstring.
    camera_clock_offset_s : float
        ``t_pose = t_cam + offset``.
    rng : numpy.random.Generator
        Draws the jitter.
    """

    def __init__(
        self,
        *,
        pose_latency_s: float,
        image_latency_s: float,
        jitter_s: float,
        camera_clock_offset_s: float,
        rng: np.random.Generator,
    ) -> None:
        self._pose_link = Link(pose_latency_s, jitter_s, rng)
        self._image_link = Link(image_latency_s, jitter_s, rng)
        self.offset_s = camera_clock_offset_s
        self._queue: list[_Message] = []
        self._order = itertools.count()
        self._images = 0

    @property
    def in_flight(self) -> int:
        """Messages sent and not yet delivered."""
        return len(self._queue)

    @property
    def images_in_flight(self) -> int:
        """Images sent and not yet delivered."""
        return self._images

    def send_pose(self, stamp_s: float, T_w_b: np.ndarray) -> float:
        """A pose sample taken at ``stamp_s`` (pose clock) leaves for the estimator; returns
        when it will arrive."""
        arrival = self._pose_link.arrival_s(stamp_s)
        heapq.heappush(self._queue, _Message(arrival, next(self._order), "pose", stamp_s, T_w_b))
        return arrival

    def send_image(self, exposure_s: float, payload: Any) -> None:
        """An image exposed at ``exposure_s`` (pose clock) leaves, stamped on the camera clock."""
        arrival = self._image_link.arrival_s(exposure_s)
        stamp_cam = exposure_s - self.offset_s
        self._images += 1
        heapq.heappush(
            self._queue, _Message(arrival, next(self._order), "image", stamp_cam, payload)
        )

    def deliver(self, now_s: float, receiver: Receiver) -> list[Delivered]:
        """Hand every message arrived by ``now_s`` to ``receiver`` in arrival order (poses in
        batches); return the images it can now process."""
        stamps: list[float] = []
        poses: list[np.ndarray] = []
        ready: list[Delivered] = []

        def flush() -> None:
            if stamps:
                receiver.receive_poses(np.array(stamps), np.array(poses))
                stamps.clear()
                poses.clear()
                ready.extend(receiver.ready())

        while self._queue and self._queue[0].arrival_s <= now_s:
            message = heapq.heappop(self._queue)
            if message.kind == "pose":
                stamps.append(message.stamp_s)
                poses.append(message.data)
                continue
            flush()  # the image sees every pose that arrived before it
            self._images -= 1
            receiver.receive_image(message.data, message.stamp_s, message.arrival_s)
            ready.extend(receiver.ready())
        flush()
        return ready
