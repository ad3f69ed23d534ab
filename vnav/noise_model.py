"""The sensors' noise model, declared once: each figure's name, unit, meaning, range and default.

One figure is one field of ``NoiseModel``, with its ``Figure`` as metadata. The simulator draws
its noise from it (``sim.noise``), the estimator is told it and propagates it into each
estimate's covariance (``vnav.sensor_noise``, ``vnav.covariance``), and the scenario file's
``[noise]`` keys are its fields (``scenarios.scenario.schema.NOISE`` is derived from
``FIGURES``). Four things carry noise (``SENSORS``):

- **the pose stream**: per sample, a Gaussian error on the body position in world axes and a
  Gaussian rotation vector in the body frame (``R_w_b @ exp(dtheta_b)``);
- **the image**: Gaussian noise on each 8-bit colour value, rounded and clipped to 0-255;
  its unit is the grey level (a 256th of the range), not the pixel;
- **the depth image**: Gaussian per pixel, ``sigma = depth_std_m + depth_std_per_m2 * z**2``
  (stereo-like growth with the planar depth ``z``);
- **the camera mount**: once per run, the mount given to the estimator is
  ``exp([rho, phi]^) @ T_b_c``, a left perturbation (docs/CONVENTIONS.md, "Uncertainty").

Degrees appear here as configuration does, in names that say so; ``attitude_std_rad`` and
``extrinsic_std_rad`` convert them for the simulator and the estimator alike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

__all__ = ["FIGURES", "NOISELESS", "SENSORS", "Figure", "NoiseModel"]

SENSORS: tuple[str, ...] = ("pose", "image", "depth", "mount")
"""What a figure perturbs: the pose stream, the image, the depth image, the declared camera
mount."""


@dataclass(frozen=True)
class Figure:
    """The declaration of one noise figure: the metadata of a ``NoiseModel`` field.

    Attributes
    ----------
    sensor : str
        What it perturbs, one of ``SENSORS``.
    unit : str
        Its unit, in words (the field's name says it too).
    doc : str
        What it is, one line, without the unit.
    hi : float
        The largest value accepted.
    lo : float
        The smallest value accepted: 0, a standard deviation.
    """

    sensor: str
    unit: str
    doc: str
    hi: float
    lo: float = 0.0

    @property
    def line(self) -> str:
        """``doc, unit``: the comment a scenario file's key carries (``vnav-demo show``)."""
        return f"{self.doc}, {self.unit}"


def _figure(sensor: str, unit: str, doc: str, hi: float, default: float = 0.0) -> Any:
    """A ``NoiseModel`` field: its default and, as metadata, its ``Figure``."""
    return field(default=default, metadata={"figure": Figure(sensor, unit, doc, hi)})


@dataclass(frozen=True)
class NoiseModel:
    """Every noise figure of the sensors: what the simulator adds, and what the estimator is
    told (as a real one is told its sensors' data sheets). All zero: no noise.

    Each field is validated when the model is made (a finite number in its declared range,
    stored as float); ``ValueError`` names the field otherwise. The Attributes below are
    written from each field's ``Figure``.
    """

    position_std_m: float = _figure("pose", "m", "error added to the body position", 100.0)
    attitude_std_deg: float = _figure("pose", "deg", "error added to the attitude", 180.0)
    intensity_std_grey: float = _figure(
        "image", "8-bit grey levels", "noise on each image colour value", 128.0
    )
    depth_std_m: float = _figure("depth", "m", "depth noise at zero range", 10.0)
    depth_std_per_m2: float = _figure("depth", "1/m", "depth noise = depth_std_m + this * z^2", 1.0)
    extrinsic_std_m: float = _figure("mount", "m", "error on the declared camera mount T_b_c", 1.0)
    extrinsic_std_deg: float = _figure(
        "mount", "deg", "error on the declared mount's rotation", 45.0
    )

    def __post_init__(self) -> None:
        for name, figure in FIGURES.items():
            value = _finite(getattr(self, name), f"NoiseModel.{name}")
            if not figure.lo <= value <= figure.hi:
                raise ValueError(
                    f"NoiseModel.{name} must be in [{figure.lo:g}, {figure.hi:g}] "
                    f"({figure.unit}), got {value!r}"
                )
            object.__setattr__(self, name, value)

    def noisy(self, sensor: str) -> bool:
        """Whether any figure of ``sensor`` (one of ``SENSORS``) is above zero."""
        if sensor not in SENSORS:
            raise ValueError(f"sensor must be one of {list(SENSORS)}, got {sensor!r}")
        return any(getattr(self, n) > 0.0 for n, f in FIGURES.items() if f.sensor == sensor)

    @property
    def attitude_std_rad(self) -> float:
        """``attitude_std_deg`` in radians."""
        return math.radians(self.attitude_std_deg)

    @property
    def extrinsic_std_rad(self) -> float:
        """``extrinsic_std_deg`` in radians."""
        return math.radians(self.extrinsic_std_deg)

    def depth_std_at(self, z_m: float | np.ndarray) -> float | np.ndarray:
        """Depth noise at planar depth ``z_m``, metres (same shape): the standard deviation the
        simulator draws with and the estimator propagates."""
        return self.depth_std_m + self.depth_std_per_m2 * z_m * z_m


def _finite(value: Any, name: str) -> float:
    """``value`` as a finite float; a bool, a string or an overflowing integer is refused."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{name} must be a number, got {value!r}")
    try:
        out = float(value)
    except OverflowError:
        raise ValueError(
            f"{name} must be a finite number, got a {value.bit_length()}-bit integer"
        ) from None
    if not math.isfinite(out):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return out


FIGURES: dict[str, Figure] = {f.name: f.metadata["figure"] for f in fields(NoiseModel)}
"""Each figure's declaration by field name, in the fields' order."""

NOISELESS = NoiseModel()
"""No noise anywhere: the defaults, and ``vnav.localize``'s default."""


def _attributes_doc() -> str:
    """The numpy-style Attributes section of ``NoiseModel``, from its figures."""
    lines = ["", "    Attributes", "    ----------"]
    for name, figure in FIGURES.items():
        lines.append(f"    {name} : float")
        lines.append(
            f"        {figure.doc} ({figure.sensor}), {figure.unit}; in "
            f"[{figure.lo:g}, {figure.hi:g}], default {getattr(NOISELESS, name):g}."
        )
    return "\n".join(lines) + "\n"


NoiseModel.__doc__ = (NoiseModel.__doc__ or "") + _attributes_doc()
