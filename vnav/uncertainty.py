"""Uncertain poses and points: covariance through the camera -> body -> world chain.

One convention throughout (docs/CONVENTIONS.md, "Uncertainty"), that of Barfoot & Furgale,
"Associating uncertainty with three-dimensional poses for use in estimation problems",
IEEE T-RO 30(3), 2014 (here "B&F"): a pose with covariance is

    T = exp(xi^) T_mean,     xi = [rho, phi] ~ N(0, Sigma),  Sigma 6x6,

a *left* perturbation, translation part first. ``exp(xi^) = [[C, J rho], [0, 1]]`` is
``vnav.se3.exp`` (B&F eq. 7-8), and ``Ad(T) = vnav.se3.adjoint(T)`` moves a perturbation
across a pose, ``T exp(xi^) = exp((Ad(T) xi)^) T`` (B&F eq. 12). A point with covariance is
``p = p_mean + dp``, ``dp ~ N(0, Sigma_p)`` (3x3) in the point's own frame.

Everything here is first order (a linearisation about the mean) except ``compose(order=4)``,
which adds B&F's fourth-order terms (eq. 55). The tests check every Jacobian against central
differences and every covariance against Monte Carlo samples pushed through the exact chain.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from statistics import NormalDist

import numpy as np

from vnav import _validate as _v
from vnav import se3
from vnav.camera import PinholeCamera

__all__ = [
    "check_covariance",
    "compose",
    "compose_covariance",
    "invert",
    "nees",
    "nees_band",
    "nees_many",
    "nees_p_value",
    "point_from_depth",
    "point_from_ground",
    "point_from_ground_unchecked",
    "point_jacobian",
    "transform_point",
]

# ------------------------------------------------------------------------ validation


def check_covariance(cov: object, shape: tuple[int, int], name: str = "cov") -> np.ndarray:
    """``cov`` as a float64 array, checked to be a covariance of ``shape``.

    Raises
    ------
    ValueError
        On a wrong shape, a non-finite entry, an asymmetric matrix (beyond 1e-9 of its largest
        entry) or one not positive semidefinite (an eigenvalue below -1e-9 of the largest),
        naming ``name`` and the problem.
    """
    a, scale = _checked_symmetric(cov, shape, name)
    if scale == 0.0:
        return a
    _check_semidefinite(float(np.linalg.eigvalsh(a)[0]), scale, name)
    return a


def _checked_symmetric(cov: object, shape: tuple[int, int], name: str) -> tuple[np.ndarray, float]:
    """``check_covariance`` but for the eigenvalues: ``cov`` as float64, of ``shape``, finite
    and symmetric, and its largest absolute entry (0 for a zero matrix)."""
    a = _v.check_finite(_v.check_shape(_v.as_float(cov, name), name, shape, batched=False), name)
    # ndarray methods, not np.max: numpy's function wrappers cost more than a 6x6 reduction.
    scale = float(np.abs(a).max()) if a.size else 0.0
    if scale == 0.0:
        return a, scale
    asym = float(np.abs(a - a.T).max())
    if asym > 1e-9 * scale:
        raise ValueError(f"{name} must be symmetric; it differs from its transpose by {asym:.3g}")
    return a, scale


def _check_semidefinite(lowest: float, scale: float, name: str) -> None:
    """``check_covariance``'s last test: the smallest eigenvalue ``lowest`` of a symmetric
    matrix whose largest absolute entry is ``scale`` is not below ``-1e-9 scale``."""
    if lowest < -1e-9 * scale:
        raise ValueError(
            f"{name} must be positive semidefinite; its smallest eigenvalue is {lowest:.3g}"
        )


# ------------------------------------------------------------------------ poses


def _dd(A: np.ndarray) -> np.ndarray:
    """``<<A>> = -tr(A) I + A`` of a 3x3 matrix (B&F eq. 53)."""
    return A - np.trace(A) * np.eye(3)


def _dd2(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``<<A, B>> = <<A>> <<B>> + <<B A>>`` (B&F eq. 53)."""
    return _dd(A) @ _dd(B) + _dd(B @ A)


def _dd6(S: np.ndarray) -> np.ndarray:
    """``<<Sigma>>`` of a 6x6 covariance (B&F eq. 54): ``[[<<S_pp>>, <<S_rp + S_rp^T>>],
    [0, <<S_pp>>]]`` with ``rho`` the first block (r) and ``phi`` the second (p)."""
    out = np.zeros((6, 6))
    out[:3, :3] = out[3:, 3:] = _dd(S[3:, 3:])
    out[:3, 3:] = _dd(S[:3, 3:] + S[:3, 3:].T)
    return out


