"""vnav.methods: the methods and their accuracy contract, declared once, against hand values."""

from __future__ import annotations

import numpy as np
import pytest

from vnav.methods import (
    CONTRACT_DOMAIN,
    METHOD_NAMES,
    METHODS,
    PREFERENCE,
    AccuracyBound,
    method,
)


def test_allowed_m_by_hand() -> None:
    depth = AccuracyBound(0.05, 0.01, "max")  # max(5 cm, 1% of range)
    np.testing.assert_allclose(
        depth.allowed_m([0.0, 2.0, 5.0, 10.0, 25.0]), [0.05] * 3 + [0.1, 0.25]
    )
    ground = AccuracyBound(0.10, 0.02, "median")  # max(10 cm, 2% of range)
    np.testing.assert_allclose(ground.allowed_m(np.array([1.0, 5.0, 20.0])), [0.1, 0.1, 0.4])
    known = AccuracyBound(0.0, 0.05, "median")  # 5% of range
    np.testing.assert_allclose(known.allowed_m(np.array([[2.0, 24.0]])), [[0.1, 1.2]])
    assert known.allowed_m(np.array([[2.0, 24.0]])).shape == (1, 2)
    assert float(depth.allowed_m(3.0)) == pytest.approx(0.05)


def test_bounds_in_words() -> None:
    assert AccuracyBound(0.05, 0.01, "max").text == "every error <= max(5 cm, 1% of range)"
    assert AccuracyBound(0.0, 0.05, "median").text == "median <= 5% of range"
    assert method("naive").promise == "reported, never checked"
    assert CONTRACT_DOMAIN.text == "cone fully in view, >= 12 px, 2-25 m"


def test_declared_bounds_are_the_contract() -> None:
    """docs/ACCURACY.md's numbers, written out."""
    assert method("depth_image").bound == AccuracyBound(0.05, 0.01, "max")
    assert method("ground_plane").bound == AccuracyBound(0.10, 0.02, "median")
    assert method("known_height").bound == AccuracyBound(0.0, 0.05, "median")
    assert method("naive").bound is None
    assert (CONTRACT_DOMAIN.min_range_m, CONTRACT_DOMAIN.max_range_m) == (2.0, 25.0)
    assert CONTRACT_DOMAIN.min_height_px == 12.0
    assert CONTRACT_DOMAIN.contains_range(2.0) and CONTRACT_DOMAIN.contains_range(25.0)
    assert not CONTRACT_DOMAIN.contains_range(1.99) and not CONTRACT_DOMAIN.contains_range(25.01)


def test_names_and_preference() -> None:
    assert METHOD_NAMES == ("depth_image", "ground_plane", "known_height", "triangulated", "naive")
    assert METHOD_NAMES == tuple(m.name for m in METHODS)
    # The checked methods, best first: the naive estimate is never the best estimate.
    assert PREFERENCE == ("depth_image", "ground_plane", "known_height", "triangulated")
    assert "naive" not in PREFERENCE
    assert all(method(name).bound is not None for name in PREFERENCE)
    assert len({m.color_rgb for m in METHODS}) == len(METHODS)  # one colour each


def test_method_lookup_and_unknown_name() -> None:
    for m in METHODS:
        assert method(m.name) is m
    with pytest.raises(ValueError, match=r"unknown method 'lidar'; valid: \['depth_image', "):
        method("lidar")
    with pytest.raises(ValueError, match=r"unknown method 'Depth_Image'"):
        method("Depth_Image")
