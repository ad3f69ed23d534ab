"""vnav.frames.FrameBuffer against independent references: SciPy's ``Slerp`` and numpy's
linear interpolation (test-only oracles), hand-composed lookups, and ``FrameTree``."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import PROPERTY_SETTINGS, random_poses, transforms
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation, Slerp

from vnav import frames, se3, so3
from vnav.frames import ExtrapolationError, FrameBuffer, FrameTree

ATOL = 1e-12


def _stamps(rng: np.random.Generator, n: int, t0: float = 0.0, rate_hz: float = 100.0):
    """n increasing stamps at about ``rate_hz`` with jitter (gaps of 0.5 to 1.5 periods)."""
    return t0 + np.cumsum(rng.uniform(0.5, 1.5, n) / rate_hz)


def _reference(stamps: np.ndarray, poses: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Interpolated poses by SciPy's Slerp and numpy's interp: the oracle."""
    R = Slerp(stamps, Rotation.from_matrix(poses[:, :3, :3]))(t).as_matrix()
    p = np.column_stack([np.interp(t, stamps, poses[:, i, 3]) for i in range(3)])
    return se3.make(R, p)


def _trajectory(rng, n: int, rate_hz: float, t0: float = 0.0):
    """Stamps and smoothly varying poses (consecutive rotations < 90 deg apart)."""
    stamps = _stamps(rng, n, t0, rate_hz)
    rotvecs = np.cumsum(rng.normal(0.0, 0.4, (n, 3)), axis=0)
    poses = se3.make(so3.exp(rotvecs), np.cumsum(rng.normal(0.0, 0.2, (n, 3)), axis=0))
    return stamps, poses


def test_interpolation_matches_scipy_slerp_and_linear(rng):
    stamps, poses = _trajectory(rng, 200, 100.0)
    buf = FrameBuffer()
    buf.set_transform("world", "body", stamps, poses)
    t = rng.uniform(stamps[0], stamps[-1], 5000)
    np.testing.assert_allclose(
        buf.lookup("world", "body", t), _reference(stamps, poses, t), atol=1e-9
    )
    # One time at a time gives the same as the vectorised call, as a (4, 4).
    for k in range(0, 5000, 997):
        single = buf.lookup("world", "body", float(t[k]))
        assert single.shape == (4, 4)
        np.testing.assert_allclose(single, buf.lookup("world", "body", t[k : k + 1])[0], atol=ATOL)


def test_exact_at_the_stored_stamps(rng):
    stamps, poses = _trajectory(rng, 50, 200.0)
    buf = FrameBuffer()
    for t, T in zip(stamps, poses, strict=True):  # one sample at a time, as a stream arrives
        buf.set_transform("world", "body", t, T)
    got = buf.lookup("world", "body", stamps)
    assert np.max(np.abs(got - poses)) <= ATOL
    assert np.max(np.abs(buf.lookup("world", "body", stamps[-1]) - poses[-1])) <= ATOL
    assert buf.interval("world", "body") == (stamps[0], stamps[-1])


def test_rotation_takes_the_shorter_arc():
    """Yaw -172 deg then +172 deg: the stored (canonical) quaternions have opposite signs
    (their dot product is cos(172 deg) < 0); the way between turns through 180 deg (16 deg of
    turn), not back through 0 (344 deg)."""
    buf = FrameBuffer()
    yaw = np.radians(172.0)
    buf.set_transform(
        "w", "b", [0.0, 1.0], se3.make(so3.rot_z(np.array([-yaw, yaw])), np.zeros((2, 3)))
    )
    np.testing.assert_allclose(buf.lookup("w", "b", 0.5)[:3, :3], so3.rot_z(np.pi), atol=1e-12)
    quarter = buf.lookup("w", "b", 0.25)[:3, :3]
    np.testing.assert_allclose(quarter, so3.rot_z(-yaw - np.radians(4.0)), atol=1e-12)