def compose(
    T_a_b: object, cov_a_b: object, T_b_c: object, cov_b_c: object, order: int = 2
) -> tuple[np.ndarray, np.ndarray]:
    """``T_a_c = T_a_b @ T_b_c`` and its covariance, the two poses independent.

    ``exp(xi1^) T1 exp(xi2^) T2 = exp(xi1^) exp((Ad(T1) xi2)^) T1 T2``; to second order
    ``Sigma = Sigma1 + Sigma2'`` with ``Sigma2' = Ad(T1) Sigma2 Ad(T1)^T`` (B&F eq. 38); with
    ``order=4`` the fourth-order terms of B&F eq. 55 are added:
    ``(A1 Sigma2' + Sigma2' A1^T + A2' Sigma1 + Sigma1 A2'^T) / 12 + B / 4``,
    ``A1 = <<Sigma1>>``, ``A2' = <<Sigma2'>>``.

    Parameters
    ----------
    T_a_b, T_b_c : ndarray, shape (4, 4)
    cov_a_b, cov_b_c : ndarray, shape (6, 6)
    order : {2, 4}

    Returns
    -------
    T_a_c : ndarray, shape (4, 4)
    cov_a_c : ndarray, shape (6, 6)
    """
    if order not in (2, 4):
        raise ValueError(f"order must be 2 or 4, got {order!r}")
    T1 = se3.check_transform(T_a_b, "T_a_b")
    T2 = se3.check_transform(T_b_c, "T_b_c")
    S1 = check_covariance(cov_a_b, (6, 6), "cov_a_b")
    S2 = check_covariance(cov_b_c, (6, 6), "cov_b_c")
    if order == 2:
        return T1 @ T2, compose_covariance(T1, S1, S2)
    Ad = se3.adjoint(T1)
    S2p = Ad @ S2 @ Ad.T
    cov = S1 + S2p
    if order == 4:
        A1, A2 = _dd6(S1), _dd6(S2p)
        r, p = slice(0, 3), slice(3, 6)
        B = np.zeros((6, 6))
        B[r, r] = (
            _dd2(S1[p, p], S2p[r, r])
            + _dd2(S1[r, p].T, S2p[r, p])
            + _dd2(S1[r, p], S2p[r, p].T)
            + _dd2(S1[r, r], S2p[p, p])
        )
        B[r, p] = _dd2(S1[p, p], S2p[r, p].T) + _dd2(S1[r, p].T, S2p[p, p])
        B[p, r] = B[r, p].T
        B[p, p] = _dd2(S1[p, p], S2p[p, p])
        cov = cov + (A1 @ S2p + S2p @ A1.T + A2 @ S1 + S1 @ A2.T) / 12.0 + B / 4.0
    return T1 @ T2, 0.5 * (cov + cov.T)


def compose_covariance(T_a_b: np.ndarray, cov_a_b: np.ndarray, cov_b_c: np.ndarray) -> np.ndarray:
    """The covariance of ``T_a_b @ T_b_c`` to second order, as ``compose`` gives it, but on
    inputs the caller has validated (``vnav.localize`` checks its poses and covariances once
    per detection; this adds no second check).

    ``cov_a_c = cov_a_b + Ad(T_a_b) cov_b_c Ad(T_a_b)^T`` (B&F eq. 38), symmetrised.

    Parameters
    ----------
    T_a_b : ndarray, shape (4, 4)
        A rigid transform (``se3.check_pose``); ``T_b_c`` itself does not enter.
    cov_a_b, cov_b_c : ndarray, shape (6, 6)
        Left-perturbation covariances (``check_covariance``) of the two independent poses.

    Returns
    -------
    cov_a_c : ndarray, shape (6, 6)

    Raises
    ------
    ValueError
        If ``T_a_b`` is not one rigid transform; the covariances are not checked.
    """
    Ad = se3.adjoint(T_a_b)
    cov = cov_a_b + Ad @ cov_b_c @ Ad.T
    return 0.5 * (cov + cov.T)


