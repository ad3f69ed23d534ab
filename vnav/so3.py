"""Rotation matrices, the group SO(3) (lecture chapters 2-5).

A rotation ``R_a_b`` is a (3, 3) float64 array whose columns are the axes of frame b expressed
in frame a (lecture chapter 2), acting on column vectors: ``p_a = R_a_b @ p_b`` (chapter 3).
Rotations are active and compose by pre-multiplication: ``R_a_c = R_a_b @ R_b_c``.
Every function takes arrays with leading batch axes where that makes sense: a (..., 3, 3)
stack of rotations, a (..., 3) stack of rotation vectors. Conventions: docs/CONVENTIONS.md.

Roll-pitch-yaw follows the lecture (chapter 4): ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``, arrays
of angles ordered ``[roll, pitch, yaw]``.
"""

from __future__ import annotations

import math
import threading
import warnings
from collections.abc import Callable
from typing import TypeVar

import numpy as np
from numpy.typing import ArrayLike

from vnav import _validate as _v
from vnav._validate import FloatArray

__all__ = [
    "GimbalLockWarning",
    "check_rotation",
    "exp",
    "from_rpy",
    "gimbal_locked",
    "is_rotation",
    "log",
    "nearest_rotation",
    "rot_x",
    "rot_y",
    "rot_z",
    "skew",
    "to_rpy",
    "vee",
]

# Below this angle (radians) exp and log use Taylor series of sin(t)/t and t/sin(t).
# The next neglected term is t**6/5040 < 2e-28 here, far below float64 resolution.
_SMALL_ANGLE = 1e-4
# Rows per block in the chunked kernels (`exp`, `log`, the stack check, `quat.from_matrix`):
# the element-wise temporaries of one block stay in cache.
_CHUNK = 8192
# Default tolerance of `check_rotation` on max |R^T R - I|.
_ATOL = 1e-9


class GimbalLockWarning(UserWarning):
    """``to_rpy`` met a rotation with pitch = +-90 deg, where only yaw -+ roll is defined."""


# --------------------------------------------------------------------------------------------
# Elementary rotations (lecture chapter 4)
# --------------------------------------------------------------------------------------------


def _elementary(angle: ArrayLike, i: int, j: int, k: int, name: str) -> FloatArray:
    """Rotation by ``angle`` about axis k, with (i, j) the rotated plane in right-handed order."""
    a = _v.scalar_or_array(angle, name)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros((*a.shape, 3, 3))
    R[..., k, k] = 1.0
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., i, j] = -s
    R[..., j, i] = s
    return R


def rot_x(angle: ArrayLike) -> FloatArray:
    """Right-handed rotation about the x axis (lecture chapter 4, Rx).

    Parameters
    ----------
    angle : float or array_like, shape (...)
        Angle in radians.

    Returns
    -------
    R : ndarray, shape (..., 3, 3)
        ``[[1, 0, 0], [0, c, -s], [0, s, c]]``.

    Raises
    ------
    ValueError
        If ``angle`` is NaN or inf or not numeric.
    """
    return _elementary(angle, 1, 2, 0, "angle")


def rot_y(angle: ArrayLike) -> FloatArray:
    """Right-handed rotation about the y axis (lecture chapter 4, Ry).

    Parameters
    ----------
    angle : float or array_like, shape (...)
        Angle in radians.

    Returns
    -------
    R : ndarray, shape (..., 3, 3)
        ``[[c, 0, s], [0, 1, 0], [-s, 0, c]]``.

    Raises
    ------
    ValueError
        If ``angle`` is NaN or inf or not numeric.
    """
    return _elementary(angle, 2, 0, 1, "angle")


def rot_z(angle: ArrayLike) -> FloatArray:
    """Right-handed rotation about the z axis (lecture chapters 2 and 4, Rz).

    Parameters
    ----------
    angle : float or array_like, shape (...)
        Angle in radians.

    Returns
    -------
    R : ndarray, shape (..., 3, 3)
        ``[[c, -s, 0], [s, c, 0], [0, 0, 1]]``.

    Raises
    ------
    ValueError
        If ``angle`` is NaN or inf or not numeric.
    """
    return _elementary(angle, 0, 1, 2, "angle")


def skew(v: ArrayLike) -> FloatArray:
    """Cross-product matrix ``[v]x`` with ``skew(v) @ u == cross(v, u)`` (lecture chapter 5).

    Parameters
    ----------
    v : array_like, shape (..., 3)

    Returns
    -------
    K : ndarray, shape (..., 3, 3)
        ``[[0, -vz, vy], [vz, 0, -vx], [-vy, vx, 0]]``.

    Raises
    ------
    ValueError
        If ``v`` does not end with a dimension of 3, or holds NaN or inf.
    """
    v = _v.vector(v, "v")
    K = np.zeros((*v.shape, 3))
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    K[..., 0, 1] = -z
    K[..., 0, 2] = y
    K[..., 1, 0] = z
    K[..., 1, 2] = -x
    K[..., 2, 0] = -y
    K[..., 2, 1] = x
    return K


def vee(S: ArrayLike) -> FloatArray:
    """The vector of a skew-symmetric matrix, the inverse of ``skew``: ``vee(skew(v)) == v``.

    Only the entries below the diagonal are read, as in Lee et al. (CDC 2010), whose attitude
    error is ``e_R = vee(R_d^T R - R^T R_d) / 2``.

    Parameters
    ----------
    S : array_like, shape (..., 3, 3)

    Returns
    -------
    v : ndarray, shape (..., 3)
        ``[S[2, 1], S[0, 2], S[1, 0]]``.

    Raises
    ------
    ValueError
        If the shape is not (..., 3, 3) or an entry is NaN or inf.
    """
    S = _v.matrix(S, "S")
    return np.stack([S[..., 2, 1], S[..., 0, 2], S[..., 1, 0]], axis=-1)


# --------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------


def _orthogonality_error(R: FloatArray) -> FloatArray:
    """max |R^T R - I| per matrix, shape (...) (lecture form of ``_rotation_errors``'s first)."""
    E = np.matmul(np.swapaxes(R, -1, -2), R)
    E -= np.eye(3)
    return np.abs(E).max(axis=(-2, -1))