@pytest.mark.parametrize("side", ["before", "after"])
def test_extrapolation_refused_with_the_edge_time_and_interval(side):
    buf = FrameBuffer()
    buf.set_transform("world", "body", [1.0, 2.0], np.stack([np.eye(4), np.eye(4)]))
    buf.set_static("body", "camera", np.eye(4))
    t = 0.5 if side == "before" else 2.25
    with pytest.raises(ExtrapolationError) as info:
        buf.lookup("camera", "world", t)
    message = str(info.value)
    assert "'world' -> 'body'" in message and repr(t) in message and "[1.0, 2.0]" in message
    assert isinstance(info.value, ValueError)
    assert not buf.can_lookup("camera", "world", t)
    assert buf.can_lookup("camera", "world", 1.5)
    with pytest.raises(ExtrapolationError, match=r"2 of 3 times asked"):
        buf.lookup("world", "body", np.array([1.5, t, t]))


def test_time_travel_equals_two_lookups_composed(rng):
    """A point seen in the camera at exposure, expressed in the body at arrival: through the
    world, fixed between the two times."""
    stamps, poses = _trajectory(rng, 100, 200.0)
    T_b_c = se3.make(frames.mount_rotation(0.3), [0.15, 0.0, 0.05])
    buf = FrameBuffer()
    buf.set_transform("world", "body", stamps, poses)
    buf.set_static("body", "camera", T_b_c)
    t_exposure = rng.uniform(stamps[0], stamps[-1] - 0.05, 50)
    t_arrival = t_exposure + 0.05
    got = buf.lookup("body", "camera", t_arrival, source_time_s=t_exposure, fixed="world")
    T_w_b_arrival = _reference(stamps, poses, t_arrival)
    T_w_c_exposure = _reference(stamps, poses, t_exposure) @ T_b_c
    np.testing.assert_allclose(got, se3.invert(T_w_b_arrival) @ T_w_c_exposure, atol=1e-9)
    # At one time, time travel is the ordinary lookup.
    same = buf.lookup("body", "camera", t_arrival, source_time_s=t_arrival, fixed="world")
    np.testing.assert_allclose(same, np.broadcast_to(T_b_c, same.shape), atol=1e-12)


def test_chain_of_three_edges_at_different_rates(rng):
    """world -> body at 200 Hz, body -> gimbal at 50 Hz, gimbal -> camera at 10 Hz."""
    edges = [
        ("world", "body", 200.0, 400),
        ("body", "gimbal", 50.0, 100),
        ("gimbal", "camera", 10.0, 20),
    ]
    buf = FrameBuffer()
    data = {}
    for parent, child, rate, n in edges:
        stamps, poses = _trajectory(rng, n, rate, t0=-0.1)
        buf.set_transform(parent, child, stamps, poses)
        data[child] = (stamps, poses)
    start = max(s[0] for s, _ in data.values())
    stop = min(s[-1] for s, _ in data.values())
    t = rng.uniform(start, stop, 1000)
    expected = np.broadcast_to(np.eye(4), (len(t), 4, 4))
    for _, child, _, _ in edges:
        expected = expected @ _reference(*data[child], t)
    np.testing.assert_allclose(buf.lookup("world", "camera", t), expected, atol=1e-9)
    np.testing.assert_allclose(buf.lookup("camera", "world", t), se3.invert(expected), atol=1e-9)
    # Between siblings' frames: body in camera goes up to body, not to the root.
    T_g_c = _reference(*data["camera"], t)
    np.testing.assert_allclose(buf.lookup("gimbal", "camera", t), T_g_c, atol=1e-9)


def test_history_is_trimmed_to_cache_s(rng):
    buf = FrameBuffer(cache_s=1.0)
    stamps = np.arange(0.0, 3.0 + 1e-9, 0.01)
    poses = random_poses(rng, len(stamps))
    for k in range(0, len(stamps), 7):  # batches of 7, as a stream in bursts
        buf.set_transform("world", "body", stamps[k : k + 7], poses[k : k + 7])
    first, last = buf.interval("world", "body")
    assert last == stamps[-1]
    assert first == stamps[np.searchsorted(stamps, last - 1.0)]
    assert not buf.can_lookup("world", "body", 1.5)
    np.testing.assert_allclose(buf.lookup("world", "body", stamps[-50:]), poses[-50:], atol=ATOL)