def invert(T: object, cov: object) -> tuple[np.ndarray, np.ndarray]:
    """``T^-1`` and its covariance: ``(exp(xi^) T)^-1 = exp(-(Ad(T^-1) xi)^) T^-1``, so
    ``Sigma_inv = Ad(T^-1) Sigma Ad(T^-1)^T``, exact (a linear map of a Gaussian).

    Returns
    -------
    T_inv : ndarray, shape (4, 4)
    cov_inv : ndarray, shape (6, 6)
    """
    T = se3.check_transform(T, "T")
    S = check_covariance(cov, (6, 6), "cov")
    T_inv = se3.invert(T)
    Ad = se3.adjoint(T_inv)
    out = Ad @ S @ Ad.T
    return T_inv, 0.5 * (out + out.T)


# ------------------------------------------------------------------------ points


def point_jacobian(p_a: Sequence[float]) -> np.ndarray:
    """``d(exp(xi^) p_a) / d xi`` at ``xi = 0``: ``[I, -p_a^]``, the first three rows of B&F's
    ``p^odot`` for the homogeneous point ``[p_a, 1]`` (the Jacobian in B&F eq. 30).

    A left perturbation ``xi`` of a pose ``T_a_b`` moves the point ``p_a = T_a_b p_b`` by
    ``point_jacobian(p_a) @ xi`` to first order; ``G cov_a_b G^T`` is that part of the point's
    covariance (``transform_point``, ``vnav.covariance``).

    Parameters
    ----------
    p_a : sequence of 3 floats, or ndarray, shape (3,)
        The point in the pose's left (reference) frame, metres. Not checked: the callers run
        it per estimate on points they computed.

    Returns
    -------
    G : ndarray, shape (3, 6)
        Acting on ``xi = [rho, phi]``.
    """
    x, y, z = p_a
    return np.array(
        [[1.0, 0.0, 0.0, 0.0, z, -y], [0.0, 1.0, 0.0, -z, 0.0, x], [0.0, 0.0, 1.0, y, -x, 0.0]]
    )


