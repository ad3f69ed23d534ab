"""Private input checks shared by ``so3``, ``quat``, ``se3``, ``frames`` and ``uncertainty``.

Every public function of the geometry core validates at its edge through these helpers, so the
error messages read the same everywhere: the argument's name, what was expected, what was
received (docs/CONVENTIONS.md, "Errors").
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def as_float(x: ArrayLike, name: str) -> FloatArray:
    """Convert ``x`` to a float64 array (no copy when it already is one).

    Raises
    ------
    ValueError
        If ``x`` cannot be read as an array of real numbers.
    """
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be an array of real numbers; got {_describe(x)}") from exc
    return a


def _describe(x: Any) -> str:
    text = repr(x)
    return text if len(text) <= 60 else text[:57] + "..."


def shape_text(trailing: tuple[int, ...], batched: bool) -> str:
    """Render an expected shape such as ``(..., 3, 3)`` or ``(3,)``."""
    dims = ", ".join(str(d) for d in trailing)
    if batched:
        return f"(..., {dims})"
    return f"({dims},)" if len(trailing) == 1 else f"({dims})"


def check_shape(
    a: FloatArray, name: str, trailing: tuple[int, ...], *, batched: bool = True
) -> FloatArray:
    """Check that ``a`` ends with the dimensions ``trailing`` (exactly, when not batched).

    Raises
    ------
    ValueError
        Naming ``name``, the expected shape and the shape received.
    """
    ok = a.shape[a.ndim - len(trailing) :] == trailing if a.ndim >= len(trailing) else False
    if ok and not batched:
        ok = a.ndim == len(trailing)
    if not ok:
        raise ValueError(
            f"{name} must have shape {shape_text(trailing, batched)}; got shape {a.shape}"
        )
    return a


_REAL_TYPES = (int, float, np.floating, np.integer)


def tolerance(atol: object, name: str = "atol") -> float:
    """A validated tolerance: a finite number >= 0 (NaN would accept anything).

    A plain float in range returns at once (every pose check passes through here); a numpy
    scalar or 0-d array is read as the number it holds.

    Raises
    ------
    ValueError
        Naming ``name`` and the value received.
    """
    if type(atol) is float and 0.0 <= atol < math.inf:
        return atol
    if isinstance(atol, np.ndarray) and atol.ndim == 0:
        atol = atol[()]
    if isinstance(atol, bool | np.bool_) or not isinstance(atol, _REAL_TYPES):
        raise ValueError(f"{name} must be a number, got {_describe(atol)}")
    if not (math.isfinite(atol) and atol >= 0.0):
        raise ValueError(f"{name} must be a finite number >= 0, got {atol!r}")
    return float(atol)


_FLOAT64 = np.dtype(np.float64)


def widened_for(atol: float, source_dtype: object) -> float:
    """``atol``, or at least 16 machine epsilons of a lower-precision float input (float32,
    float16): its rounding alone exceeds a float64 tolerance such as 1e-9."""
    if source_dtype is None or source_dtype is _FLOAT64:
        return atol  # the common case, without the costlier dtype queries below
    if not np.issubdtype(source_dtype, np.floating):
        return atol
    eps = float(np.finfo(source_dtype).eps)
    return max(atol, 16.0 * eps) if eps > float(np.finfo(np.float64).eps) else atol


_SMALL = 64
"""Arrays up to this many entries are checked element-wise (see check_finite)."""


def check_finite(a: FloatArray, name: str) -> FloatArray:
    """Check that ``a`` holds no NaN or inf.

    For a large array a single reduction (the sum) finds them: NaN and inf propagate through it.
    Only when the sum is not finite (a NaN, an inf, or an overflow of huge values) is the
    element-wise test run to tell which. Small arrays are tested element-wise at once.

    Raises
    ------
    ValueError
        Naming ``name`` and how many entries are NaN or inf.
    """
    if a.size <= _SMALL:
        # A pose or a point: one element-wise test is cheaper than entering np.errstate.
        all_finite = bool(np.isfinite(a).all())
    else:
        with np.errstate(over="ignore", invalid="ignore"):
            all_finite = bool(np.isfinite(np.add.reduce(a, axis=None)))
    if not all_finite:
        bad = ~np.isfinite(a)
        if bad.any():
            n_nan = int(np.isnan(a).sum())
            n_inf = int(bad.sum()) - n_nan
            raise ValueError(
                f"{name} must be finite; got {n_nan} NaN and {n_inf} inf entries "
                f"in an array of shape {a.shape}"
            )
    return a


def vector(
    x: ArrayLike, name: str, size: int = 3, *, batched: bool = True, finite: bool = True
) -> FloatArray:
    """``x`` as a float64 array of shape (..., size) (or exactly (size,)), checked finite."""
    a = check_shape(as_float(x, name), name, (size,), batched=batched)
    return check_finite(a, name) if finite else a


def matrix(
    x: ArrayLike, name: str, size: int = 3, *, batched: bool = True, finite: bool = True
) -> FloatArray:
    """``x`` as a float64 array of shape (..., size, size), checked finite."""
    a = check_shape(as_float(x, name), name, (size, size), batched=batched)
    return check_finite(a, name) if finite else a


def scalar_or_array(x: ArrayLike, name: str) -> FloatArray:
    """``x`` as a finite float64 array of any shape (angles, interpolation parameters)."""
    return check_finite(as_float(x, name), name)
