"""``vnav.least_squares.levenberg_marquardt`` against SciPy's Levenberg-Marquardt (MINPACK's
``lmder``, a test-only oracle) on a curve fit, and its handling of a solve that fails."""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from vnav.least_squares import levenberg_marquardt

T = np.linspace(0.0, 4.0, 40)
TRUE = np.array([2.5, 1.3, 0.5])


def _model(x: np.ndarray) -> np.ndarray:
    return x[0] * np.exp(-x[1] * T) + x[2]


DATA = _model(TRUE) + 0.01 * np.random.default_rng(3).standard_normal(T.size)


def _residuals(x: np.ndarray) -> np.ndarray:
    return _model(x) - DATA


def _jacobian(x: np.ndarray) -> np.ndarray:
    e = np.exp(-x[1] * T)
    return np.column_stack([e, -x[0] * T * e, np.ones_like(T)])


def _normal_equations(x: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    J = _jacobian(x)
    return J.T @ J, J.T @ r


def test_the_minimum_is_scipys():
    """From a start far off (every parameter off by 60-300%), the same minimum as SciPy's
    ``least_squares(method="lm")`` to 1e-8, and the data's own parameters within the noise."""
    x0 = np.array([1.0, 0.3, 2.0])
    ours = levenberg_marquardt(
        _residuals, _normal_equations, x0, iterations=100, gain_tol=1e-15, step_tol=1e-14
    )
    scipys = least_squares(_residuals, x0, jac=_jacobian, method="lm", xtol=1e-15, ftol=1e-15).x
    np.testing.assert_allclose(ours, scipys, rtol=0, atol=1e-8)
    np.testing.assert_allclose(ours, TRUE, rtol=0, atol=0.05)


def test_a_solve_that_fails_is_a_rejected_step():
    """A solve raising ``LinAlgError`` (its first three calls) is taken as a step that does
    not lower the cost: the damping grows and the fit goes on to SciPy's minimum."""
    x0 = np.array([1.0, 0.3, 2.0])
    calls = [0]

    def solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
        calls[0] += 1
        if calls[0] <= 3:
            raise np.linalg.LinAlgError("refused")
        return np.linalg.solve(A, b)

    ours = levenberg_marquardt(
        _residuals,
        _normal_equations,
        x0,
        iterations=200,
        gain_tol=1e-15,
        step_tol=1e-14,
        solve=solve,
    )
    scipys = least_squares(_residuals, x0, jac=_jacobian, method="lm", xtol=1e-15, ftol=1e-15).x
    assert calls[0] > 3
    np.testing.assert_allclose(ours, scipys, rtol=0, atol=1e-8)


def test_a_start_no_step_improves_is_returned_as_it_is():
    """Residuals that are zero at the start (``x - c`` from ``c``): no step lowers the cost,
    the damping grows past its ceiling and the start comes back unchanged."""
    c = np.array([0.1, -2.0, 3.0])
    out = levenberg_marquardt(
        lambda x: x - c, lambda x, r: (np.eye(3), r), c.copy(), iterations=5, gain_tol=0.0
    )
    assert np.array_equal(out, c)