def _rotation_errors(R: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``(max |R^T R - I|, det R)`` per matrix, shapes (...), in one pass over the data.

    The nine entries are copied once into contiguous rows, then the six distinct entries of
    ``R^T R - I`` and the determinant are formed elementwise: a few arithmetic passes over N
    numbers instead of a batched matmul, a (N, 3, 3) temporary and a separate LAPACK
    determinant (about 5x faster for 1e6 matrices; ``benchmarks/geometry.py``). Same figures
    as ``_orthogonality_error`` and ``np.linalg.det`` to rounding (``tests/test_so3.py``)."""
    a, b, c, d, e, f, g, h, i = np.ascontiguousarray(R.reshape(-1, 9).T)
    err = np.abs(a * a + d * d + g * g - 1.0)
    np.maximum(err, np.abs(b * b + e * e + h * h - 1.0), out=err)
    np.maximum(err, np.abs(c * c + f * f + i * i - 1.0), out=err)
    np.maximum(err, np.abs(a * b + d * e + g * h), out=err)
    np.maximum(err, np.abs(a * c + d * f + g * i), out=err)
    np.maximum(err, np.abs(b * c + e * f + h * i), out=err)
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    shape = R.shape[:-2]
    return err.reshape(shape), det.reshape(shape)


def _rotation_error(a, b, c, d, e, f, g, h, i) -> tuple[float, float]:
    """(max |R^T R - I|, det R) of R = [[a, b, c], [d, e, f], [g, h, i]] in plain floats."""
    err = max(
        abs(a * a + d * d + g * g - 1.0),
        abs(b * b + e * e + h * h - 1.0),
        abs(c * c + f * f + i * i - 1.0),
        abs(a * b + d * e + g * h),
        abs(a * c + d * f + g * i),
        abs(b * c + e * f + h * i),
    )
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    return err, det


def _clearly_rotation(R: object, atol: float) -> bool:
    """True when ``R`` is one float64 (3, 3) array that the full check accepts.

    Plain float arithmetic (a few microseconds, where the batched reductions of the full check
    take tens): every pose at every public edge passes through here. Anything else, or any
    doubt (NaN, inf, overflow, out of tolerance), goes to the full check and its messages.
    """
    if type(R) is not np.ndarray or R.dtype != np.float64 or R.shape != (3, 3):
        return False
    values = R.ravel().tolist()
    if not math.isfinite(sum(values)):
        return False
    err, det = _rotation_error(*values)
    return err <= atol and det > 0.0


def check_rotation(R: ArrayLike, name: str = "R", atol: float = 1e-9) -> FloatArray:
    """Validate a rotation matrix (or a stack of them) and return it as float64.

    A rotation satisfies ``R^T R = I`` and ``det R = +1`` (lecture chapter 2).

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
    name : str
        The argument's name, used in error messages.
    atol : float
        Largest accepted entry of ``|R^T R - I|`` (finite, >= 0). A float32 (or float16)
        input is allowed 16 of its machine epsilons at least (1.9e-6 for float32), as its
        own rounding exceeds the float64 default.

    Returns
    -------
    R : ndarray, shape (..., 3, 3), float64
        The input (a view when it already was float64).

    Raises
    ------
    ValueError
        If the shape is not (..., 3, 3) (the message gives the shape received), if an entry is
        NaN or inf, if ``det R < 0`` (a reflection, not a rotation), or if ``R^T R`` differs
        from I by more than ``atol`` (the message gives max |R^T R - I|, det R and, for a
        float32 input, the widened tolerance and its dtype); or if ``atol`` is not a finite
        number >= 0.
    """
    if type(atol) is not float or not 0.0 <= atol < math.inf:  # inline: the fast path's cost
        atol = _v.tolerance(atol)
    if _clearly_rotation(R, atol):
        return R
    return _check_rotation(R, name, atol, getattr(R, "dtype", None))


def _check_rotation(R: ArrayLike, name: str, atol: float, source_dtype: object) -> FloatArray:
    """The full check of ``check_rotation``; ``atol`` widened for a float32 source.

    The verdict comes from one chunked pass (``_stack_valid``); only a stack that fails it is
    examined again, matrix by matrix, to say what is wrong with it.
    """
    tol = _v.widened_for(atol, source_dtype)
    R = _v.matrix(R, name, finite=False)
    if R.size == 0 or _stack_valid(R, tol):
        return R
    _v.check_finite(R, name)
    err, det = _rotation_errors(R)
    where = "" if R.ndim == 2 else " (worst matrix of the stack)"
    if np.any(det < 0):
        i = np.unravel_index(np.argmin(det), det.shape) if det.ndim else ()
        raise ValueError(
            f"{name} is a reflection, not a rotation: det = {float(det[i]):.6g} < 0{where}; "
            "a rotation has det = +1 (right-handed axes)"
        )
    if np.any(err > tol):
        i = np.unravel_index(np.argmax(err), err.shape) if err.ndim else ()
        source = f" for {np.dtype(source_dtype)} input" if tol != atol else ""
        raise ValueError(
            f"{name} is not a rotation matrix: max |R^T R - I| = {float(err[i]):.3g} "
            f"(tolerance {tol:g}{source}), det = {float(det[i]):.9g}{where}; "
            "so3.nearest_rotation projects a nearly orthogonal matrix onto SO(3)"
        )
    return R


def is_rotation(R: ArrayLike, atol: float = 1e-9) -> bool:
    """Whether ``R`` (or every matrix of a stack) is a rotation within ``atol``.

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
    atol : float
        Largest accepted entry of ``|R^T R - I|`` (finite, >= 0; widened for float32 input as
        in ``check_rotation``).

    Returns
    -------
    bool
        False for a wrong shape, NaN or inf, a reflection or a non-orthogonal matrix.

    Raises
    ------
    ValueError
        If ``atol`` is not a finite number >= 0 (a bad tolerance is the caller's error, not an
        answer about ``R``).
    """
    atol = _v.tolerance(atol)
    try:
        check_rotation(R, atol=atol)
    except ValueError:
        return False
    return True


def nearest_rotation(M: ArrayLike) -> FloatArray:
    """Project a matrix onto SO(3): the rotation closest to ``M`` in the Frobenius norm.

    With the SVD ``M = U S V^T``, the answer is ``U diag(1, 1, det(U V^T)) V^T`` (the
    orthogonal Procrustes solution with the determinant fixed to +1; Umeyama 1991, eq. 39-40).

    Parameters
    ----------
    M : array_like, shape (..., 3, 3)

    Returns
    -------
    R : ndarray, shape (..., 3, 3)

    Raises
    ------
    ValueError
        If ``M`` is not (..., 3, 3) or holds NaN or inf.
    """
    M = _v.matrix(M, "M")
    U, _, Vt = np.linalg.svd(M)
    d = np.sign(np.linalg.det(np.matmul(U, Vt)))
    d = np.where(d == 0, 1.0, d)
    U = U.copy()
    U[..., :, 2] *= d[..., None]
    return np.matmul(U, Vt)


# --------------------------------------------------------------------------------------------
# Chunked kernels over stacks of rotation matrices
# --------------------------------------------------------------------------------------------


_Scratch = TypeVar("_Scratch")
_THREAD_SCRATCH = threading.local()
_SCRATCH_SIZES = 3  # scratch sets kept per kind and thread: the full chunk, two tail lengths


def _scratch(factory: Callable[[int], _Scratch], m: int) -> _Scratch:
    """This thread's ``factory(m)``: made on its first use, then reused by later calls.

    The chunked kernels' scratch arrays (a few MB) are mapped and faulted in once, not on every
    call (that cost ~2 ms per call on 1e6 rotations). One set per thread: numpy releases the
    GIL inside its loops, so two threads must never share them.
    """
    kept = _THREAD_SCRATCH.__dict__.setdefault(factory, {})
    found = kept.get(m)
    if found is None:
        if len(kept) >= _SCRATCH_SIZES:
            kept.clear()
        found = kept[m] = factory(m)
    return found


class _Entries:
    """The nine entries of a chunk of M matrices, stored as rows ``flat[S i + j] = R_ij``
    (S >= 3 rows per matrix row), as the (strided) groups Markley's matrix is built from."""

    def __init__(self, flat: FloatArray, S: int) -> None:
        self.diag = flat[0 : 2 * S + 3 : S + 1]  # R00 R11 R22
        self.upper = flat[1 : S + 3 : S + 1]  # R01 R12
        self.lower = flat[S : 2 * S + 2 : S + 1]  # R10 R21
        self.R02, self.R20 = flat[2], flat[2 * S]


class _Blocks:
    """Scratch arrays, and their views, of the chunked kernels over exactly m rotations.

    A chunk is copied once, transposed, into rows of m numbers: ``entries`` (9, m), or, where
    it is checked, ``rows`` (3, 5, m), row i of every matrix as ``[R_i0, R_i1, R_i2, R_i0,
    R_i1]``, whose cyclic repeat makes the products of neighbouring columns (in ``R^T R`` and
    ``det R``) one call over a (3, m) block. Every later step is a ufunc over contiguous rows
    that stay in cache, writing into these arrays: nothing is allocated per chunk.
    """

    def __init__(self, m: int) -> None:
        self.m = m
        self.entries = np.empty((9, m))
        self.rows = np.empty((3, 5, m))
        self.of_entries = _Entries(self.entries, 3)
        self.of_rows = _Entries(self.rows.reshape(15, m), 5)
        self._validation_views(m)
        self._markley_views(m)

    def _validation_views(self, m: int) -> None:
        P = self.rows
        self.rows_head, self.rows_tail, self.rows_wrap = P[:, :3], P[:, 3:], P[:, :2]
        self.row = [P[i, :3] for i in range(3)]  # (R_i0, R_i1, R_i2)
        self.row_1 = [P[i, 1:4] for i in range(3)]  # (R_i1, R_i2, R_i0)
        self.row_2 = [P[i, 2:5] for i in range(3)]  # (R_i2, R_i0, R_i1)
        self.gram = np.empty((6, m))  # R^T R - I: diagonal 00 11 22, then 01 12 20
        self.gram_diag, self.gram_off = self.gram[:3], self.gram[3:]
        self.t3 = np.empty((2, 3, m))
        self.det = np.empty(m)

    def _markley_views(self, m: int) -> None:
        # Markley's symmetric K: entry (j, k) in row c_j + c_k, c = (0, 1, 3, 7) for x y z w.
        # Those ten sums differ, so each entry is stored once, and column k of every matrix is
        # gathered at rows c_j + c_k: offset c_k m = (2^k - 1) m from `base`.
        K = self.K = np.empty((15, m))
        self.K_flat = K.reshape(-1)
        self.K_xx, self.K_yy, self.K_zz, self.K_ww = K[0], K[2], K[6], K[14]
        self.K_diag_1_3, self.K_diag_0_2 = K[2:15:12], K[0:7:6]  # (yy, ww), (xx, zz)
        self.K_sums = K[1:5:3]  # xy = R01 + R10, yz = R12 + R21
        self.K_diffs = K[10:6:-3]  # zw = R10 - R01, xw = R21 - R12
        self.K_xz, self.K_yw = K[3], K[8]  # R02 + R20, R02 - R20
        self.s, self.d = np.empty(m), np.empty(m)
        self.f = np.empty((2, m))
        self.flags = np.empty((4, m), dtype=bool)
        self.k = np.empty(m, dtype=np.uint8)
        self.offset = np.empty(m, dtype=np.intp)
        self.idx = np.empty((4, m), dtype=np.intp)
        # (c_j - 1) m + i: with (2^k) m added, the flat index of K[j, k] for matrix i.
        self.base = (np.array([0, 1, 3, 7]) - 1)[:, None] * m + np.arange(m)
        self.m_intp = np.intp(m)
        self.q = np.empty((4, m))

    def load(self, R3: FloatArray) -> None:
        """Copy ``R3`` (m, 3, 3), any strides, into ``rows``."""
        np.copyto(self.rows_head, R3.transpose(1, 2, 0))
        np.copyto(self.rows_tail, self.rows_wrap)

    def load_entries(self, R3: FloatArray, transpose: Callable | None) -> None:
        """Copy ``R3`` (m, 3, 3) into ``entries``; a C-contiguous chunk through ``transpose``
        (cv2.transpose, a blocked transposition ~1.6x faster than numpy's strided copy)."""
        if transpose is not None and R3.flags.c_contiguous:
            if transpose(R3.reshape(self.m, 9), dst=self.entries) is self.entries:
                return
        np.copyto(self.entries.reshape(3, 3, self.m), R3.transpose(1, 2, 0))


class _MatrixRows:
    """Scratch rows of the kernels that build rotation matrices (``exp``,
    ``vnav.quat.to_matrix``) for exactly m of them, one set per thread (``_scratch``).

    The vectors (or quaternions) are copied once, transposed, into ``v`` = [x, y, z, x, y, w]
    and their squares into ``sq`` = [xx, yy, zz, xx, yy]: the cyclic repeats make each group of
    three entries of R one call over a (3, m) block. The nine rows of R are built in ``res``,
    then written out with one transposing copy.
    """

    def __init__(self, m: int) -> None:
        self.m = m
        self.v = np.empty((6, m))
        self.sq = np.empty((5, m))
        self.s = np.empty((4, m))
        self.A, self.B = np.empty(m), np.empty(m)
        self.small = np.empty(m, dtype=bool)
        self.P, self.W = np.empty((3, m)), np.empty((3, m))
        self.res = np.empty((9, m))  # R00 R01 R02 R10 ... R22, one row each
        self.res_diag = self.res[0::4]
        self.res_01_12, self.res_10_21 = self.res[1:6:4], self.res[3:8:4]
        self.res_20, self.res_02 = self.res[6], self.res[2]

    def load(self, v: FloatArray) -> None:
        """Copy ``v`` (m, 3), or quaternions (m, 4) [x, y, z, w], into ``v``; their squares
        into ``sq``."""
        np.copyto(self.v[:3], v[:, :3].T)
        np.copyto(self.v[3:5], self.v[:2])
        if v.shape[1] == 4:
            np.copyto(self.v[5], v[:, 3])
        np.multiply(self.v[:3], self.v[:3], out=self.sq[:3])
        np.copyto(self.sq[3:], self.sq[:2])

    def store(self, R: FloatArray, transpose: Callable | None) -> None:
        """Write ``res`` into ``R`` (m, 3, 3); a C-contiguous chunk through ``transpose``
        (cv2.transpose, ~1.6x faster than numpy's strided copy) when one is given."""
        rows = R.reshape(self.m, 9)
        if transpose is not None and R.flags.c_contiguous:
            if transpose(self.res, dst=rows) is rows:
                return
        np.copyto(rows, self.res.T)


def _fill_rotation_rows(b: _MatrixRows, B: FloatArray, C: FloatArray) -> None:
    """``b.res`` = the rows of ``R = I + C [v]x + B (v v^T - |v|^2 I)`` for v in ``b.v``.

    Rodrigues' formula with C = sin(t)/t, B = (1 - cos(t))/t^2 (``exp``), or the quaternion's
    matrix with B = 2/|q|^2, C = 2 w/|q|^2 (``quat.to_matrix``): diagonal
    ``1 - B (v_j^2 + v_k^2)``, and ``R_ij = B v_i v_j - C v_k``, ``R_ji = B v_i v_j + C v_k``
    for (i, j, k) cyclic.
    """
    v, sq, P, W = b.v, b.sq, b.P, b.W
    np.add(sq[1:4], sq[2:5], out=W)  # yy + zz, zz + xx, xx + yy
    np.multiply(W, B, out=W)
    np.subtract(1.0, W, out=b.res_diag)
    np.multiply(v[0:3], v[1:4], out=P)  # xy, yz, zx
    np.multiply(P, B, out=P)
    np.multiply(v[2:5], C, out=W)  # C z, C x, C y
    np.subtract(P[:2], W[:2], out=b.res_01_12)
    np.subtract(P[2], W[2], out=b.res_20)
    np.add(P[:2], W[:2], out=b.res_10_21)
    np.add(P[2], W[2], out=b.res_02)


def _rows_valid(b: _Blocks, tol: float) -> bool:
    """Whether every matrix loaded in ``b.rows`` passes ``check_rotation``'s test.

    ``max |R^T R - I| <= tol`` and ``det R > 0``, with the products and sums of
    ``_rotation_errors`` in the same order (so the same verdict), on (3, m) blocks. A NaN or an
    inf fails.
    """
    row, row_1, row_2 = b.row, b.row_1, b.row_2
    T, X = b.t3
    # (R^T R)_jk = sum_i R_ij R_ik: the diagonal from squares, 01 12 20 from neighbours.
    np.multiply(row[0], row[0], out=b.gram_diag)
    np.multiply(row[0], row_1[0], out=b.gram_off)
    for i in (1, 2):
        np.add(b.gram_diag, np.multiply(row[i], row[i], out=T), out=b.gram_diag)
        np.add(b.gram_off, np.multiply(row[i], row_1[i], out=T), out=b.gram_off)
    np.subtract(b.gram_diag, 1.0, out=b.gram_diag)
    # det R = sum_j R_0j (R_1,j+1 R_2,j+2 - R_1,j+2 R_2,j+1), indices mod 3 (triple product).
    np.multiply(row_1[1], row_2[2], out=T)
    np.subtract(T, np.multiply(row_2[1], row_1[2], out=X), out=T)
    np.multiply(T, row[0], out=T)
    det = np.add.reduce(T, axis=0, out=b.det)
    return bool(b.gram.max() <= tol and -tol <= b.gram.min() and det.min() > 0.0)


def _stack_valid(R: FloatArray, tol: float) -> bool:
    """``_rows_valid`` over a whole stack (..., 3, 3), chunk by chunk; False at the first
    failing chunk."""
    R3 = R.reshape(-1, 3, 3)
    with np.errstate(invalid="ignore", over="ignore"):
        for start in range(0, R3.shape[0], _CHUNK):
            chunk = R3[start : start + _CHUNK]
            b = _scratch(_Blocks, chunk.shape[0])
            b.load(chunk)
            if not _rows_valid(b, tol):
                return False
    return True


def _map_rotations(
    R: FloatArray,
    kernel: Callable[[_Entries, FloatArray, _Blocks], None],
    width: int,
    tol: float | None,
) -> tuple[FloatArray, bool]:
    """Run ``kernel(E, out_chunk, blocks)`` over the stack ``R`` (..., 3, 3), chunk by chunk;
    ``E`` (``_Entries``) points at the chunk's entries in ``blocks``.

    Returns the (N, width) result and whether every matrix passed ``_rows_valid`` at ``tol``
    (the check fused into the same pass over the data; skipped when ``tol`` is None). Stops at
    the first failing chunk: the caller then raises with ``_check_rotation``'s message.
    """
    R3 = R.reshape(-1, 3, 3)
    out = np.empty((R3.shape[0], width))
    transpose = _cv2_transpose() if tol is None and R3.shape[0] >= _CHUNK else None
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        for start in range(0, R3.shape[0], _CHUNK):
            chunk = R3[start : start + _CHUNK]
            b = _scratch(_Blocks, chunk.shape[0])
            if tol is None:
                b.load_entries(chunk, transpose)
            else:
                b.load(chunk)
                if not _rows_valid(b, tol):
                    return out, False
            kernel(b.of_entries if tol is None else b.of_rows, out[start : start + _CHUNK], b)
    return out, True


def _cv2_transpose() -> Callable:
    """``cv2.transpose``, imported only by the kernels that use it on long stacks (so that the
    geometry core loads OpenCV only where it pays)."""
    import cv2

    return cv2.transpose


def _markley_columns(E: _Entries, b: _Blocks) -> FloatArray:
    """Per matrix, the column of Markley's ``K = 4 q q^T`` with the largest diagonal entry.

    Markley 2008 ("Unit Quaternion from Rotation Matrix", J. Guid. Control Dyn. 31(2)), with
    q = [x, y, z, w]: diagonal ``1 + 2 R_kk - tr R`` (= 4 q_k^2) for x, y, z and ``1 + tr R``
    (= 4 w^2); off the diagonal ``R_ij + R_ji`` (= 4 q_i q_j) and ``R_kj - R_jk`` (= 4 w q_i,
    (i, j, k) cyclic). Column k is ``4 q_k q``: the one with the largest q_k^2 >= 1/4 gives q
    to rounding (Shepperd's choice), with no square root and no division.

    Returns
    -------
    ndarray, shape (4, m)
        Rows x, y, z, w of the chosen column, proportional to q (``b.q``).
    """
    R00, R11, R22 = E.diag
    s, d = b.s, b.d
    # The diagonal from two sums and two differences: (1 + R00) -+ (R11 + R22), ...
    np.add(R11, R22, out=s)
    np.add(R00, 1.0, out=d)
    np.subtract(d, s, out=b.K_xx)
    np.add(d, s, out=b.K_ww)
    np.subtract(R11, R22, out=s)
    np.subtract(1.0, R00, out=d)
    np.add(d, s, out=b.K_yy)
    np.subtract(d, s, out=b.K_zz)
    np.add(E.upper, E.lower, out=b.K_sums)
    np.subtract(E.lower, E.upper, out=b.K_diffs)
    np.add(E.R02, E.R20, out=b.K_xz)
    np.subtract(E.R02, E.R20, out=b.K_yw)
    return _dominant_column(b)


def _dominant_column(b: _Blocks) -> FloatArray:
    """Column ``argmax(diag K)`` of every (4, 4) ``K`` stored in ``b.K``: (4, m).

    The argmax is a tournament (x against y and z against w in one call, then the winners);
    the column is gathered with one flat ``take`` instead of a branch per matrix.
    """
    y_or_w, zw_wins, h = b.flags[:2], b.flags[2], b.flags[3]
    np.greater(b.K_diag_1_3, b.K_diag_0_2, out=y_or_w)  # y beats x, w beats z
    np.maximum(b.K_diag_0_2, b.K_diag_1_3, out=b.f)  # best of x y, best of z w
    np.greater(b.f[1], b.f[0], out=zw_wins)
    # k = 2 + w_wins where zw_wins, else y_wins: 2 zw_wins + (y ^ (zw & (w ^ y))).
    y_wins, w_wins = y_or_w
    np.bitwise_xor(w_wins, y_wins, out=h)
    np.bitwise_and(h, zw_wins, out=h)
    np.bitwise_xor(h, y_wins, out=h)
    np.left_shift(zw_wins.view(np.uint8), 1, out=b.k)
    np.bitwise_or(b.k, h.view(np.uint8), out=b.k)
    np.left_shift(b.m_intp, b.k, out=b.offset)  # 2^k m
    np.add(b.base, b.offset, out=b.idx)
    return np.take(b.K_flat, b.idx, out=b.q, mode="wrap")  # every index is in range


def _markley_column_of(R: FloatArray) -> tuple[float, float, float, float]:
    """``_markley_columns`` of one (3, 3) matrix in plain floats: the same sums, the same
    choice (a few microseconds, where the chunked kernel's fixed cost is tens)."""
    (R00, R01, R02), (R10, R11, R12), (R20, R21, R22) = R.tolist()
    s, d = R11 + R22, R00 + 1.0
    Kxx, Kww = d - s, d + s
    s, d = R11 - R22, 1.0 - R00
    Kyy, Kzz = d + s, d - s
    sxy, sxz, syz = R01 + R10, R02 + R20, R12 + R21
    dx, dy, dz = R21 - R12, R02 - R20, R10 - R01
    if max(Kzz, Kww) > max(Kxx, Kyy):
        return (dx, dy, dz, Kww) if Kww > Kzz else (sxz, syz, Kzz, dz)
    return (sxy, Kyy, syz, dy) if Kyy > Kxx else (Kxx, sxy, sxz, dx)


def _quaternion_block(E: _Entries, out: FloatArray, b: _Blocks) -> None:
    """``out`` (m, 4): the unit quaternions [x, y, z, w], w >= 0, of the chunk ``E``."""
    q = _markley_columns(E, b)
    n = np.einsum("ji,ji->i", q, q, out=b.f[0])
    np.sqrt(n, out=n)
    np.divide(1.0, n, out=n)
    np.copysign(n, q[3], out=n)  # the sign that makes w >= 0
    for j in range(4):
        np.multiply(q[j], n, out=out[:, j])


def _log_block(E: _Entries, out: FloatArray, b: _Blocks) -> None:
    """``out`` (m, 3): the rotation vectors, angle in [0, pi], of the chunk ``E``.

    From Markley's column u (proportional to q, any positive or negative factor): the angle is
    ``2 atan2(|u_v|, |u_w|)`` (scale-free, accurate at every angle) and the vector
    ``sign(u_w) angle u_v / |u_v|``. Below |u_v| = 1e-150 (an angle under ~1e-150 rad, where
    |u_v|^2 would underflow) ``angle / |u_v|`` is taken at 1e-150: its limit ``2 / |u_w|``.
    """
    q = _markley_columns(E, b)
    nv, k = b.f
    np.einsum("ji,ji->i", q[:3], q[:3], out=nv)
    np.sqrt(nv, out=nv)
    np.maximum(nv, 1e-150, out=nv)
    np.abs(q[3], out=k)
    np.arctan2(nv, k, out=k)
    np.multiply(k, 2.0, out=k)  # the angle
    np.divide(k, nv, out=k)
    np.copysign(k, q[3], out=k)
    for j in range(3):
        np.multiply(q[j], k, out=out[:, j])


# --------------------------------------------------------------------------------------------
# Axis-angle: exp and log (lecture chapter 5)
# --------------------------------------------------------------------------------------------


def exp(rotvec: ArrayLike) -> FloatArray:
    """Rotation matrix of a rotation vector ``theta * u`` (Rodrigues' formula, lecture ch. 5).

    ``R = I + A [v]x + B [v]x^2`` with ``v = theta u``, ``A = sin(theta)/theta`` and
    ``B = (1 - cos(theta))/theta^2 = 2 sin^2(theta/2)/theta^2`` (the half-angle form avoids the
    cancellation of 1 - cos). This equals the lecture's ``cos(t) I + sin(t) [u]x +
    (1 - cos(t)) u u^T`` because ``[u]x^2 = u u^T - I``. Below 1e-4 rad, A and B come from
    their Taylor series, so ``exp`` is exact to rounding near the identity. Stacks run through a
    chunked kernel; ``_exp_reference`` is the lecture's form, kept to test it against.

    Parameters
    ----------
    rotvec : array_like, shape (..., 3)
        Axis times angle, radians. Any length: angles beyond pi wrap around.

    Returns
    -------
    R : ndarray, shape (..., 3, 3)

    Raises
    ------
    ValueError
        If ``rotvec`` does not end with a dimension of 3, holds NaN or inf, or is so long that
        its squared length overflows.
    """
    rotvec = _v.vector(rotvec, "rotvec", finite=False)
    v = rotvec.reshape(-1, 3)
    R = np.empty((v.shape[0], 3, 3))
    transpose = _cv2_transpose() if v.shape[0] >= _CHUNK else None
    finite = True
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        for start in range(0, v.shape[0], _CHUNK):
            chunk = v[start : start + _CHUNK]
            b = _scratch(_MatrixRows, chunk.shape[0])
            finite &= _exp_block(chunk, R[start : start + _CHUNK], b, transpose)
    if not finite:
        _v.check_finite(rotvec, "rotvec")  # raises for NaN or inf
        raise ValueError(
            "rotvec is too long: |rotvec|^2 overflows float64 (an angle beyond 1e154 rad has "
            "no meaningful value)"
        )
    return R.reshape(*rotvec.shape, 3)


def _exp_block(v: FloatArray, R: FloatArray, b: _MatrixRows, transpose: Callable | None) -> bool:
    """Fill ``R`` (m, 3, 3) with ``exp`` of ``v`` (m, 3); False if theta^2 is not finite."""
    b.load(v)
    t2, t, tau, tau2 = b.s
    A, B = b.A, b.B
    np.add.reduce(b.sq[:3], axis=0, out=t2)  # theta^2 = (xx + yy) + zz
    finite = bool(np.isfinite(t2.sum()))
    np.sqrt(t2, out=t)
    # One transcendental call: with tau = tan(theta/4), sin(theta/2) = 2 tau / (1 + tau^2) and
    # cos(theta/2) = (1 - tau^2) / (1 + tau^2) (half-angle identities, valid at any angle and
    # without cancellation that matters: the absolute error of each stays ~1 ulp).
    np.multiply(t, 0.25, out=tau)
    np.tan(tau, out=tau)
    np.multiply(tau, tau, out=tau2)
    np.add(tau2, 1.0, out=B)
    np.divide(1.0, B, out=B)
    np.subtract(1.0, tau2, out=A)
    np.multiply(A, B, out=A)  # cos(theta/2)
    np.multiply(tau, B, out=tau)
    np.multiply(tau, 2.0, out=tau)  # sin(theta/2)
    np.divide(tau, t, out=tau)  # sin(theta/2) / theta
    np.multiply(A, tau, out=A)
    np.multiply(A, 2.0, out=A)  # sin(theta) / theta = 2 sin(theta/2) cos(theta/2) / theta
    np.multiply(tau, tau, out=B)
    np.multiply(B, 2.0, out=B)  # (1 - cos(theta)) / theta^2 = 2 sin^2(theta/2) / theta^2
    small = np.less(t, _SMALL_ANGLE, out=b.small)
    if small.any():
        ts = t2[small]
        A[small] = 1.0 - ts / 6.0 * (1.0 - ts / 20.0)
        B[small] = 0.5 - ts / 24.0 * (1.0 - ts / 30.0)
    _fill_rotation_rows(b, B, A)
    b.store(R, transpose)
    return finite


def _exp_reference(rotvec: FloatArray) -> FloatArray:
    """Lecture form of ``exp`` (chapter 5) for (..., 3) rotation vectors:
    ``R = cos(t) I + sin(t) [u]x + (1 - cos(t)) u u^T``, t = |v|, u = v / t (I at t = 0)."""
    t = np.linalg.norm(rotvec, axis=-1)[..., None, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(t[..., 0] > 0.0, rotvec / t[..., 0], 0.0)
    uuT = u[..., :, None] * u[..., None, :]
    return np.cos(t) * np.eye(3) + np.sin(t) * skew(u) + (1.0 - np.cos(t)) * uuT


def log(R: ArrayLike) -> FloatArray:
    """Rotation vector ``theta * u`` of a rotation matrix, ``theta`` in [0, pi].

    Accurate to rounding for every rotation, unlike ``arccos((tr R - 1)/2)``, which loses half
    the digits near 0 and near pi. Computed through the quaternion ``q = [sin(theta/2) u;
    cos(theta/2)]`` (lecture chapter 6): Markley's column of ``4 q q^T`` read off R (as in
    ``vnav.quat.from_matrix``), then ``theta = 2 atan2(|v|, |w|)`` and the axis ``sign(w) v /
    |v|``. Both hold for an unnormalised column, and neither divides by a small number: near 0
    ``theta / |v|`` tends to ``2 / |w|``, near pi the column of the largest of x, y, z is used.
    At exactly pi both signs give the same rotation. The chunked kernel checks R (as
    ``check_rotation``) in the same pass over the data; ``_log_reference`` is the lecture's
    two-branch form, kept to test it against.

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
        Rotation matrices (validated with ``check_rotation``).

    Returns
    -------
    rotvec : ndarray, shape (..., 3)
        Axis times angle, with the angle in [0, pi].

    Raises
    ------
    ValueError
        If ``R`` is not a rotation (see ``check_rotation``).
    """
    if _clearly_rotation(R, _ATOL):  # one float64 rotation: plain floats, same formulas
        x, y, z, w = _markley_column_of(R)
        nv = max(math.sqrt(x * x + y * y + z * z), 1e-150)
        k = math.copysign(2.0 * math.atan2(nv, abs(w)) / nv, w)
        return np.array([x * k, y * k, z * k])
    source_dtype = getattr(R, "dtype", None)
    R = _v.matrix(R, "R", finite=False)
    rotvec, valid = _map_rotations(R, _log_block, 3, _v.widened_for(_ATOL, source_dtype))
    if not valid:
        _check_rotation(R, "R", _ATOL, source_dtype)  # raises, saying what is wrong
        rotvec, _ = _map_rotations(R, _log_block, 3, None)  # never expected: one verdict
    return rotvec.reshape(R.shape[:-1])


def _log_reference(R: FloatArray) -> FloatArray:
    """Lecture form of ``log`` for a validated stack (..., 3, 3), in two branches.

    - the angle is ``atan2(|w|/2, (tr R - 1)/2)`` with ``w = vee(R - R^T) = 2 sin(theta) u``
      (lecture chapter 5: tr R = 1 + 2 cos(theta), and the antisymmetric part of R is
      sin(theta) [u]x);
    - for theta <= pi/2 the axis is ``w / |w|``, so the vector is ``w theta / (2 sin theta)``,
      with a Taylor series of theta / sin(theta) below 1e-4 rad;
    - for theta > pi/2, where |w| vanishes, the axis comes from the symmetric part
      ``(R + R^T)/2 - cos(theta) I = (1 - cos(theta)) u u^T``: its column with the largest
      diagonal entry, normalised, with the sign that makes it point along w.
    """
    R_in = R
    R = R_in.reshape(-1, 3, 3)
    w = np.stack(
        [R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]],
        axis=-1,
    )
    s = 0.5 * np.sqrt(np.sum(w * w, axis=-1))  # sin(theta) >= 0
    c = 0.5 * (R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2] - 1.0)  # cos(theta)
    theta = np.arctan2(s, c)

    out = np.empty(w.shape)
    # theta <= pi/2: rotvec = w * theta / (2 sin theta).
    near = c >= 0.0
    if np.any(near):
        tn, sn = theta[near], s[near]
        small = tn < _SMALL_ANGLE
        factor = np.empty_like(tn)
        factor[~small] = tn[~small] / sn[~small]
        t2 = tn[small] ** 2
        factor[small] = 1.0 + t2 / 6.0 * (1.0 + 7.0 * t2 / 60.0)  # theta/sin(theta), Taylor
        out[near] = 0.5 * factor[..., None] * w[near]
    far = ~near
    if np.any(far):
        Rf, cf, wf = R[far], c[far], w[far]
        S = 0.5 * (Rf + np.swapaxes(Rf, -1, -2))
        S -= cf[:, None, None] * np.eye(3)  # (1 - cos theta) u u^T
        i = np.argmax(np.diagonal(S, axis1=-2, axis2=-1), axis=-1)
        u = np.take_along_axis(S, i[:, None, None], axis=-1)[..., 0]  # column i = k u_i u
        u /= np.linalg.norm(u, axis=-1, keepdims=True)
        sign = np.where(np.sum(u * wf, axis=-1) < 0.0, -1.0, 1.0)
        out[far] = (sign * theta[far])[:, None] * u
    return out.reshape(R_in.shape[:-1])