def test_static_buffer_behaves_like_the_frame_tree(rng):
    """A random tree of static edges: every lookup equals FrameTree's, with or without t_s."""
    names = [f"f{i}" for i in range(8)]
    tree, buf = FrameTree(), FrameBuffer()
    poses = random_poses(rng, len(names) - 1)
    for i in range(1, len(names)):
        parent = names[int(rng.integers(0, i))]
        tree.add(parent, names[i], poses[i - 1])
        buf.set_static(parent, names[i], poses[i - 1])
    for a in names:
        for b in names:
            np.testing.assert_allclose(buf.lookup(a, b), tree.lookup(a, b), atol=ATOL)
            np.testing.assert_allclose(buf.lookup(a, b, 12.5), tree.lookup(a, b), atol=ATOL)
    assert buf.lookup("f0", "f7", np.zeros(3)).shape == (3, 4, 4)
    assert buf.frames == tree.frames and all(buf.parent(f) == tree.parent(f) for f in names)


# ------------------------------------------------------------------ interpolation laws


@given(T0=transforms(), T1=transforms(), alpha=st.floats(0.0, 1.0))
@PROPERTY_SETTINGS
def test_interpolation_follows_the_geodesic(T0, T1, alpha):
    """At t = alpha between two samples: the rotation is alpha of the way along the shorter
    arc (R0^T R(t) = exp(alpha log(R0^T R1))) and the translation alpha of the way."""
    buf = FrameBuffer()
    buf.set_transform("a", "b", [2.0, 4.0], np.stack([T0, T1]))
    T = buf.lookup("a", "b", 2.0 + 2.0 * alpha)
    relative = so3.log(T0[:3, :3].T @ T1[:3, :3])
    if np.linalg.norm(relative) > np.pi - 1e-6:
        return  # half a turn: both ways round are as short, either is right
    np.testing.assert_allclose(T[:3, :3], T0[:3, :3] @ so3.exp(alpha * relative), atol=1e-9)
    np.testing.assert_allclose(T[:3, 3], (1 - alpha) * T0[:3, 3] + alpha * T1[:3, 3], atol=1e-9)
    assert so3.is_rotation(T[:3, :3])


@given(
    Ts=st.lists(transforms(), min_size=6, max_size=6),
    t=st.floats(0.0, 1.0),
)
@PROPERTY_SETTINGS
def test_lookups_compose_and_invert(Ts, t):
    """T_a_c(t) = T_a_b(t) T_b_c(t) and T_b_a(t) = T_a_b(t)^-1 at any time, any path."""
    buf = FrameBuffer()
    buf.set_transform("a", "b", [0.0, 1.0], np.stack(Ts[0:2]))
    buf.set_transform("b", "c", [0.0, 0.5, 1.0], np.stack(Ts[2:5]))
    buf.set_static("a", "d", Ts[5])
    for x, y, z in [("a", "b", "c"), ("d", "a", "c"), ("c", "b", "d")]:
        np.testing.assert_allclose(
            buf.lookup(x, z, t), buf.lookup(x, y, t) @ buf.lookup(y, z, t), atol=1e-8
        )
        np.testing.assert_allclose(buf.lookup(z, x, t) @ buf.lookup(x, z, t), np.eye(4), atol=1e-8)


# ------------------------------------------------------------------------- bad input


