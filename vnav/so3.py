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
import warnings

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
# Rows per block in `exp`: the element-wise temporaries of one block stay in cache.
_CHUNK = 8192


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
    """The full check of ``check_rotation``; ``atol`` widened for a float32 source."""
    tol = _v.widened_for(atol, source_dtype)
    R = _v.matrix(R, name)
    if R.size == 0:
        return R
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
# Axis-angle: exp and log (lecture chapter 5)
# --------------------------------------------------------------------------------------------


def exp(rotvec: ArrayLike) -> FloatArray:
    """Rotation matrix of a rotation vector ``theta * u`` (Rodrigues' formula, lecture ch. 5).

    ``R = I + A [v]x + B [v]x^2`` with ``v = theta u``, ``A = sin(theta)/theta`` and
    ``B = (1 - cos(theta))/theta^2 = 2 sin^2(theta/2)/theta^2`` (the half-angle form avoids the
    cancellation of 1 - cos). This equals the lecture's ``cos(t) I + sin(t) [u]x +
    (1 - cos(t)) u u^T`` because ``[u]x^2 = u u^T - I``. Below 1e-4 rad, A and B come from
    their Taylor series, so ``exp`` is exact to rounding near the identity.

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
    finite = True
    with np.errstate(invalid="ignore", over="ignore"):
        for start in range(0, v.shape[0], _CHUNK):
            finite &= _exp_block(v[start : start + _CHUNK], R[start : start + _CHUNK])
    if not finite:
        _v.check_finite(rotvec, "rotvec")  # raises for NaN or inf
        raise ValueError(
            "rotvec is too long: |rotvec|^2 overflows float64 (an angle beyond 1e154 rad has "
            "no meaningful value)"
        )
    return R.reshape(*rotvec.shape, 3)


def _exp_block(v: FloatArray, R: FloatArray) -> bool:
    """Fill ``R`` (M, 3, 3) with ``exp`` of ``v`` (M, 3); False if theta^2 is not finite.

    Works on a contiguous transposed copy of the block, so every ufunc runs in place on
    contiguous cache-resident rows, and writes the nine entries back with one transposing copy.
    """
    x, y, z = v.T.copy()
    res = np.empty((9, v.shape[0]))
    xx, yy, zz = x * x, y * y, z * z
    t2 = xx + yy
    t2 += zz
    finite = bool(np.isfinite(t2.sum()))
    t = np.sqrt(t2)
    # One transcendental call: with tau = tan(theta/4), sin(theta/2) = 2 tau / (1 + tau^2) and
    # cos(theta/2) = (1 - tau^2) / (1 + tau^2) (half-angle identities, valid at any angle and
    # without cancellation that matters: the absolute error of each stays ~1 ulp).
    tau = np.multiply(t, 0.25)
    np.tan(tau, out=tau)
    tau2 = np.multiply(tau, tau)
    d = np.add(tau2, 1.0)
    np.divide(1.0, d, out=d)
    A = np.subtract(1.0, tau2, out=tau2)
    A *= d  # cos(theta/2)
    h = np.multiply(tau, d, out=tau)
    h *= 2.0  # sin(theta/2)
    with np.errstate(divide="ignore"):
        np.divide(h, t, out=h)  # sin(theta/2) / theta
    A *= h
    A *= 2.0  # sin(theta) / theta = 2 sin(theta/2) cos(theta/2) / theta
    B = np.multiply(h, h, out=h)
    B *= 2.0  # (1 - cos(theta)) / theta^2 = 2 sin^2(theta/2) / theta^2
    small = t < _SMALL_ANGLE
    if small.any():
        ts = t2[small]
        A[small] = 1.0 - ts / 6.0 * (1.0 - ts / 20.0)
        B[small] = 0.5 - ts / 24.0 * (1.0 - ts / 30.0)
    # R = I + A [v]x + B (v v^T - theta^2 I); diagonal 1 - B (theta^2 - v_i^2).
    for a, b, i in ((yy, zz, 0), (xx, zz, 4), (xx, yy, 8)):
        r = np.add(a, b, out=res[i])
        r *= B
        np.subtract(1.0, r, out=r)
    # Off-diagonal: R_ij = B v_i v_j - A v_k, R_ji = B v_i v_j + A v_k for (i, j, k) cyclic.
    Bxy = np.multiply(x, y, out=xx)
    Bxy *= B
    Byz = np.multiply(y, z, out=yy)
    Byz *= B
    Bxz = np.multiply(x, z, out=zz)
    Bxz *= B
    x *= A
    y *= A
    z *= A
    for bb, av, i, j in ((Bxy, z, 0, 1), (Byz, x, 1, 2), (Bxz, y, 2, 0)):
        np.subtract(bb, av, out=res[3 * i + j])
        np.add(bb, av, out=res[3 * j + i])
    R.reshape(-1, 9)[...] = res.T
    return finite


def log(R: ArrayLike) -> FloatArray:
    """Rotation vector ``theta * u`` of a rotation matrix, ``theta`` in [0, pi].

    Accurate to rounding for every rotation, unlike ``arccos((tr R - 1)/2)``, which loses half
    the digits near 0 and near pi:

    - the angle is ``atan2(|w|/2, (tr R - 1)/2)`` with ``w = vee(R - R^T) = 2 sin(theta) u``
      (from the lecture's chapter 5 formula: tr R = 1 + 2 cos(theta), and the antisymmetric
      part of R is sin(theta) [u]x);
    - for theta <= pi/2 the axis is ``w / |w|``, so the vector is ``w theta / (2 sin theta)``,
      with a Taylor series of theta / sin(theta) below 1e-4 rad;
    - for theta > pi/2, where |w| vanishes, the axis comes from the symmetric part
      ``(R + R^T)/2 - cos(theta) I = (1 - cos(theta)) u u^T``: its column with the largest
      diagonal entry, normalised, with the sign that makes it point along w. At exactly pi both
      signs give the same rotation.

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
    R_in = check_rotation(R)
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
        warnings.warn(
            f"gimbal lock: pitch is +-90 deg for {int(np.count_nonzero(locked))} rotation(s); "
            "only yaw -+ roll is defined there, so roll was set to 0 "
            "(pass warn=False to silence, or use so3.gimbal_locked)",
            GimbalLockWarning,
            stacklevel=2,
        )
    return np.stack([roll, pitch, yaw], axis=-1)
