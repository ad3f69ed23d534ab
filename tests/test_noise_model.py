"""``vnav.noise_model``: the noise figures declared once."""

from __future__ import annotations

import math

import pytest

from vnav.noise_model import FIGURES, NOISELESS, SENSORS, NoiseModel


def test_every_sensor_has_a_figure_and_every_name_says_its_unit() -> None:
    assert {f.sensor for f in FIGURES.values()} == set(SENSORS)
    suffixes = {"m": "_m", "deg": "_deg", "1/m": "_per_m2", "8-bit grey levels": "_grey"}
    for name, figure in FIGURES.items():
        assert name.endswith(suffixes[figure.unit]), name


def test_model_stores_floats_and_refuses_what_is_not_a_number() -> None:
    assert type(NoiseModel(intensity_std_grey=4).intensity_std_grey) is float
    for bad in (True, "1", None, math.inf, 10**400):
        with pytest.raises(ValueError, match=r"NoiseModel\.depth_std_m must be"):
            NoiseModel(depth_std_m=bad)


def test_noisy_says_which_sensors_carry_noise() -> None:
    noise = NoiseModel(attitude_std_deg=1.0, depth_std_per_m2=0.001)
    assert [s for s in SENSORS if noise.noisy(s)] == ["pose", "depth"]
    assert not any(NOISELESS.noisy(s) for s in SENSORS)
    with pytest.raises(ValueError, match="sensor must be one of"):
        noise.noisy("imu")


def test_degrees_convert_once() -> None:
    noise = NoiseModel(attitude_std_deg=1.0, extrinsic_std_deg=2.0)
    assert noise.attitude_std_rad == math.radians(1.0)
    assert noise.extrinsic_std_rad == math.radians(2.0)


def test_docstring_lists_every_figure() -> None:
    doc = NoiseModel.__doc__ or ""
    for name, figure in FIGURES.items():
        assert f"{name} : float" in doc and figure.doc in doc