def _transform_point(
    T: np.ndarray, cov_T: np.ndarray, p_b: np.ndarray, cov_p_b: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    R = T[:3, :3]
    p_a = R @ p_b + T[:3, 3]
    G = point_jacobian(p_a)
    cov = G @ cov_T @ G.T + R @ cov_p_b @ R.T
    return p_a, 0.5 * (cov + cov.T)


def transform_point(
    T_a_b: object, cov_a_b: object, p_b: object, cov_p_b: object
) -> tuple[np.ndarray, np.ndarray]:
    """``p_a = T_a_b p_b`` and its covariance, first order, pose and point independent.

    ``exp(xi^) T (p_b + dp) = p_a + [I, -p_a^] xi + R dp + O(2)`` (B&F eq. 30), so
    ``Sigma_a = G Sigma_T G^T + R Sigma_b R^T`` with ``G = [I, -p_a^]``.

    Returns
    -------
    p_a : ndarray, shape (3,)
    cov_p_a : ndarray, shape (3, 3)
    """
    T = se3.check_transform(T_a_b, "T_a_b")
    S = check_covariance(cov_a_b, (6, 6), "cov_a_b")
    p = _v.vector(p_b, "p_b", 3, batched=False)
    Sp = check_covariance(cov_p_b, (3, 3), "cov_p_b")
    return _transform_point(T, S, p, Sp)


def point_from_depth(
    camera: PinholeCamera,
    T_w_c: object,
    uv: object,
    z_m: float,
    *,
    cov_uv: object,
    var_z: float,
    cov_T_w_c: object,
) -> tuple[np.ndarray, np.ndarray]:
    """A pixel with planar depth, back-projected into the world, with its covariance.

    ``p_c = [(u - cx) z / fx, (v - cy) z / fy, z]`` (the pinhole model, VNAV lecture 1), then
    ``p_w = T_w_c p_c`` (``transform_point``). Jacobians:
    ``dp_c / d(u, v) = [[z / fx, 0], [0, z / fy], [0, 0]]``,
    ``dp_c / dz = [(u - cx) / fx, (v - cy) / fy, 1]``.

    Parameters
    ----------
    camera : PinholeCamera
    T_w_c : ndarray, shape (4, 4)
    uv : ndarray, shape (2,)
        Pixel, OpenCV convention.
    z_m : float
        Planar depth along the optical axis, metres, > 0.
    cov_uv : ndarray, shape (2, 2)
        Pixel covariance, px^2.
    var_z : float
        Depth variance, m^2, >= 0.
    cov_T_w_c : ndarray, shape (6, 6)

    Returns
    -------
    p_w : ndarray, shape (3,)
    cov_p_w : ndarray, shape (3, 3)
    """
    T = se3.check_transform(T_w_c, "T_w_c")
    u, v = _v.vector(uv, "uv", 2, batched=False)
    if not (math.isfinite(z_m) and z_m > 0.0):
        raise ValueError(f"z_m must be a positive depth, got {z_m!r}")
    if not (math.isfinite(var_z) and var_z >= 0.0):
        raise ValueError(f"var_z must be a variance >= 0, got {var_z!r}")
    S_uv = check_covariance(cov_uv, (2, 2), "cov_uv")
    S_T = check_covariance(cov_T_w_c, (6, 6), "cov_T_w_c")
    x, y = (u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy
    p_c = np.array([x * z_m, y * z_m, z_m])
    J_uv = np.array([[z_m / camera.fx, 0.0], [0.0, z_m / camera.fy], [0.0, 0.0]])
    J_z = np.array([x, y, 1.0])
    cov_c = J_uv @ S_uv @ J_uv.T + var_z * np.outer(J_z, J_z)
    return _transform_point(T, S_T, p_c, cov_c)


def point_from_ground(
    camera: PinholeCamera,
    T_w_c: object,
    uv: object,
    *,
    cov_uv: object,
    cov_T_w_c: object,
) -> tuple[np.ndarray, np.ndarray]:
    """Where the ray through pixel ``uv`` meets the ground z = 0, with its covariance.

    ``d_w = R_w_c [(u - cx) / fx, (v - cy) / fy, 1]``, ``p_w = t + lam d_w`` with
    ``lam = -t_z / d_z``. With ``P = I - d_w e_z^T / d_z`` (the projection along the ray onto
    the ground): ``dp / dt = P``, ``dp / dd_w = lam P``, so
    ``dp / d(u, v) = lam P [r_0 / fx, r_1 / fy]`` (``r_i`` the columns of ``R_w_c``) and, for a
    left perturbation ``t -> t + rho + phi x t``, ``d_w -> d_w + phi x d_w``,
    ``dp / dxi = P [I, -p_w^]``. The covariance has rank 2 at most: the point is on z = 0 by
    construction (its third row and column are zero).

    Parameters
    ----------
    camera : PinholeCamera
    T_w_c : ndarray, shape (4, 4)
    uv : ndarray, shape (2,)
    cov_uv : ndarray, shape (2, 2)
        Pixel covariance, px^2.
    cov_T_w_c : ndarray, shape (6, 6)

    Returns
    -------
    p_w : ndarray, shape (3,)
    cov_p_w : ndarray, shape (3, 3)

    Raises
    ------
    ValueError
        If the camera is not above the ground or the ray does not point down to it.
    """
    T = se3.check_transform(T_w_c, "T_w_c")
    u, v = _v.vector(uv, "uv", 2, batched=False)
    S_uv = check_covariance(cov_uv, (2, 2), "cov_uv")
    S_T = check_covariance(cov_T_w_c, (6, 6), "cov_T_w_c")
    p_w, cov = point_from_ground_unchecked(camera, T, float(u), float(v), S_uv, S_T)
    return p_w, 0.5 * (cov + cov.T)


def point_from_ground_unchecked(
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    u: float,
    v: float,
    cov_uv: np.ndarray,
    cov_T_w_c: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """``point_from_ground`` on inputs the caller has validated, in plain floats where numpy's
    per-call cost would dominate (``vnav.covariance.ground_plane_cov`` runs it for every
    detection). The same formulas; the covariance is symmetric to rounding, not symmetrised.

    Parameters
    ----------
    camera : PinholeCamera
    T_w_c : ndarray, shape (4, 4)
        A rigid transform (``se3.check_pose``), not checked here.
    u, v : float
        The pixel, OpenCV convention.
    cov_uv : ndarray, shape (2, 2)
        Pixel covariance, px^2 (``check_covariance``), not checked here.
    cov_T_w_c : ndarray, shape (6, 6)
        Left-perturbation covariance of ``T_w_c``, not checked here.

    Returns
    -------
    p_w : ndarray, shape (3,)
    cov_p_w : ndarray, shape (3, 3)

    Raises
    ------
    ValueError
        If the camera is not above the ground or the ray does not point down to it.
    """
    (r00, r01, r02, tx), (r10, r11, r12, ty), (r20, r21, r22, tz), _ = T_w_c.tolist()
    x, y = (u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy
    dx, dy, dz = r00 * x + r01 * y + r02, r10 * x + r11 * y + r12, r20 * x + r21 * y + r22
    _check_reaches_ground(tz, (dx, dy, dz), u, v)
    lam = -tz / dz
    px, py = tx + lam * dx, ty + lam * dy
    # J = P [lam r_0 / fx, lam r_1 / fy, I, -p^] with P = I - d e_z^T / d_z, the projection
    # along the ray onto the ground: its third row is zero, so the covariance's third row
    # and column come out exactly zero. Row i of P J0 is J0's row i minus (d_i / d_z) row 2.
    ku, kv = lam / camera.fx, lam / camera.fy
    row2 = (ku * r20, kv * r21, 0.0, 0.0, 1.0, py, -px, 0.0)
    qx, qy = dx / dz, dy / dz
    u2, v2 = row2[0], row2[1]
    J = np.array(
        [
            [ku * r00 - qx * u2, kv * r01 - qx * v2, 1.0, 0.0, -qx, -qx * py, qx * px, -py],
            [ku * r10 - qy * u2, kv * r11 - qy * v2, 0.0, 1.0, -qy, -qy * py, qy * px, px],
            [0.0] * 8,
        ]
    )
    J_uv, J_xi = J[:, :2], J[:, 2:]
    return np.array([px, py, 0.0]), J_uv @ cov_uv @ J_uv.T + J_xi @ cov_T_w_c @ J_xi.T


def _check_reaches_ground(tz: float, d_w: tuple[float, float, float], u: float, v: float) -> None:
    """Refuse a camera that is not above the ground, or a ray that does not point down to it.

    Parameters
    ----------
    tz : float
        The camera's height, metres.
    d_w : tuple of 3 floats
        The pixel's ray, world frame (any length).
    u, v : float
        The pixel (for the message).

    Raises
    ------
    ValueError
        If ``tz`` is not positive, or the ray's z is not negative (to a relative ``1e-9``).
    """
    dx, dy, dz = d_w
    if not tz > 0.0:
        raise ValueError(f"the camera must be above the ground z = 0, got z = {tz:.6g} m")
    if not dz < -1e-9 * math.sqrt(dx * dx + dy * dy + dz * dz):
        raise ValueError(
            f"the ray through pixel ({u:g}, {v:g}) does not reach the ground "
            f"(its world z component is {dz:.3g}, not negative)"
        )


# ------------------------------------------------------------------------ consistency


def nees(error: object, cov: object, rtol: float = 1e-9) -> tuple[float, int]:
    """The normalised estimation error squared ``e^T Sigma^+ e`` and its degrees of freedom.

    The pseudo-inverse is taken on the covariance's range (eigenvalues above ``rtol`` times
    the largest) and the degrees of freedom are its rank: a ground-plane covariance, exact in
    z, gives a 2-dof NEES. An error with a component outside that range (more than 1e-9 m or
    ``sqrt(rtol)`` of its length) is impossible under the covariance: NEES = inf.

    Returns
    -------
    value : float
    dof : int
    """
    e = np.asarray(error, dtype=np.float64).reshape(-1)
    n = e.size
    # check_covariance, with its semidefiniteness read off the eigenvalues needed here anyway
    # (one eigen-decomposition per call, not two: NEES is computed per method and detection).
    S, scale = _checked_symmetric(cov, (n, n), "cov")
    w, V = np.linalg.eigh(S)
    if scale != 0.0:
        _check_semidefinite(float(w[0]), scale, "cov")
    top = float(w[-1])
    if top <= 0.0:
        return (0.0, 0) if not np.any(e) else (math.inf, 0)
    keep = w > rtol * top
    c = V.T @ e
    # |x| as np.linalg.norm computes it for a real vector, sqrt(x . x), without its wrapper.
    outside_c = c[~keep]
    outside = math.sqrt(float(outside_c.dot(outside_c)))
    if outside > 1e-9 + math.sqrt(rtol) * math.sqrt(float(e.dot(e))):
        return math.inf, int(keep.sum())
    return float(np.sum(c[keep] ** 2 / w[keep])), int(keep.sum())


def nees_many(errors: object, covs: object, rtol: float = 1e-9) -> list[tuple[float, int]]:
    """``nees`` of each error (M, n) against its covariance (M, n, n): every estimate of a
    detection at once, the covariances checked and decomposed as one stack. numpy decomposes
    a stack matrix by matrix with the same LAPACK routine, so each value is ``nees``'s (the
    reference form) to the last bit; a test compares them.

    Raises
    ------
    ValueError
        As ``nees`` would for the first pair it refuses, with its message.
    """
    e = np.asarray(errors, dtype=np.float64)
    S = np.asarray(covs, dtype=np.float64)
    if e.ndim != 2 or S.shape != (e.shape[0], e.shape[1], e.shape[1]):
        raise ValueError(f"errors must be (M, n) and covs (M, n, n); got {e.shape} and {S.shape}")
    if not len(e):
        return []
    # ``check_covariance``'s tests, every matrix at once; on a failure ``nees`` of the pair
    # raises its own message.
    scale = np.abs(S).max(axis=(1, 2)) if np.isfinite(S).all() else None
    bad = scale is None or bool(
        (np.abs(S - S.transpose(0, 2, 1)).max(axis=(1, 2)) > 1e-9 * scale).any()
    )
    if not bad:
        w, V = np.linalg.eigh(S)
        bad = bool(((scale != 0.0) & (w[:, 0] < -1e-9 * scale)).any())
    if bad:
        return [nees(ei, Si, rtol) for ei, Si in zip(e, S, strict=True)]
    # ``nees`` past its decomposition, every pair at once: ``Vi.T @ ei`` as a stack is the
    # same BLAS product matrix by matrix; the eigenvalues come sorted, so those ``nees``
    # leaves out are a row's first, and its sum with zeros in their place is the same sum.
    top = w[:, -1]
    keep = w > rtol * top[:, None]
    c = np.matmul(V.transpose(0, 2, 1), e[:, :, None])[..., 0]
    terms = np.where(keep, c**2 / np.where(keep, w, 1.0), 0.0)
    values = np.sum(terms, axis=1).tolist()
    dofs = keep.sum(axis=1).tolist()
    out = list(zip(values, dofs, strict=True))
    for i in np.flatnonzero(~keep.all(axis=1)).tolist():
        ei = e[i]
        if not float(top[i]) > 0.0:
            out[i] = (0.0, 0) if not np.any(ei) else (math.inf, 0)
            continue
        outside_c = c[i][~keep[i]]
        outside = math.sqrt(float(outside_c.dot(outside_c)))
        if outside > 1e-9 + math.sqrt(rtol) * math.sqrt(float(ei.dot(ei))):
            out[i] = (math.inf, dofs[i])
    return out


def _wilson_hilferty(k: float) -> tuple[float, float]:
    """Mean and standard deviation of ``(X / k)^(1/3)`` for ``X ~ chi2(k)`` (Wilson &
    Hilferty 1931): ``1 - 2 / (9k)`` and ``sqrt(2 / (9k))``, the cube root being nearly
    Gaussian."""
    s2 = 2.0 / (9.0 * k)
    return 1.0 - s2, math.sqrt(s2)


def nees_band(dof: float, count: int, probability: float = 0.95) -> tuple[float, float]:
    """The two-sided ``probability`` band of the mean of ``count`` NEES values of ``dof``
    degrees of freedom (their sum is chi-square with ``dof * count``; Bar-Shalom, Li &
    Kirubarajan 2001, sec. 5.4.2), by the Wilson-Hilferty approximation (within 0.5% of the
    exact quantiles from 6 degrees of freedom in all; the tests compare with SciPy).

    Returns
    -------
    low, high : float
    """
    if not (count >= 1 and dof > 0.0 and 0.0 < probability < 1.0):
        raise ValueError(
            f"need count >= 1, dof > 0 and 0 < probability < 1, got {count}, {dof}, {probability}"
        )
    k = dof * count
    mean, std = _wilson_hilferty(k)
    z = NormalDist().inv_cdf(0.5 + 0.5 * probability)
    low = k * max(mean - z * std, 0.0) ** 3
    high = k * (mean + z * std) ** 3
    return low / count, high / count


def nees_p_value(mean_nees: float, dof: float, count: int) -> float:
    """The two-sided chi-square probability of a mean NEES at least this far from ``dof``:
    ``2 min(F, 1 - F)`` with ``F`` the chi-square(``dof * count``) CDF of the sum (Wilson &
    Hilferty), so that ``p >= 0.05`` exactly when the mean lies in ``nees_band(..., 0.95)``.
    0 for an infinite or NaN mean."""
    if not math.isfinite(mean_nees):
        return 0.0
    k = dof * count
    mean, std = _wilson_hilferty(k)
    z = ((max(mean_nees, 0.0) / dof) ** (1.0 / 3.0) - mean) / std
    F = NormalDist().cdf(z)
    return 2.0 * min(F, 1.0 - F)