# --------------------------------------------------------------------------------------------
# Roll, pitch, yaw (lecture chapter 4)
# --------------------------------------------------------------------------------------------


def from_rpy(roll: ArrayLike, pitch: ArrayLike, yaw: ArrayLike) -> FloatArray:
    """Rotation from roll, pitch, yaw: ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (lecture ch. 4).

    Applied right to left: roll about x first, then pitch about y, then yaw about z (fixed
    axes); SciPy's ``from_euler("ZYX", [yaw, pitch, roll])``.

    Parameters
    ----------
    roll, pitch, yaw : float or array_like, broadcastable to a common shape (...)
        Radians.

    Returns
    -------
    R : ndarray, shape (..., 3, 3)

    Raises
    ------
    ValueError
        If an angle is NaN or inf, or the three do not broadcast together.
    """
    r = _v.scalar_or_array(roll, "roll")
    p = _v.scalar_or_array(pitch, "pitch")
    y = _v.scalar_or_array(yaw, "yaw")
    try:
        r, p, y = np.broadcast_arrays(r, p, y)
    except ValueError as exc:
        raise ValueError(
            f"roll, pitch, yaw must broadcast together; got shapes {r.shape}, {p.shape}, {y.shape}"
        ) from exc
    cr, sr = np.cos(r), np.sin(r)
    cp, sp = np.cos(p), np.sin(p)
    cy, sy = np.cos(y), np.sin(y)
    R = np.empty((*r.shape, 3, 3))
    R[..., 0, 0] = cy * cp
    R[..., 0, 1] = cy * sp * sr - sy * cr
    R[..., 0, 2] = cy * sp * cr + sy * sr
    R[..., 1, 0] = sy * cp
    R[..., 1, 1] = sy * sp * sr + cy * cr
    R[..., 1, 2] = sy * sp * cr - cy * sr
    R[..., 2, 0] = -sp
    R[..., 2, 1] = cp * sr
    R[..., 2, 2] = cp * cr
    return R


