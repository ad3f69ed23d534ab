"""Levenberg-Marquardt: the non-linear least-squares solver of both calibrations.

``levenberg_marquardt`` minimises ``|r(x)|^2`` with Marquardt's diagonal scaling (Nocedal &
Wright, *Numerical Optimization*, 2nd ed., section 10.3): each iteration solves
``(A + lam D) step = -g`` with the normal equations ``A = J^T J``, ``g = J^T r`` and
``D = diag(A)``, keeps the step if it lowers the cost (``lam`` divided by 10) and otherwise
damps more (``lam`` times 10) until it does. The problem gives its residuals and its normal
equations: the camera mount's calibration (``vnav.calibration``) from a numerical Jacobian,
the camera-IMU calibration (``vnav.imu_calibration``) from a sparse one.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["levenberg_marquardt"]

LAMBDA_START = 1e-3
"""The damping of the first step, relative to ``diag(A)``."""
LAMBDA_MIN, LAMBDA_MAX = 1e-12, 1e12
"""The damping's floor, and the ceiling past which no step lowers the cost (``x`` is kept)."""


def levenberg_marquardt(
    residuals: Callable[[np.ndarray], np.ndarray],
    normal_equations: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]],
    x: np.ndarray,
    *,
    iterations: int,
    gain_tol: float,
    step_tol: float = 0.0,
    solve: Callable[[np.ndarray, np.ndarray], np.ndarray] = np.linalg.solve,
) -> np.ndarray:
    """Minimise ``|residuals(x)|^2`` from ``x``.

    Parameters
    ----------
    residuals : callable, (n,) -> (m,)
    normal_equations : callable, ((n,), (m,)) -> ((n, n), (n,))
        ``A = J^T J`` and ``g = J^T r`` at ``x`` with ``r = residuals(x)``.
    x : ndarray, shape (n,)
        The start.
    iterations : int
        Accepted steps at most.
    gain_tol : float
        Stop when a step lowers the cost by less than this fraction of it.
    step_tol : float
        Stop when every component of a step is smaller than this (0: never).
    solve : callable, ((n, n), (n,)) -> (n,)
        ``A^-1 b``; a ``numpy.linalg.LinAlgError`` there is a rejected step (more damping).

    Returns
    -------
    ndarray, shape (n,)
        The last accepted ``x`` (the start if no step lowered the cost).
    """
    r = residuals(x)
    cost = float(r @ r)
    lam = LAMBDA_START
    for _ in range(iterations):
        A, g = normal_equations(x, r)
        D = np.diag(np.maximum(np.diag(A), 1e-12))
        while True:
            try:
                step = -solve(A + lam * D, g)
            except np.linalg.LinAlgError:
                step = np.full_like(x, np.nan)  # rejected below: more damping
            x_new = x + step
            r_new = residuals(x_new) if np.isfinite(step).all() else np.array([np.inf])
            cost_new = float(r_new @ r_new)
            if cost_new < cost:
                lam = max(lam / 10.0, LAMBDA_MIN)
                break
            lam *= 10.0
            if lam > LAMBDA_MAX:
                return x
        gain = cost - cost_new
        x, r, cost = x_new, r_new, cost_new
        if gain < gain_tol * max(cost, 1e-12) or np.all(np.abs(step) < step_tol):
            break
    return x
