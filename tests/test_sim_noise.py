"""``sim.noise``: the noise the simulator adds has the statistics the scenario declares.

Tolerances are statistical: a sample mean's standard error is ``std / sqrt(n)``, a sample
variance's relative standard error ``sqrt(2 / n)`` (a sample std's ``sqrt(1 / (2 n))``), a
sample correlation's standard error ``1 / sqrt(n)`` when the true one is zero; each figure is
held to 5 of them, so that a correct implementation fails about once in two million.
"""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np
import pytest

from sim.noise import mount_error, noisy_depth, noisy_rgb
from vnav import se3
from vnav.noise_model import NoiseModel

N_SIGMA = 5.0
"""How many standard errors a sample statistic may lie from its expected value."""


# ------------------------------------------------------------------------------ noisy_rgb


def test_noisy_rgb_with_zero_std_returns_the_input_itself() -> None:
    """``std = 0`` is documented to return ``rgb`` itself, drawing nothing: the generator's
    state is left as it was (the next draw equals a fresh generator's)."""
    rng = np.random.default_rng(0)
    grey = np.full((4, 5, 3), 77, dtype=np.uint8)
    assert noisy_rgb(grey, NoiseModel(), rng) is grey
    assert rng.standard_normal() == np.random.default_rng(0).standard_normal()


def test_noisy_rgb_has_zero_mean_and_the_declared_std_and_keeps_the_image_type() -> None:
    """On mid-grey (128, far from both clips) the error of each colour value is a rounded
    Gaussian: mean 0 and variance ``std^2 + 1/12`` (rounding to whole levels adds a uniform
    error on [-1/2, 1/2], Sheppard's correction); shape and uint8 dtype are kept and the
    input is not modified."""
    rng = np.random.default_rng(1)
    std = 4.0
    grey = np.full((200, 200, 3), 128, dtype=np.uint8)
    out = noisy_rgb(grey, NoiseModel(intensity_std_grey=std), rng)
    assert out.dtype == np.uint8 and out.shape == grey.shape
    assert np.all(grey == 128)
    err = out.astype(np.float64) - 128.0
    np.testing.assert_array_equal(err, np.round(err))  # whole levels
    n = err.size
    assert abs(err.mean()) <= N_SIGMA * std / math.sqrt(n)
    expected_var = std**2 + 1.0 / 12.0
    assert err.var() / expected_var == pytest.approx(1.0, abs=N_SIGMA * math.sqrt(2.0 / n))
    # Independent per value: neighbouring values (along a row, across channels) uncorrelated.
    for a, b in ((err[:, :-1], err[:, 1:]), (err[..., 0], err[..., 1])):
        r = np.corrcoef(a.ravel(), b.ravel())[0, 1]
        assert abs(r) <= N_SIGMA / math.sqrt(a.size)


def _rounded_rectified_gaussian_mean(std: float) -> float:
    """``E[round(max(0, N(0, std^2)))] = sum_k k P(k - 1/2 < N < k + 1/2)`` for ``k >= 1``
    (the definition, summed to 15 std where the tail is below double precision)."""
    cdf = NormalDist(0.0, std).cdf
    return sum(k * (cdf(k + 0.5) - cdf(k - 0.5)) for k in range(1, math.ceil(15 * std) + 1))


def test_noisy_rgb_clips_at_black_and_white_instead_of_wrapping() -> None:
    """At 0 the value is ``round(max(0, N))``: its mean is the rounded rectified Gaussian's
    (close to ``std / sqrt(2 pi)`` before rounding); at 255 it is ``255 - round(max(0, N))``
    by symmetry. A uint8 wrap-around would put values near 255 in the black image and near 0
    in the white one."""
    rng = np.random.default_rng(2)
    std = 4.0
    expected = _rounded_rectified_gaussian_mean(std)
    # The same figure before rounding, the rectified Gaussian's mean: |round(x) - x| <= 1/2
    # bounds the difference.
    assert expected == pytest.approx(std / math.sqrt(2.0 * math.pi), abs=0.5)
    black = np.zeros((200, 200, 3), dtype=np.uint8)
    white = np.full((200, 200, 3), 255, dtype=np.uint8)
    noise = NoiseModel(intensity_std_grey=std)
    out_black = noisy_rgb(black, noise, rng).astype(np.float64)
    out_white = noisy_rgb(white, noise, rng).astype(np.float64)
    # Nothing beyond 10 std of the clip: a wrapped value would be ~255 levels away.
    assert out_black.max() <= 10 * std and out_white.min() >= 255 - 10 * std
    # The clipped value's std is below ``std``: ``std / sqrt(n)`` bounds its standard error.
    tol = N_SIGMA * std / math.sqrt(out_black.size)
    assert out_black.mean() == pytest.approx(expected, abs=tol)
    assert 255.0 - out_white.mean() == pytest.approx(expected, abs=tol)


def test_noisy_rgb_is_reproducible_from_the_seed() -> None:
    """The same seed gives the same image (a run is repeatable); another seed another one."""
    grey = np.full((50, 50, 3), 100, dtype=np.uint8)
    noise = NoiseModel(intensity_std_grey=3.0)
    a = noisy_rgb(grey, noise, np.random.default_rng(7))
    b = noisy_rgb(grey, noise, np.random.default_rng(7))
    c = noisy_rgb(grey, noise, np.random.default_rng(8))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


# ---------------------------------------------------------------------------- noisy_depth