def gimbal_locked(R: ArrayLike, atol: float = 1e-9) -> bool | np.ndarray:
    """Whether the pitch of ``R`` is +-90 deg within ``atol`` (lecture chapter 4, gimbal lock).

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
        Rotation matrices (validated with ``check_rotation``).
    atol : float
        Largest ``cos(pitch) = hypot(R[0, 0], R[1, 0])`` counted as locked (about the distance
        of the pitch from +-90 deg, radians); finite, >= 0.

    Returns
    -------
    bool or ndarray of bool, shape (...)

    Raises
    ------
    ValueError
        If ``R`` is not a rotation (see ``check_rotation``), or ``atol`` is not a finite
        number >= 0.
    """
    atol = _v.tolerance(atol)
    R = check_rotation(R)
    locked = np.hypot(R[..., 0, 0], R[..., 1, 0]) <= atol
    return bool(locked) if locked.ndim == 0 else locked


def to_rpy(R: ArrayLike, *, warn: bool = True, atol: float = 1e-9) -> FloatArray:
    """Roll, pitch, yaw with ``R == from_rpy(roll, pitch, yaw)`` (lecture chapter 4).

    Away from gimbal lock, yaw = atan2(R10, R00); roll and pitch are then read from
    ``Rz(yaw)^T R = Ry(pitch) Rx(roll)``, which keeps the round trip exact to rounding even
    close to the lock, where yaw alone is ill-conditioned. Roll and yaw are in (-pi, pi],
    pitch in [-pi/2, pi/2].

    At gimbal lock (pitch = +-90 deg within ``atol``) only yaw - roll (pitch = +90) or
    yaw + roll (pitch = -90) is defined: roll is set to 0, yaw carries the whole
    angle, ``from_rpy`` of the result still reproduces ``R``, and a ``GimbalLockWarning`` is
    emitted unless ``warn=False`` (use ``gimbal_locked`` to test for it without warnings).

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
        Rotation matrices (validated with ``check_rotation``).
    warn : bool
        Emit ``GimbalLockWarning`` when some matrix is at gimbal lock.
    atol : float
        Gimbal-lock tolerance, as in ``gimbal_locked`` (finite, >= 0).

    Returns
    -------
    rpy : ndarray, shape (..., 3)
        ``[roll, pitch, yaw]`` in radians.

    Raises
    ------
    ValueError
        If ``R`` is not a rotation (see ``check_rotation``), or ``atol`` is not a finite
        number >= 0.

    Warns
    -----
    GimbalLockWarning
        If some matrix is at gimbal lock and ``warn`` is true.
    """
    atol = _v.tolerance(atol)
    R = check_rotation(R)
    R00, R01, R02 = R[..., 0, 0], R[..., 0, 1], R[..., 0, 2]
    R10, R11, R12 = R[..., 1, 0], R[..., 1, 1], R[..., 1, 2]
    R20 = R[..., 2, 0]
    locked = np.hypot(R00, R10) <= atol

    # Not locked: yaw from the first column; M = Rz(-yaw) R = Ry(pitch) Rx(roll) has
    # M00 = cos(pitch), M20 = -sin(pitch), M11 = cos(roll), M12 = -sin(roll).
    yaw = np.arctan2(R10, R00)
    cy, sy = np.cos(yaw), np.sin(yaw)
    # Locked: roll = 0 and R = Rz(yaw) Ry(+-pi/2), whose R01 = -sin(yaw), R11 = cos(yaw).
    yaw = np.where(locked, np.arctan2(-R01, R11), yaw)
    cy = np.where(locked, np.cos(yaw), cy)
    sy = np.where(locked, np.sin(yaw), sy)
    roll = np.where(locked, 0.0, np.arctan2(sy * R02 - cy * R12, cy * R11 - sy * R01))
    pitch = np.arctan2(-R20, cy * R00 + sy * R10)
    pitch = np.where(locked, np.copysign(np.pi / 2, -R20), pitch)
    if warn and np.any(locked):
        _warn_gimbal_lock(int(np.count_nonzero(locked)))
    return np.stack([roll, pitch, yaw], axis=-1)


def _warn_gimbal_lock(n_locked: int) -> None:
    """Emit ``to_rpy``'s ``GimbalLockWarning``, pointing at ``to_rpy``'s caller.

    Parameters
    ----------
    n_locked : int
        How many of the rotations are at gimbal lock.

    Warns
    -----
    GimbalLockWarning
        Always.
    """
    warnings.warn(
        f"gimbal lock: pitch is +-90 deg for {n_locked} rotation(s); "
        "only yaw -+ roll is defined there, so roll was set to 0 "
        "(pass warn=False to silence, or use so3.gimbal_locked)",
        GimbalLockWarning,
        stacklevel=3,  # this function, to_rpy, its caller
    )