def test_bad_input_is_a_value_error_that_names_the_problem():
    buf = FrameBuffer()
    I2 = np.stack([np.eye(4), np.eye(4)])
    buf.set_transform("world", "body", [0.0, 1.0], I2)
    with pytest.raises(ValueError, match=r"must increase; got 1.0 s after the newest"):
        buf.set_transform("world", "body", 1.0, np.eye(4))
    with pytest.raises(ValueError, match=r"must increase; got 3.0 then 2.0"):
        buf.set_transform("world", "body", [3.0, 2.0], I2)
    with pytest.raises(ValueError, match=r"finite"):
        buf.set_transform("world", "body", [np.nan], I2[:1])
    with pytest.raises(ValueError, match=r"shape \(2, 4, 4\) for 2 stamps"):
        buf.set_transform("world", "body", [5.0, 6.0], np.eye(4))
    with pytest.raises(ValueError, match=r"already has parent 'world'"):
        buf.set_transform("map", "body", 5.0, np.eye(4))
    with pytest.raises(ValueError, match=r"time-stamped; it cannot become static"):
        buf.set_static("world", "body", np.eye(4))
    buf.set_static("body", "camera", np.eye(4))
    with pytest.raises(ValueError, match=r"is static"):
        buf.set_transform("body", "camera", 5.0, np.eye(4))
    with pytest.raises(ValueError, match=r"close a cycle"):
        buf.set_static("camera", "world", np.eye(4))
    with pytest.raises(ValueError, match=r"not a rotation|rotation block"):
        buf.set_transform("world", "body", 5.0, np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match=r"needs t_s: edge 'world' -> 'body'"):
        buf.lookup("world", "camera")
    with pytest.raises(ValueError, match=r"both source_time_s and fixed"):
        buf.lookup("body", "camera", 0.5, source_time_s=0.4)
    with pytest.raises(ValueError, match=r"unknown frame 'map'"):
        buf.lookup("map", "camera", 0.5)
    with pytest.raises(ValueError, match=r"t_s must be finite"):
        buf.lookup("world", "camera", np.inf)
    assert not buf.can_lookup("map", "camera", 0.5)
    for bad in (0.0, -1.0, np.inf, "10", True):
        with pytest.raises(ValueError, match="cache_s"):
            FrameBuffer(cache_s=bad)


def _screw_pose(t: float) -> np.ndarray:
    """The writer's pose at ``t``: a constant-rate turn about z and a straight line, which the
    buffer's interpolation (slerp, linear) reproduces exactly between any two samples."""
    return se3.make(so3.rot_z(0.3 * t), [t, -2.0 * t, 0.5])


def test_one_writer_and_three_readers_never_see_a_torn_edge():
    """One thread appends samples at 1 kHz of simulated time (trimming a 0.5 s cache as it
    goes), three look up single times and arrays of times inside the interval they last
    saw. Every lookup is either the true pose or an ``ExtrapolationError`` (the time was
    trimmed meanwhile): never another exception, never a pose mixed from two states."""
    import sys
    import threading

    buf = FrameBuffer(cache_s=0.5)
    dt = 1e-3
    buf.set_transform("world", "body", 0.0, _screw_pose(0.0))
    stop = threading.Event()
    errors: list[str] = []
    counts = [0, 0, 0]

    def write() -> None:
        k = 1
        while not stop.is_set():
            stamps = (k + np.arange(3)) * dt
            buf.set_transform("world", "body", stamps, np.stack([_screw_pose(s) for s in stamps]))
            k += 3

    def read(slot: int) -> None:
        rng = np.random.default_rng(slot)
        while not stop.is_set():
            try:
                first, last = buf.interval("world", "body")
                if counts[slot] % 4:
                    t = float(rng.uniform(first, last))
                    got, want = buf.lookup("world", "body", t), _screw_pose(t)
                else:
                    t = np.sort(rng.uniform(first, last, 8))
                    got = buf.lookup("world", "body", t)
                    want = np.stack([_screw_pose(s) for s in t])
                if not np.allclose(got, want, atol=1e-9):
                    errors.append(f"wrong pose at t = {t}")
            except ExtrapolationError:
                pass
            except Exception as exc:  # the failure this test looks for
                errors.append(f"{type(exc).__name__}: {exc}")
            counts[slot] += 1

    switch = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # switch threads as often as possible: races show quickly
    threads = [threading.Thread(target=write)] + [
        threading.Thread(target=read, args=(i,)) for i in range(3)
    ]
    try:
        for thread in threads:
            thread.start()
        stop.wait(3.0)
    finally:
        stop.set()
        for thread in threads:
            thread.join()
        sys.setswitchinterval(switch)
    assert min(counts) > 100, counts
    assert not errors, f"{len(errors)} of {sum(counts)} lookups: {errors[:3]}"
