"""``sim.noise``: the noise the simulator adds has the statistics the scenario declares.

Tolerances are statistical: a sample mean's standard error is ``std / sqrt(n)``, a sample
variance's relative standard error ``sqrt(2 / n)``; each figure is held to 5 of them.
"""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np
import pytest

from sim.noise import mount_error, noisy_depth, noisy_rgb
from vnav.uncertainty import se3_log


def test_noisy_rgb_has_the_declared_std_and_keeps_the_image_type() -> None:
    rng = np.random.default_rng(1)
    grey = np.full((200, 200, 3), 128, dtype=np.uint8)
    out = noisy_rgb(grey, 4.0, rng)
    assert out.dtype == np.uint8 and out.shape == grey.shape
    err = out.astype(np.float64) - 128.0
    n = err.size
    assert abs(err.mean()) <= 5 * 4.0 / math.sqrt(n)
    # Rounding to whole levels adds 1/12 level^2 of variance (uniform on [-1/2, 1/2]).
    assert err.var() / (16.0 + 1.0 / 12.0) == pytest.approx(1.0, abs=5 * math.sqrt(2.0 / n))
    assert noisy_rgb(grey, 0.0, rng) is grey


def test_noisy_rgb_clips_at_black_and_white() -> None:
    """At 0 the noise is clipped to ``max(0, N)``: mean ``std / sqrt(2 pi)`` before rounding;
    at 255 nothing wraps round to dark values."""
    rng = np.random.default_rng(2)
    black = np.zeros((200, 200, 3), dtype=np.uint8)
    out = noisy_rgb(black, 4.0, rng).astype(np.float64)
    # Rounded: E[round(max(0, N))] = sum_k k P(k - 1/2 < N < k + 1/2) for k >= 1.
    k = np.arange(1, 60)
    cdf = NormalDist(0.0, 4.0).cdf
    expected = float(sum(kk * (cdf(kk + 0.5) - cdf(kk - 0.5)) for kk in k))
    assert out.mean() == pytest.approx(expected, abs=5 * 4.0 / math.sqrt(out.size))
    white = np.full((200, 200, 3), 255, dtype=np.uint8)
    assert noisy_rgb(white, 4.0, rng).min() > 200


def test_noisy_rgb_is_reproducible_from_the_seed() -> None:
    grey = np.full((50, 50, 3), 100, dtype=np.uint8)
    a = noisy_rgb(grey, 3.0, np.random.default_rng(7))
    b = noisy_rgb(grey, 3.0, np.random.default_rng(7))
    c = noisy_rgb(grey, 3.0, np.random.default_rng(8))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_noisy_depth_grows_with_the_square_of_depth_and_leaves_no_return_alone() -> None:
    rng = np.random.default_rng(3)
    far_m = 50.0
    depth = np.empty((300, 300), dtype=np.float32)
    depth[:100] = 2.0
    depth[100:200] = 10.0
    depth[200:250] = far_m  # no return
    depth[250:] = 0.0  # no return
    before = depth.copy()
    out = noisy_depth(depth, 0.01, 0.001, far_m, rng)
    np.testing.assert_array_equal(depth, before)  # the input is not modified
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out[200:], depth[200:])
    for rows, z in ((slice(0, 100), 2.0), (slice(100, 200), 10.0)):
        err = out[rows].astype(np.float64) - z
        sigma = 0.01 + 0.001 * z * z
        n = err.size
        assert abs(err.mean()) <= 5 * sigma / math.sqrt(n)
        assert err.std() / sigma == pytest.approx(1.0, abs=5 * math.sqrt(0.5 / n))
    assert noisy_depth(depth, 0.0, 0.0, far_m, rng) is depth


def test_mount_error_draws_the_declared_left_perturbation() -> None:
    rng = np.random.default_rng(4)
    np.testing.assert_array_equal(mount_error(0.0, 0.0, rng), np.eye(4))
    E = mount_error(0.01, 2.0, rng)
    R = E[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    n = 4000
    xis = np.array([se3_log(mount_error(0.01, 2.0, rng)) for _ in range(n)])
    expected = np.array([0.01**2] * 3 + [math.radians(2.0) ** 2] * 3)
    np.testing.assert_allclose(xis.var(axis=0) / expected, 1.0, atol=5 * math.sqrt(2.0 / n))
    assert np.all(np.abs(xis.mean(axis=0)) <= 5 * np.sqrt(expected / n))
