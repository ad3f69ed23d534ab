"""Rigid-body transforms, the group SE(3), as 4x4 homogeneous matrices (lecture chapter 7).

``T_a_b = [[R_a_b, t_a_b], [0, 0, 0, 1]]`` is the pose of frame b in frame a: it maps
b-coordinates into a, ``p_a = R_a_b @ p_b + t_a_b`` (``apply``). Composition is plain ``@`` and
the inner letters cancel, ``T_a_c = T_a_b @ T_b_c``; the inverse has the closed form
``T_b_a = [[R^T, -R^T t], [0, 1]]`` (``invert``). Arrays are the interchange format: (4, 4)
float64, or (..., 4, 4) stacks where a function says so. Conventions: docs/CONVENTIONS.md.

The exponential map and its inverse, ``exp`` and ``log``, and the adjoint ``adjoint`` follow
Barfoot & Furgale, "Associating uncertainty with three-dimensional poses for use in estimation
problems", IEEE T-RO 30(3), 2014 (here "B&F"): ``xi = [rho, phi]``, translation first, and
``xi^ = [[phi^, rho], [0, 0]]``.

``compose_xyzw_xyz`` and ``invert_xyzw_xyz`` are the group's product and inverse on a pose's
seven components, a unit quaternion ``[x, y, z, w]`` then the translation: the kernels of
``vnav.frames.FrameBuffer``'s lookups.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from vnav import _validate as _v
from vnav import so3
from vnav._validate import FloatArray

__all__ = [
    "adjoint",
    "apply",
    "check_pose",
    "check_transform",
    "compose_xyzw_xyz",
    "exp",
    "invert",
    "invert_xyzw_xyz",
    "log",
    "make",
]

_BOTTOM = np.array([0.0, 0.0, 0.0, 1.0])
# `_apply_blas` adds the translation to blocks of this many points at once: broadcasting a
# (3,) vector over (N, 3) rows runs an inner loop of length 3, ~4x slower than long rows.
_T_BLOCK = 512
# Rows per chunk in `_apply_blas`. OpenBLAS runs a product on one thread when
# M N K <= 4 * 65536 (its GEMM_MULTITHREAD_THRESHOLD): 16384 rows x 3 x 3 stays below, so no
# worker thread is woken, and none can stall when another process holds the other core.
_CHUNK = 16384
# Rows per call of cv2.transform (its row count is a C int).
_CV2_ROWS = 1 << 24
_DBL_EPSILON = float(np.finfo(np.float64).eps)
_SMALL_ANGLE = 1e-6
"""Below this rotation angle (rad) the left Jacobian and its inverse use their Taylor series."""


def make(R: ArrayLike, t: ArrayLike) -> FloatArray:
    """Homogeneous transform ``[[R, t], [0, 0, 0, 1]]`` (lecture chapter 7).

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
        Rotation ``R_a_b`` (validated with ``vnav.so3.check_rotation``).
    t : array_like, shape (..., 3)
        Translation ``t_a_b``, the position of b's origin in a. Leading shapes broadcast.

    Returns
    -------
    T : ndarray, shape (..., 4, 4)

    Raises
    ------
    ValueError
        If ``R`` is not a rotation, or ``t`` is not (..., 3) or holds NaN or inf.
    """
    R = so3.check_rotation(R, "R")
    t = _v.vector(t, "t")
    try:
        batch = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    except ValueError as exc:
        raise ValueError(
            f"R and t leading shapes must broadcast; got R {R.shape} and t {t.shape}"
        ) from exc
    T = np.zeros((*batch, 4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def _clearly_rigid(T: object, atol: float) -> bool:
    """True when ``T`` is one float64 (4, 4) array that the full check accepts: finite, bottom
    row exactly [0, 0, 0, 1], rotation block within ``atol`` of orthonormal with det > 0.

    Plain float arithmetic, about 2 us where the batched check takes about 40 us; anything
    else, or any doubt, goes to the full check and its messages.
    """
    if type(T) is not np.ndarray or T.dtype != np.float64 or T.shape != (4, 4):
        return False
    (a, b, c, tx), (d, e, f, ty), (g, h, i, tz), bottom = T.tolist()
    if bottom != [0.0, 0.0, 0.0, 1.0]:
        return False
    if not math.isfinite(a + b + c + d + e + f + g + h + i + tx + ty + tz):
        return False  # a NaN or inf (or an overflow): let the full check say which
    err, det = so3._rotation_error(a, b, c, d, e, f, g, h, i)
    return err <= atol and det > 0.0


def check_transform(T: ArrayLike, name: str = "T", atol: float = 1e-9) -> FloatArray:
    """Validate a homogeneous transform (or a stack) and return it as float64.

    Parameters
    ----------
    T : array_like, shape (..., 4, 4)
    name : str
        The argument's name, used in error messages.
    atol : float
        Tolerance on the rotation block (see ``vnav.so3.check_rotation``: finite, >= 0, widened
        for float32 input); the bottom row must be exactly ``[0, 0, 0, 1]``.

    Returns
    -------
    T : ndarray, shape (..., 4, 4), float64

    Raises
    ------
    ValueError
        If the shape is not (..., 4, 4) (the message gives the shape received), an entry is NaN
        or inf, the bottom row is not ``[0, 0, 0, 1]`` (the message gives the row received), or
        the rotation block is not a rotation; or if ``atol`` is not a finite number >= 0.
    """
    if type(atol) is not float or not 0.0 <= atol < math.inf:  # inline: the fast path's cost
        atol = _v.tolerance(atol)
    if _clearly_rigid(T, atol):
        return T
    source_dtype = getattr(T, "dtype", None)
    T = _v.matrix(T, name, 4)
    bottom = T[..., 3, :]
    if np.any(bottom != _BOTTOM):
        bad = bottom.reshape(-1, 4)[np.any(bottom.reshape(-1, 4) != _BOTTOM, axis=-1)][0]
        raise ValueError(
            f"{name} must have bottom row [0, 0, 0, 1] (a homogeneous rigid transform); "
            f"got bottom row {np.array2string(bad, separator=', ')}"
        )
    so3._check_rotation(T[..., :3, :3], f"the rotation block {name}[:3, :3]", atol, source_dtype)
    return T


def invert(T: ArrayLike) -> FloatArray:
    """Inverse transform in closed form, ``[[R^T, -R^T t], [0, 1]]`` (lecture chapter 7).

    ``T_b_a = invert(T_a_b)``. Never a general matrix inverse: exact for any rotation block and
    a dozen multiplications.

    Parameters
    ----------
    T : array_like, shape (..., 4, 4)

    Returns
    -------
    ndarray, shape (..., 4, 4)

    Raises
    ------
    ValueError
        If ``T`` is not a rigid transform (see ``check_transform``).
    """
    T = check_transform(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.matmul(Rt, T[..., :3, 3, None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def apply(T: ArrayLike, p: ArrayLike, *, out: np.ndarray | None = None) -> FloatArray:
    """Transform points: ``p_a = R_a_b @ p_b + t_a_b`` for ``T = T_a_b`` (lecture chapter 7).

    Parameters
    ----------
    T : array_like, shape (4, 4)
        The transform ``T_a_b``.
    p : array_like, shape (3,) or (N, 3) (any (..., 3))
        Points ``p_b``, one per row. NaN rows pass through as NaN (so masked point sets, such
        as points behind a camera, keep their rows); only the shape is checked.
    out : ndarray, optional
        A C-contiguous float64 array of ``p``'s shape to write the result into (a buffer kept
        across frames: no new memory to map per call). It must not overlap ``p``.

    Returns
    -------
    ndarray, same shape as ``p``
        Points ``p_a`` (``out`` itself when given).

    Raises
    ------
    ValueError
        If ``T`` is not a rigid transform, ``p`` does not end with a dimension of 3, or ``out``
        is not a C-contiguous float64 array of ``p``'s shape apart from ``p``.

    Notes
    -----
    Point sets go through ``cv2.transform`` with the 3x4 ``T[:3]``: one single-threaded pass
    at about the speed of a copy, steady whatever else the machine runs (docs/CONVENTIONS.md,
    "Performance and threads"). ``_apply_reference`` is the lecture's form, kept to test it.
    """
    T = check_transform(T)
    if T.ndim != 2:
        raise ValueError(f"T must have shape (4, 4); got shape {T.shape}")
    p = _v.vector(p, "p", finite=False)
    if out is not None:
        _check_out(out, p)
    R, t = T[:3, :3], T[:3, 3]
    if p.ndim == 1:
        if out is None:
            return R @ p + t
        np.matmul(R, p, out=out)
        out += t
        return out
    flat = p.reshape(-1, 3)
    result = np.empty(flat.shape) if out is None else out.reshape(-1, 3)
    if flat.shape[0] > 0:
        if _opencv_treats_as_diagonal(R):
            _apply_blas(R, t, flat, result)
        else:
            _apply_cv2(T, flat, result)
    return result.reshape(p.shape) if out is None else out


def _check_out(out: object, p: FloatArray) -> None:
    """Raise unless ``out`` is a writeable C-contiguous float64 array of ``p``'s shape, apart
    from ``p``."""
    if (
        not isinstance(out, np.ndarray)
        or out.dtype != np.float64
        or out.shape != p.shape
        or not out.flags.c_contiguous
        or not out.flags.writeable
    ):
        raise ValueError(
            f"out must be a writeable C-contiguous float64 array of shape {p.shape}; got "
            f"{getattr(out, 'dtype', type(out).__name__)} {getattr(out, 'shape', '')}"
        )
    if np.shares_memory(out, p):
        raise ValueError("out must not overlap p (the chunks read p after writing out)")


def _opencv_treats_as_diagonal(R: FloatArray) -> bool:
    """Whether cv2.transform would take ``R`` for a diagonal matrix (every off-diagonal entry
    within DBL_EPSILON of 0) and scale each coordinate alone, skipping ``0 * nan = nan``.

    Those few rotations (the identity, the half turns about the axes) go through
    ``_apply_blas``, so that a NaN or inf coordinate spreads to its whole row whatever R is.
    """
    (_, b, c), (d, _, f), (g, h, _) = R.tolist()
    return max(abs(b), abs(c), abs(d), abs(f), abs(g), abs(h)) <= _DBL_EPSILON


def _apply_cv2(T: FloatArray, p: FloatArray, out: FloatArray) -> None:
    """``out = p R^T + t`` for (N, 3) rows, by cv2.transform with the 3x4 matrix ``T[:3]``.

    One pass over the points with the products and the translation fused, single-threaded,
    at about the speed of a copy: never threaded BLAS (whose worker threads stall when
    another process is busy), and none of the (N, 3) temporaries of the numpy form.
    """
    import cv2  # imported here: modules that never transform point sets do not load OpenCV

    M = np.ascontiguousarray(T[:3])
    src = np.ascontiguousarray(p).reshape(-1, 1, 3)  # N points as one 3-channel column
    dst = out.reshape(-1, 1, 3)
    for start in range(0, src.shape[0], _CV2_ROWS):
        chunk = dst[start : start + _CV2_ROWS]
        written = cv2.transform(src[start : start + _CV2_ROWS], M, dst=chunk)
        if written is not chunk:  # never expected: OpenCV reallocated instead of filling dst
            chunk[...] = written


def _apply_blas(R: FloatArray, t: FloatArray, p: FloatArray, out: FloatArray) -> None:
    """``out = p R^T + t`` for (N, 3) rows with numpy: per chunk (in cache for the second
    step), one single-threaded BLAS product, then ``+ t`` on long rows of interleaved
    ``[x0 y0 z0 x1 y1 z1 ...]``."""
    t_rows = np.tile(t, _T_BLOCK)
    with np.errstate(invalid="ignore"):  # inf * 0 = nan, as cv2.transform gives it, silently
        for start in range(0, p.shape[0], _CHUNK):
            chunk = out[start : start + _CHUNK]
            np.matmul(p[start : start + _CHUNK], R.T, out=chunk)
            n_block = chunk.shape[0] // _T_BLOCK * _T_BLOCK
            rows = chunk[:n_block].reshape(-1, 3 * _T_BLOCK)  # a view
            np.add(rows, t_rows, out=rows)
            chunk[n_block:] += t


def _apply_reference(T: FloatArray, p: FloatArray) -> FloatArray:
    """Lecture form of ``apply`` for (..., 3) points: ``p_a = p_b R^T + t`` (chapter 7)."""
    return p @ T[:3, :3].T + T[:3, 3]


def check_pose(T: ArrayLike, name: str = "T") -> FloatArray:
    """Validate exactly one 4x4 rigid transform (``check_transform``'s default tolerance).

    ``check_transform`` also accepts stacks ``(..., 4, 4)``; functions that take one pose
    validate it with this.

    Raises
    ------
    ValueError
        As ``check_transform``, or if ``T`` is a stack rather than a single 4x4 transform.
    """
    T = check_transform(T, name)
    if T.shape != (4, 4):
        raise ValueError(f"{name} must be a single 4x4 transform, got shape {T.shape}")
    return T


# ---------------------------------------------------------------- exponential map (B&F)


def exp(xi: ArrayLike) -> FloatArray:
    """The exponential map of se(3): ``exp(xi^) = [[C, J rho], [0, 1]]`` (B&F eq. 7).

    ``C = so3.exp(phi)`` is Rodrigues' formula (lecture chapter 5) and ``J`` the left Jacobian
    of SO(3) (B&F eq. 8), so the result is a transform as lecture chapter 7 writes it. A pose
    with covariance is ``exp(xi^) @ T_mean`` (docs/CONVENTIONS.md, "Uncertainty").

    Parameters
    ----------
    xi : array_like, shape (6,)
        ``[rho, phi]``: ``rho`` the translation part, metres; ``phi`` the rotation vector,
        radians (any angle).

    Returns
    -------
    T : ndarray, shape (4, 4)

    Raises
    ------
    ValueError
        If ``xi`` is not of shape (6,) or holds NaN or inf.

    Notes
    -----
    Below ``|phi| = 1e-6`` rad ``J`` is its series; above, ``(1 - cos t) / t^2`` loses about
    ``eps / t^2`` to cancellation, so the translation is exact to about ``eps |rho| / |phi|``
    (2e-10 ``|rho|`` just above the branch, 2e-12 ``|rho|`` at 1e-4 rad; tests/test_se3.py
    holds it to that bound against the matrix exponential).
    """
    xi = _v.vector(xi, "xi", 6, batched=False)
    T = np.eye(4)
    T[:3, :3] = so3.exp(xi[3:])
    T[:3, 3] = _left_jacobian(xi[3:]) @ xi[:3]
    return T


def log(T: ArrayLike) -> FloatArray:
    """The inverse of ``exp``: ``xi = [J(phi)^-1 t, phi]`` with ``phi = so3.log(C)``.

    The rotation vector comes from ``so3.log`` (angle in [0, pi], accurate at 0 and pi); the
    translation part inverts ``t = J(phi) rho`` (B&F eq. 7) with ``J^-1`` in closed form
    (Barfoot, "State Estimation for Robotics", 2017, sec. 7.1.5). ``exp(log(T)) == T`` to
    rounding.

    Parameters
    ----------
    T : array_like, shape (4, 4)
        A rigid transform.

    Returns
    -------
    xi : ndarray, shape (6,)
        ``[rho, phi]``, the rotation angle ``|phi|`` in [0, pi].

    Raises
    ------
    ValueError
        If ``T`` is not one rigid transform (see ``check_pose``).
    """
    T = check_pose(T, "T")
    phi = so3.log(T[:3, :3])
    return np.concatenate([_left_jacobian_inverse(phi) @ T[:3, 3], phi])


def adjoint(T: ArrayLike) -> FloatArray:
    """The adjoint of a transform, ``Ad(T) = [[C, t^ C], [0, C]]`` (B&F eq. 12).

    It moves a perturbation across the pose: ``T exp(xi^) = exp((Ad(T) xi)^) T``, so a left
    perturbation ``xi`` of ``T_b_c`` becomes ``Ad(T_a_b) xi`` on ``T_a_c = T_a_b @ T_b_c``.

    Parameters
    ----------
    T : array_like, shape (4, 4)
        A rigid transform ``[[C, t], [0, 1]]``.

    Returns
    -------
    Ad : ndarray, shape (6, 6)
        Acting on ``xi = [rho, phi]``.

    Raises
    ------
    ValueError
        If ``T`` is not one rigid transform (see ``check_pose``).
    """
    T = check_pose(T, "T")
    C, t = T[:3, :3], T[:3, 3]
    out = np.zeros((6, 6))
    out[:3, :3] = C
    out[3:, 3:] = C
    out[:3, 3:] = so3.skew(t) @ C
    return out


def _left_jacobian(phi: FloatArray) -> FloatArray:
    """SO(3)'s left Jacobian, (3, 3) (B&F eq. 8): ``I + (1 - cos t) / t^2 phi^ + (t - sin t) /
    t^3 phi^2`` with ``t = |phi|``; its series to second order below ``_SMALL_ANGLE``."""
    theta = float(np.linalg.norm(phi))
    S = so3.skew(phi)
    if theta < _SMALL_ANGLE:
        return np.eye(3) + 0.5 * S + S @ S / 6.0
    t2 = theta * theta
    return (
        np.eye(3)
        + (1.0 - math.cos(theta)) / t2 * S
        + (theta - math.sin(theta)) / (t2 * theta) * (S @ S)
    )


def _left_jacobian_inverse(phi: FloatArray) -> FloatArray:
    """``J(phi)^-1`` in closed form, (3, 3) (Barfoot, "State Estimation for Robotics", 2017,
    sec. 7.1.5): ``I - phi^ / 2 + (1 - (t / 2) cot(t / 2)) / t^2 phi^2``; finite for
    ``t = |phi|`` in [0, pi], as ``so3.log`` returns it."""
    theta = float(np.linalg.norm(phi))
    S = so3.skew(phi)
    if theta < _SMALL_ANGLE:
        return np.eye(3) - 0.5 * S + S @ S / 12.0
    half = 0.5 * theta
    return np.eye(3) - 0.5 * S + (1.0 - half / math.tan(half)) / (theta * theta) * (S @ S)


# ------------------------------------------------ seven components: quaternion, translation

# A pose as its components ``(qx, qy, qz, qw, x, y, z)``: the unit quaternion scalar last
# (docs/CONVENTIONS.md, "Quaternions"), then the translation, metres (jaxlie's ``wxyz_xyz``
# layout with vnav's quaternion order). Each component is a float, or an (N,) array for N
# poses at once: the same arithmetic serves one pose (plain Python, no numpy call) and many
# (numpy columns, not (N, 4, 4) stacks).
_Component = float | FloatArray
XyzwXyz = tuple[_Component, ...]


def _rotate(
    qx: _Component,
    qy: _Component,
    qz: _Component,
    qw: _Component,
    vx: _Component,
    vy: _Component,
    vz: _Component,
) -> tuple[_Component, _Component, _Component]:
    """``R(q) v`` as ``v + w t + u x t`` with ``t = 2 u x v``, ``u`` the vector part of ``q``:
    ``q v q*`` expanded for a unit quaternion (lecture chapter 6's ``R(q)`` applied to ``v``)."""
    tx = 2.0 * (qy * vz - qz * vy)
    ty = 2.0 * (qz * vx - qx * vz)
    tz = 2.0 * (qx * vy - qy * vx)
    return (
        vx + qw * tx + (qy * tz - qz * ty),
        vy + qw * ty + (qz * tx - qx * tz),
        vz + qw * tz + (qx * ty - qy * tx),
    )


def compose_xyzw_xyz(pose_a_b: XyzwXyz, pose_b_c: XyzwXyz) -> XyzwXyz:
    """``T_a_c = T_a_b @ T_b_c`` of two poses given as components ``(qx, qy, qz, qw, x, y, z)``.

    The rotation is the Hamilton product ``q_a_b q_b_c`` (lecture chapter 6, as
    ``quat.multiply``), the translation ``t_a_b + R(q_a_b) t_b_c`` (lecture chapter 7): as 4x4
    matrices, the result is ``T_a_b @ T_b_c`` to rounding, the inner letters cancelling.

    No check of any kind: this is ``vnav.frames.FrameBuffer``'s inner loop (several calls per
    lookup, a few microseconds each), where a check would cost more than the arithmetic. The
    caller passes unit quaternions.

    Parameters
    ----------
    pose_a_b, pose_b_c : tuple of 7 floats, or of 7 arrays of shape (N,)
        ``(qx, qy, qz, qw, x, y, z)``, translations in metres; arrays broadcast against each
        other and against floats.

    Returns
    -------
    pose_a_c : tuple of 7 floats, or of 7 arrays of shape (N,)
        In the same order.
    """
    ax, ay, az, aw, apx, apy, apz = pose_a_b
    bx, by, bz, bw, bpx, bpy, bpz = pose_b_c
    px, py, pz = _rotate(ax, ay, az, aw, bpx, bpy, bpz)
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
        apx + px,
        apy + py,
        apz + pz,
    )


def invert_xyzw_xyz(pose_a_b: XyzwXyz) -> XyzwXyz:
    """``T_b_a = T_a_b^-1`` of a pose given as components ``(qx, qy, qz, qw, x, y, z)``.

    The conjugate quaternion (lecture chapter 6) and ``-R^T t`` (lecture chapter 7, as
    ``invert``). Unchecked, as ``compose_xyzw_xyz``: the caller passes a unit quaternion.

    Parameters
    ----------
    pose_a_b : tuple of 7 floats, or of 7 arrays of shape (N,)
        ``(qx, qy, qz, qw, x, y, z)``, translation in metres.

    Returns
    -------
    pose_b_a : tuple of 7 floats, or of 7 arrays of shape (N,)
        In the same order.
    """
    qx, qy, qz, qw, px, py, pz = pose_a_b
    ix, iy, iz = _rotate(-qx, -qy, -qz, qw, px, py, pz)
    return (-qx, -qy, -qz, qw, -ix, -iy, -iz)