def test_noisy_depth_std_grows_with_the_square_of_depth() -> None:
    """``sigma = std_m + std_per_m2 * z**2``: checked at 2 m and 10 m (sigma 0.014 and
    0.11 m), 30 000 pixels each, against the sample mean (0) and the sample std; float32 is
    kept and the input is not modified."""
    rng = np.random.default_rng(3)
    std_m, std_per_m2, far_m = 0.01, 0.001, 50.0
    depth = np.empty((200, 300), dtype=np.float32)
    depth[:100] = 2.0
    depth[100:] = 10.0
    before = depth.copy()
    out = noisy_depth(depth, NoiseModel(depth_std_m=std_m, depth_std_per_m2=std_per_m2), far_m, rng)
    np.testing.assert_array_equal(depth, before)
    assert out.dtype == np.float32 and out.shape == depth.shape
    for rows, z in ((slice(0, 100), 2.0), (slice(100, 200), 10.0)):
        err = out[rows].astype(np.float64) - z
        sigma = std_m + std_per_m2 * z * z
        n = err.size
        assert abs(err.mean()) <= N_SIGMA * sigma / math.sqrt(n)
        assert err.std() / sigma == pytest.approx(1.0, abs=N_SIGMA * math.sqrt(0.5 / n))


def test_noisy_depth_leaves_pixels_with_no_return_alone() -> None:
    """A pixel at 0 (no return) or at or beyond ``far_m`` is reported as it is, not with noise:
    a sensor gives no noisy depth where it got no echo. Valid pixels beside them do change."""
    rng = np.random.default_rng(4)
    far_m = 20.0
    depth = np.zeros((60, 60), dtype=np.float32)
    depth[:20] = far_m
    depth[20:30] = far_m + 5.0
    depth[30:40] = 0.0
    depth[40:] = 5.0
    out = noisy_depth(depth, NoiseModel(depth_std_m=0.05, depth_std_per_m2=0.01), far_m, rng)
    np.testing.assert_array_equal(out[:40], depth[:40])
    assert np.all(out[40:] != depth[40:])


def test_noisy_depth_never_reports_a_negative_depth() -> None:
    """At 1 cm with 5 cm of noise half the raw draws cross zero; the function documents that
    the result stays positive (a sensor reports no negative depth)."""
    rng = np.random.default_rng(5)
    depth = np.full((100, 100), 0.01, dtype=np.float32)
    out = noisy_depth(depth, NoiseModel(depth_std_m=0.05), 10.0, rng)
    assert np.all(out > 0.0)


def test_noisy_depth_with_both_std_zero_returns_the_input_itself() -> None:
    """Both figures zero: nothing to add, the input itself comes back."""
    depth = np.full((8, 8), 3.0, dtype=np.float32)
    assert noisy_depth(depth, NoiseModel(), 10.0, np.random.default_rng(6)) is depth


# ---------------------------------------------------------------------------- mount_error


def test_mount_error_is_the_identity_without_noise() -> None:
    """Both std zero: the declared mount is the true one."""
    np.testing.assert_array_equal(mount_error(NoiseModel(), np.random.default_rng(7)), np.eye(4))


def test_mount_error_is_a_rigid_transform() -> None:
    """Each draw is in SE(3): rotation block orthonormal with determinant +1, last row
    ``[0, 0, 0, 1]`` (the largest rotation std declared, 45 deg, so that rotations are far
    from the identity)."""
    rng = np.random.default_rng(8)
    noise = NoiseModel(extrinsic_std_m=0.5, extrinsic_std_deg=45.0)
    for _ in range(50):
        E = mount_error(noise, rng)
        R = E[:3, :3]
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
        np.testing.assert_array_equal(E[3], [0.0, 0.0, 0.0, 1.0])


def test_mount_error_draws_the_declared_left_perturbation() -> None:
    """``se3.log(E) = [rho, phi]`` over 4000 draws has mean 0 and the covariance
    ``diag(std_m^2 I3, std_rad^2 I3)``: variances to ``sqrt(2 / n)`` relative, correlations
    to ``1 / sqrt(n)`` (each at 5 standard errors)."""
    rng = np.random.default_rng(9)
    std_m, std_deg = 0.01, 2.0
    n = 4000
    noise = NoiseModel(extrinsic_std_m=std_m, extrinsic_std_deg=std_deg)
    xis = np.array([se3.log(mount_error(noise, rng)) for _ in range(n)])
    expected_var = np.array([std_m**2] * 3 + [math.radians(std_deg) ** 2] * 3)
    assert np.all(np.abs(xis.mean(axis=0)) <= N_SIGMA * np.sqrt(expected_var / n))
    cov = np.cov(xis, rowvar=False)
    np.testing.assert_allclose(
        np.diag(cov) / expected_var, 1.0, atol=N_SIGMA * math.sqrt(2.0 / (n - 1))
    )
    corr = cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    off = corr[~np.eye(6, dtype=bool)]
    assert np.all(np.abs(off) <= N_SIGMA / math.sqrt(n))


def test_mount_error_is_reproducible_from_the_seed() -> None:
    """The mount error is drawn once per run from the run's generator: the same seed gives
    the same error, another seed another one."""
    noise = NoiseModel(extrinsic_std_m=0.01, extrinsic_std_deg=1.0)
    a = mount_error(noise, np.random.default_rng(10))
    b = mount_error(noise, np.random.default_rng(10))
    c = mount_error(noise, np.random.default_rng(11))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
