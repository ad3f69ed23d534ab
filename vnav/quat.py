"""Unit quaternions, scalar last ``[x, y, z, w]`` (lecture chapter 6).

vnav stores a quaternion as ``[x, y, z, w]``, the lecture's ``q = [v; s]`` with
``v = sin(theta/2) u`` and ``s = cos(theta/2)``. MuJoCo stores ``[w, x, y, z]``: convert with
``xyzw_to_wxyz`` / ``wxyz_to_xyzw`` exactly where data crosses that border; SciPy and Rerun are
scalar last like vnav. ``q`` and ``-q`` are the same rotation (the double cover of SO(3) by
S^3). Products are Hamilton's: ``to_matrix(multiply(a, b)) == to_matrix(a) @ to_matrix(b)``.

Only unit quaternions are accepted: a non-unit input raises ``ValueError`` unless the caller
opts in with ``normalize=True`` (where offered) or calls ``normalize`` first. Every function is
batched over leading axes: a (..., 4) stack of quaternions. Conventions: docs/CONVENTIONS.md.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from vnav import _validate as _v
from vnav import so3
from vnav._validate import FloatArray

__all__ = [
    "check_quaternion",
    "conjugate",
    "from_axis_angle",
    "from_matrix",
    "from_rotvec",
    "multiply",
    "normalize",
    "slerp",
    "to_axis_angle",
    "to_matrix",
    "to_rotvec",
    "wxyz_to_xyzw",
    "xyzw_to_wxyz",
]

_SMALL_ANGLE = 1e-4  # below it, sin(t/2)/t comes from its Taylor series
_CHUNK = 8192  # rows per block in `to_matrix` and `multiply`: keeps the temporaries in cache
_NORM_ATOL = 1e-6  # default tolerance on | |q| - 1 |
# Up to this many products, `multiply` runs its lecture form directly (the chunked kernel's
# fixed cost, tens of microseconds, only pays off on longer stacks).
_SMALL_STACK = 64


def _squared_norm(q: FloatArray) -> FloatArray:
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    with np.errstate(over="ignore"):
        return x * x + y * y + z * z + w * w


def _check_norm(
    n2: FloatArray,
    name: str,
    atol: float,
    *,
    allow_non_unit: bool = False,
    source_dtype: object = None,
) -> None:
    """Raise for a zero quaternion, or for a non-unit one unless ``allow_non_unit``.

    ``atol`` is widened for a lower-precision ``source_dtype`` (float32), which the message
    then names.
    """
    if n2.size == 0:
        return
    if np.any(n2 == 0.0):
        raise ValueError(
            f"{name} is the zero quaternion (norm 0), which is no rotation; a unit quaternion "
            "[x, y, z, w] is required"
        )
    if allow_non_unit:
        return
    tol = _v.widened_for(atol, source_dtype)
    # | |q| - 1 | <= tol, tested on the squared norm: |q|^2 - 1 = (|q| - 1)(|q| + 1).
    dev = np.abs(n2 - 1.0)
    if np.any(dev > tol * (2.0 + tol)):
        norm = np.sqrt(n2.flat[int(np.argmax(dev))])
        where = "" if n2.ndim == 0 else " (worst of the stack)"
        source = f" (the tolerance for {np.dtype(source_dtype)} input)" if tol != atol else ""
        raise ValueError(
            f"{name} must be a unit quaternion [x, y, z, w]; got norm {norm:.9g}{where}, "
            f"|norm - 1| > {tol:g}{source}; normalise explicitly with quat.normalize({name}) "
            "or pass normalize=True where the function offers it"
        )


def check_quaternion(q: ArrayLike, name: str = "q", atol: float = _NORM_ATOL) -> FloatArray:
    """Validate a unit quaternion ``[x, y, z, w]`` (or a stack) and return it as float64.

    Parameters
    ----------
    q : array_like, shape (..., 4)
    name : str
        The argument's name, used in error messages.
    atol : float
        Largest accepted ``| |q| - 1 |`` (finite, >= 0). A float32 (or float16) input is
        allowed 16 of its machine epsilons at least (1.9e-6 for float32), as for rotation
        matrices in ``vnav.so3.check_rotation``.

    Returns
    -------
    q : ndarray, shape (..., 4), float64
        The input (a view when it already was float64); never normalised.

    Raises
    ------
    ValueError
        If the shape is not (..., 4), an entry is NaN or inf, ``q`` is zero, or its norm
        differs from 1 by more than the tolerance (the message gives the norm received, the
        tolerance, naming the dtype when it was widened, and points at ``normalize=True``);
        or if ``atol`` is not a finite number >= 0.
    """
    atol = _v.tolerance(atol)
    source_dtype = getattr(q, "dtype", None)
    q = _v.vector(q, name, 4)
    _check_norm(_squared_norm(q), name, atol, source_dtype=source_dtype)
    return q


def normalize(q: ArrayLike) -> FloatArray:
    """``q / |q|``: the explicit opt-in for non-unit quaternions.

    Parameters
    ----------
    q : array_like, shape (..., 4)

    Returns
    -------
    ndarray, shape (..., 4)

    Raises
    ------
    ValueError
        If the shape is not (..., 4), an entry is NaN or inf, or ``q`` is zero.
    """
    q = _v.vector(q, "q", 4)
    # Scale by the largest magnitude first, so that |q|^2 neither overflows nor underflows.
    m = np.max(np.abs(q), axis=-1, keepdims=True)
    _check_norm(m[..., 0], "q", 0.0, allow_non_unit=True)
    q = q / m
    return q / np.sqrt(_squared_norm(q))[..., None]


_normalized = normalize  # for functions whose keyword argument `normalize` shadows it


def _unit(q: ArrayLike, name: str, normalize_: bool) -> FloatArray:
    return _normalized(q) if normalize_ else check_quaternion(q, name)


def xyzw_to_wxyz(q: ArrayLike) -> FloatArray:
    """Reorder scalar-last ``[x, y, z, w]`` (vnav, SciPy, Rerun) to ``[w, x, y, z]`` (MuJoCo).

    Parameters
    ----------
    q : array_like, shape (..., 4)

    Returns
    -------
    ndarray, shape (..., 4), a new array

    Raises
    ------
    ValueError
        If the shape is not (..., 4) or an entry is NaN or inf.
    """
    q = _v.vector(q, "q_xyzw", 4)
    return q[..., [3, 0, 1, 2]]


def wxyz_to_xyzw(q: ArrayLike) -> FloatArray:
    """Reorder ``[w, x, y, z]`` (MuJoCo) to scalar-last ``[x, y, z, w]`` (vnav).

    Parameters
    ----------
    q : array_like, shape (..., 4)

    Returns
    -------
    ndarray, shape (..., 4), a new array

    Raises
    ------
    ValueError
        If the shape is not (..., 4) or an entry is NaN or inf.
    """
    q = _v.vector(q, "q_wxyz", 4)
    return q[..., [1, 2, 3, 0]]


def from_axis_angle(axis: ArrayLike, angle: ArrayLike) -> FloatArray:
    """Quaternion ``[sin(angle/2) u, cos(angle/2)]`` of a rotation about ``axis`` (ch. 6).

    Parameters
    ----------
    axis : array_like, shape (..., 3)
        Rotation axis, any non-zero length: it is scaled to unit length (this is the axis's
        direction being read, not a quaternion being normalised).
    angle : float or array_like, shape (...)
        Radians, broadcast against the axis's leading shape.

    Returns
    -------
    q : ndarray, shape (..., 4)
        ``[x, y, z, w]``; no sign canonicalisation (an angle beyond pi gives w < 0).

    Raises
    ------
    ValueError
        If ``axis`` is not (..., 3), is zero, or an input holds NaN or inf.
    """
    axis = _v.vector(axis, "axis")
    angle = _v.scalar_or_array(angle, "angle")
    # Scaled by its largest component first, so that a huge (or tiny) axis neither overflows
    # nor underflows when squared.
    scale = np.max(np.abs(axis), axis=-1)
    if np.any(scale == 0.0):
        raise ValueError("axis must be non-zero: a zero vector has no direction to rotate about")
    axis = axis / scale[..., None]
    u = axis / np.sqrt(np.sum(axis * axis, axis=-1))[..., None]
    half = 0.5 * angle
    s = np.sin(half)
    c = np.cos(half)
    shape = np.broadcast_shapes(u.shape[:-1], half.shape)
    q = np.empty((*shape, 4))
    q[..., :3] = s[..., None] * u
    q[..., 3] = c
    return q


def to_axis_angle(q: ArrayLike, *, normalize: bool = False) -> tuple[FloatArray, FloatArray]:
    """Unit axis and angle in [0, pi] of a unit quaternion.

    The sign is canonicalised first (``q`` and ``-q`` give the same answer); the angle is
    ``2 atan2(|v|, |w|)``, accurate at every angle (unlike ``2 arccos(w)``).

    Parameters
    ----------
    q : array_like, shape (..., 4)
        ``[x, y, z, w]``.
    normalize : bool
        Accept a non-unit (non-zero) quaternion and normalise it.

    Returns
    -------
    axis : ndarray, shape (..., 3)
        Unit axis; ``[1, 0, 0]`` for the identity, whose axis is undefined.
    angle : ndarray, shape (...)
        Radians, in [0, pi].

    Raises
    ------
    ValueError
        See ``check_quaternion``.
    """
    q = _unit(q, "q", normalize)
    sign = np.where(q[..., 3] < 0.0, -1.0, 1.0)
    v = q[..., :3] * sign[..., None]
    w = q[..., 3] * sign
    n = np.sqrt(np.sum(v * v, axis=-1))
    angle = 2.0 * np.arctan2(n, w)
    zero = n == 0.0
    with np.errstate(invalid="ignore", divide="ignore"):
        axis = v / n[..., None]
    axis = np.where(zero[..., None], np.array([1.0, 0.0, 0.0]), axis)
    return axis, angle


def from_rotvec(rotvec: ArrayLike) -> FloatArray:
    """Quaternion of a rotation vector ``theta u`` (lecture chapter 6 with chapter 5's axis).

    ``q = [sin(theta/2)/theta * rotvec, cos(theta/2)]``, with a Taylor series of
    ``sin(theta/2)/theta`` below 1e-4 rad.

    Parameters
    ----------
    rotvec : array_like, shape (..., 3)
        Radians.

    Returns
    -------
    q : ndarray, shape (..., 4)
        ``[x, y, z, w]``, w >= 0 for angles up to pi.

    Raises
    ------
    ValueError
        If ``rotvec`` is not (..., 3), holds NaN or inf, or is so long that its squared length
        overflows (as ``so3.exp``).
    """
    v = _v.vector(rotvec, "rotvec")
    with np.errstate(over="ignore"):
        t2 = np.sum(v * v, axis=-1)
    if not np.all(np.isfinite(t2)):
        raise ValueError(
            "rotvec is too long: |rotvec|^2 overflows float64 (an angle beyond 1e154 rad has "
            "no meaningful value)"
        )
    t = np.sqrt(t2)
    small = t < _SMALL_ANGLE
    with np.errstate(invalid="ignore", divide="ignore"):
        k = np.sin(0.5 * t) / t
    ts = np.where(small, t2, 0.0)  # the series only where it is used (no overflow elsewhere)
    k = np.where(small, 0.5 - ts / 48.0 * (1.0 - ts / 80.0), k)
    q = np.empty((*v.shape[:-1], 4))
    q[..., :3] = k[..., None] * v
    q[..., 3] = np.cos(0.5 * t)
    return q


def to_rotvec(q: ArrayLike, *, normalize: bool = False) -> FloatArray:
    """Rotation vector ``theta u``, theta in [0, pi], of a unit quaternion.

    Parameters
    ----------
    q : array_like, shape (..., 4)
        ``[x, y, z, w]``.
    normalize : bool
        Accept a non-unit (non-zero) quaternion and normalise it.

    Returns
    -------
    rotvec : ndarray, shape (..., 3)

    Raises
    ------
    ValueError
        See ``check_quaternion``.
    """
    q = _unit(q, "q", normalize)
    sign = np.where(q[..., 3] < 0.0, -1.0, 1.0)
    v = q[..., :3] * sign[..., None]
    w = q[..., 3] * sign
    n = np.sqrt(np.sum(v * v, axis=-1))
    theta = 2.0 * np.arctan2(n, w)
    # theta / n has no cancellation for n > 0; at n = 0 its limit is 2 / w.
    with np.errstate(invalid="ignore", divide="ignore"):
        k = np.where(n > 0.0, theta / n, 2.0 / w)
    return k[..., None] * v


def _to_matrix_block(
    q: FloatArray, out: FloatArray, b: so3._MatrixRows, transpose: Callable | None
) -> tuple[float, float]:
    """Fill ``out`` (m, 3, 3) with the rotations of ``q`` (m, 4), dividing by |q|^2.

    ``R = I + (2/|q|^2) (w [v]x + v v^T - |v|^2 I)``, the lecture's ``R(q)`` rewritten so that
    it shares ``vnav.so3._fill_rotation_rows`` with Rodrigues' formula. Returns the smallest
    and largest |q|^2 of the block (NaN if any entry is NaN).
    """
    b.load(q)
    w, s, ww = b.v[5], b.A, b.B
    np.add.reduce(b.sq[:3], axis=0, out=s)
    np.add(s, np.multiply(w, w, out=ww), out=s)  # |q|^2 = ((xx + yy) + zz) + ww
    n2_range = (float(s.min()), float(s.max()))
    np.divide(2.0, s, out=s)  # B = 2 / |q|^2
    np.multiply(w, s, out=ww)  # C = 2 w / |q|^2
    so3._fill_rotation_rows(b, s, ww)
    b.store(out, transpose)
    return n2_range


def _to_matrix_reference(q: FloatArray) -> FloatArray:
    """Lecture form of ``to_matrix`` (chapter 6) for unit quaternions (..., 4), q = [q1, q2,
    q3, q4] with scalar q4: ``R11 = q1^2 - q2^2 - q3^2 + q4^2``, ``R12 = 2 (q1 q2 - q3 q4)``,
    ..."""
    q1, q2, q3, q4 = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = [
        [q1 * q1 - q2 * q2 - q3 * q3 + q4 * q4, 2 * (q1 * q2 - q3 * q4), 2 * (q1 * q3 + q2 * q4)],
        [2 * (q1 * q2 + q3 * q4), -q1 * q1 + q2 * q2 - q3 * q3 + q4 * q4, 2 * (q2 * q3 - q1 * q4)],
        [2 * (q1 * q3 - q2 * q4), 2 * (q2 * q3 + q1 * q4), -q1 * q1 - q2 * q2 + q3 * q3 + q4 * q4],
    ]
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def to_matrix(q: ArrayLike, *, normalize: bool = False) -> FloatArray:
    """Rotation matrix of a unit quaternion (lecture chapter 6).

    The lecture's ``R(q)`` with ``q = [q1, q2, q3, q4]``, scalar q4:
    ``R11 = q1^2 - q2^2 - q3^2 + q4^2``, ``R12 = 2 (q1 q2 - q3 q4)``, ...; written here in the
    equivalent form ``R = I + (2/|q|^2) (...)`` (``R11 = 1 - 2 (q2^2 + q3^2)/|q|^2``), which for
    a unit q is the same matrix and for an accepted q within the norm tolerance is still
    exactly orthogonal.

    Parameters
    ----------
    q : array_like, shape (..., 4)
        ``[x, y, z, w]``.
    normalize : bool
        Accept any non-zero quaternion (the formula divides by |q|^2 anyway).

    Returns
    -------
    R : ndarray, shape (..., 3, 3)

    Raises
    ------
    ValueError
        If the shape is not (..., 4), an entry is NaN or inf, ``q`` is zero, or (unless
        ``normalize``) its norm is not 1 within 1e-6 (widened for float32 input as in
        ``check_quaternion``).
    """
    source_dtype = getattr(q, "dtype", None)
    q = _v.vector(q, "q", 4, finite=False)
    flat = q.reshape(-1, 4)
    out = np.empty((flat.shape[0], 3, 3))
    # The norm test runs on the range of |q|^2 that each block reports (written so that a NaN
    # fails it); only on failure is the full check run, to raise with the proper message.
    lo_ok, hi_ok = ((1.0 - _NORM_ATOL) ** 2, (1.0 + _NORM_ATOL) ** 2)
    if normalize:
        lo_ok, hi_ok = np.finfo(np.float64).tiny, np.finfo(np.float64).max
    transpose = so3._cv2_transpose() if flat.shape[0] >= _CHUNK else None
    valid = True
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for start in range(0, flat.shape[0], _CHUNK):
            chunk = flat[start : start + _CHUNK]
            b = so3._scratch(so3._MatrixRows, chunk.shape[0])
            lo, hi = _to_matrix_block(chunk, out[start : start + _CHUNK], b, transpose)
            valid = valid and lo >= lo_ok and hi <= hi_ok
    if not valid:
        _v.check_finite(q, "q")
        if normalize:
            return to_matrix(_normalized(q))  # |q|^2 over- or underflowed in the blocks
        # Raises unless a float32 input is within its widened tolerance (then `out` stands).
        _check_norm(_squared_norm(q), "q", _NORM_ATOL, source_dtype=source_dtype)
    return out.reshape(*q.shape[:-1], 3, 3)


def from_matrix(R: ArrayLike, *, assume_valid: bool = False) -> FloatArray:
    """Unit quaternion ``[x, y, z, w]``, w >= 0, of a rotation matrix.

    Robust for every rotation: of the four expressions ``4w^2 = 1 + tr R``,
    ``4x^2 = 1 + 2 R00 - tr R``, ... the largest is used (Shepperd 1978), in Markley's form
    (Markley 2008, "Unit Quaternion from Rotation Matrix", J. Guid. Control Dyn. 31(2)): the
    corresponding column of the symmetric 4x4 matrix whose dominant eigenvector is q,
    normalised. No division by a small w. Stacks run through a chunked kernel
    (``vnav.so3._quaternion_block``) that also checks R in the same pass over the data;
    ``_from_matrix_reference`` is the lecture's form, kept to test it against.

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
        Rotation matrices (validated with ``vnav.so3.check_rotation``).
    assume_valid : bool
        The caller vouches that ``R`` holds rotations already checked (as SciPy's
        ``Rotation.from_matrix(..., assume_valid=True)``): only its shape is checked. For a
        matrix that is not a rotation the result is meaningless.

    Returns
    -------
    q : ndarray, shape (..., 4)
        ``[x, y, z, w]`` with w >= 0 (at w = 0, a rotation by pi, either sign is valid).

    Raises
    ------
    ValueError
        If ``R`` is not a rotation (see ``vnav.so3.check_rotation``), or with
        ``assume_valid``, if its shape is not (..., 3, 3).
    """
    if (
        so3._clearly_rotation(R, so3._ATOL)
        if not assume_valid
        else type(R) is np.ndarray and R.dtype == np.float64 and R.shape == (3, 3)
    ):  # one float64 rotation: plain floats, the same formulas as the kernel
        q = so3._markley_column_of(R)
        scale = math.copysign(1.0 / math.sqrt(sum(c * c for c in q)), q[3])
        return np.array([c * scale for c in q])
    source_dtype = getattr(R, "dtype", None)
    if assume_valid:
        R = np.asarray(R, dtype=np.float64)
        if R.ndim < 2 or R.shape[-2:] != (3, 3):
            raise ValueError(f"R must have shape (..., 3, 3); got {R.shape}")
        tol = None
    else:
        R = _v.matrix(R, "R", finite=False)
        tol = _v.widened_for(so3._ATOL, source_dtype)
    q, valid = so3._map_rotations(R, so3._quaternion_block, 4, tol)
    if not valid:
        so3._check_rotation(R, "R", so3._ATOL, source_dtype)  # raises, saying what is wrong
        q, _ = so3._map_rotations(R, so3._quaternion_block, 4, None)  # never expected
    return q.reshape(*R.shape[:-2], 4)


def _from_matrix_reference(R: np.ndarray) -> np.ndarray:
    """Lecture form of ``from_matrix`` for one (3, 3) rotation: Shepperd's four branches, the
    dominant component from its square root, the others over it."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    k = int(np.argmax([R[0, 0], R[1, 1], R[2, 2], tr]))
    if k == 3:
        w = 0.5 * math.sqrt(1.0 + tr)
        q = [
            (R[2, 1] - R[1, 2]) / (4 * w),
            (R[0, 2] - R[2, 0]) / (4 * w),
            (R[1, 0] - R[0, 1]) / (4 * w),
            w,
        ]
    else:
        i, j, m = k, (k + 1) % 3, (k + 2) % 3
        v = [0.0, 0.0, 0.0]
        v[i] = 0.5 * math.sqrt(1.0 + R[i, i] - R[j, j] - R[m, m])
        v[j] = (R[i, j] + R[j, i]) / (4 * v[i])
        v[m] = (R[i, m] + R[m, i]) / (4 * v[i])
        q = [*v, (R[m, j] - R[j, m]) / (4 * v[i])]
    out = np.array(q) / math.sqrt(sum(c * c for c in q))
    return -out if out[3] < 0.0 else out


def multiply(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """Hamilton product ``a (x) b``: the rotation b first, then a (lecture chapter 6).

    With ``a = [u; s]``, ``b = [v; t]``: ``a (x) b = [s v + t u + u x v; s t - u . v]``, so
    ``to_matrix(multiply(a, b)) == to_matrix(a) @ to_matrix(b)``. Stacks of more than
    ``_SMALL_STACK`` products run through a chunked kernel that checks both norms in the same
    pass; ``_multiply_reference`` is the lecture's form, with the same operations in the same
    order.

    Parameters
    ----------
    a, b : array_like, shape (..., 4)
        Unit quaternions ``[x, y, z, w]``, broadcast against each other.

    Returns
    -------
    ndarray, shape (..., 4)
        Renormalised to unit length (as SciPy and Sophus do): without it the rounding of
        repeated products grows until the result is no longer a unit quaternion.

    Raises
    ------
    ValueError
        See ``check_quaternion`` (for ``a`` and ``b``); also if their shapes do not broadcast.
    """
    a_in, b_in = a, b
    a = _v.vector(a, "a", 4, finite=False)
    b = _v.vector(b, "b", 4, finite=False)
    try:
        shape = np.broadcast_shapes(a.shape, b.shape)
    except ValueError as exc:
        raise ValueError(
            f"a and b must broadcast against each other; got shapes {a.shape} and {b.shape}"
        ) from exc
    n = math.prod(shape[:-1])
    if n <= _SMALL_STACK:
        return _multiply_reference(check_quaternion(a_in, "a"), check_quaternion(b_in, "b"))
    flat_a = np.broadcast_to(a, shape).reshape(-1, 4)
    flat_b = np.broadcast_to(b, shape).reshape(-1, 4)
    dtypes = [getattr(a_in, "dtype", None), getattr(b_in, "dtype", None)]
    limits = [_norm_limit(_v.widened_for(_NORM_ATOL, dtype)) for dtype in dtypes]
    out = np.empty((n, 4))
    blocks = so3._scratch(_ProductBlocks, _CHUNK)
    valid = True
    with np.errstate(invalid="ignore", over="ignore"):
        for start in range(0, n, _CHUNK):
            stop = start + _CHUNK
            valid = blocks.product(flat_a[start:stop], flat_b[start:stop], out[start:stop], limits)
            if not valid:
                break
    if not valid:  # raises, naming the argument and what is wrong with it
        for q, name, dtype in ((a, "a", dtypes[0]), (b, "b", dtypes[1])):
            _check_norm(
                _squared_norm(_v.check_finite(q, name)), name, _NORM_ATOL, source_dtype=dtype
            )
        return _multiply_reference(a, b)  # never expected: the two checks have one verdict
    return out.reshape(shape)


def _norm_limit(tol: float) -> float:
    """The largest ``| |q|^2 - 1 |`` that ``_check_norm`` accepts at ``tol``: tol (2 + tol)."""
    return tol * (2.0 + tol)


class _ProductBlocks:
    """Scratch rows of ``multiply``'s chunked kernel (one set per thread, ``so3._scratch``).

    Each factor's chunk is copied once, transposed, into (6, M) rows ``[x, y, z, x, y, w]``:
    the cyclic repeat makes ``u x v`` two (3, M) products, ``u[1:4] v[2:5] - u[2:5] v[1:4]``.
    """

    def __init__(self, m: int) -> None:
        self.a = np.empty((6, m))
        self.b = np.empty((6, m))
        self.q = np.empty((4, m))
        self.t = np.empty((4, m))
        self.n2 = np.empty(m)

    def _load(self, rows: FloatArray, q: FloatArray, limit: float) -> bool:
        """Copy ``q`` (M, 4) into ``rows``; whether every ``| |q|^2 - 1 | <= limit``, as
        ``_check_norm`` tests it (its largest value is at the smallest or largest |q|^2)."""
        m = q.shape[0]
        np.copyto(rows[:3, :m], q[:, :3].T)
        np.copyto(rows[5, :m], q[:, 3])
        np.copyto(rows[3:5, :m], rows[:2, :m])
        sq = np.multiply(rows[:3, :m], rows[:3, :m], out=self.t[:3, :m])
        n2 = np.add.reduce(sq, axis=0, out=self.n2[:m])  # ((x x + y y) + z z) + w w
        n2 += np.multiply(rows[5, :m], rows[5, :m], out=self.t[3, :m])
        return bool(max(abs(float(n2.min()) - 1.0), abs(float(n2.max()) - 1.0)) <= limit)

    def product(self, qa: FloatArray, qb: FloatArray, out: FloatArray, limits: list[float]) -> bool:
        """``out`` (M, 4) = qa (x) qb, normalised; False (and ``out`` unfinished) if a factor's
        norm is out of ``limits``."""
        m = qa.shape[0]
        if not (self._load(self.a, qa, limits[0]) and self._load(self.b, qb, limits[1])):
            return False
        a, b, T = self.a[:, :m], self.b[:, :m], self.t[:3, :m]
        v, w = self.q[:3, :m], self.q[3, :m]
        # [s v + t u + u x v; s t - u . v] for a = [u; s], b = [v; t], in the reference's order.
        np.multiply(a[5], b[:3], out=v)
        v += np.multiply(b[5], a[:3], out=T)
        v += np.multiply(a[1:4], b[2:5], out=T)
        v -= np.multiply(a[2:5], b[1:4], out=T)
        np.multiply(a[5], b[5], out=w)
        np.multiply(a[:3], b[:3], out=T)
        for i in range(3):
            w -= T[i]
        q = self.q[:, :m]
        n = np.add.reduce(np.multiply(q, q, out=self.t[:, :m]), axis=0, out=self.n2[:m])
        np.sqrt(n, out=n)
        for j in range(4):
            np.divide(q[j], n, out=out[:, j])
        return True


def _multiply_reference(a: FloatArray, b: FloatArray) -> FloatArray:
    """Lecture form of ``multiply`` for checked unit quaternions (..., 4), broadcast."""
    ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    q = np.stack(
        [
            aw * bx + bw * ax + ay * bz - az * by,
            aw * by + bw * ay + az * bx - ax * bz,
            aw * bz + bw * az + ax * by - ay * bx,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=-1,
    )
    return q / np.sqrt(_squared_norm(q))[..., None]


def conjugate(q: ArrayLike) -> FloatArray:
    """``[-v; s]``, the inverse of a unit quaternion (lecture chapter 6).

    Parameters
    ----------
    q : array_like, shape (..., 4)

    Returns
    -------
    ndarray, shape (..., 4)

    Raises
    ------
    ValueError
        If the shape is not (..., 4) or an entry is NaN or inf.
    """
    q = _v.vector(q, "q", 4)
    out = -q
    out[..., 3] = q[..., 3]
    return out


def slerp(q0: ArrayLike, q1: ArrayLike, t: ArrayLike) -> FloatArray:
    """Spherical linear interpolation along the shorter arc (Shoemake 1985).

    ``q1`` is negated where ``q0 . q1 < 0`` (q and -q are one rotation), so the path turns by
    at most pi. ``slerp(q0, q1, 0) == q0``, ``slerp(q0, q1, 1) == +-q1``. The angle between the
    two 4-vectors is ``2 atan2(|q1 - q0|, |q1 + q0|)``, accurate when they are close (unlike
    ``arccos(q0 . q1)``); below 1e-12 rad the weights are linear.

    Parameters
    ----------
    q0, q1 : array_like, shape (..., 4)
        Unit quaternions ``[x, y, z, w]``.
    t : float or array_like, shape (...)
        Interpolation parameter, usually in [0, 1]; broadcast against the quaternions' leading
        shape (a (T,) array of times with single q0, q1 gives (T, 4)).

    Returns
    -------
    ndarray, shape (..., 4)
        Unit quaternions.

    Raises
    ------
    ValueError
        See ``check_quaternion`` (for ``q0`` and ``q1``); also if ``t`` is NaN or inf.
    """
    q0 = check_quaternion(q0, "q0")
    q1 = check_quaternion(q1, "q1")
    t = _v.scalar_or_array(t, "t")
    dot = np.sum(q0 * q1, axis=-1)
    q1 = np.where((dot < 0.0)[..., None], -q1, q1)
    # Angle between the two unit 4-vectors, accurate for close and for opposite ones.
    d = q1 - q0
    s = q1 + q0
    omega = 2.0 * np.arctan2(np.sqrt(np.sum(d * d, axis=-1)), np.sqrt(np.sum(s * s, axis=-1)))
    t, omega = np.broadcast_arrays(t, omega)
    sin_omega = np.sin(omega)
    tiny = sin_omega < 1e-12
    with np.errstate(invalid="ignore", divide="ignore"):
        w0 = np.where(tiny, 1.0 - t, np.sin((1.0 - t) * omega) / sin_omega)
        w1 = np.where(tiny, t, np.sin(t * omega) / sin_omega)
    q = w0[..., None] * q0 + w1[..., None] * q1
    return q / np.sqrt(np.sum(q * q, axis=-1))[..., None]
