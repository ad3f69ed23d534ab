"""The report's NEES section (``scenarios.judge.report.nees_summary``) and the ``consistent`` check
on runs built by hand from Gaussian errors of known covariance.

Each matched estimate is the true cone plus an error drawn from a covariance ``C``; the
record declares ``C``, ``C / 4`` (overconfident) or ``4 C`` (underconfident) and carries the
NEES ``e^T C_declared^+ e`` computed here with numpy, with the covariance's rank as its
degrees of freedom, as ``scenarios.run.evaluate`` records them. When the declared covariance is
the true one, the sum of ``n`` NEES values is chi-square with the sum of their degrees of
freedom (Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4.2): the reference figures are numpy's
and SciPy's.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math

import numpy as np
import pytest
from helpers import REFERENCE_SEED
from scipy.stats import chi2

from scenarios.judge import checks, report
from scenarios.run.records import DetectionRecord, RunResult, TickRecord
from scenarios.scenario import builtin, check_kinds
from scenarios.scenario.spec import from_dict
from vnav.detect import ConeDetection
from vnav.methods import METHOD_NAMES
from vnav.uncertainty import nees

N = 300
"""Matched estimates per method in the hand-made runs."""

PER_TICK = 50
"""Detections per camera tick (the run's NEES is gathered across ticks)."""

CONE_W = np.array([2.0, 1.0, 0.0])
"""The true cone: ``frame-problem``'s only one (the spec the report is built with)."""

# A full 3-dof covariance, elongated along a tilted axis (depth-like), and a ground-plane one,
# exact in z (rank 2), as ``point_from_ground`` gives.
_Q, _ = np.linalg.qr(np.array([[1.0, 0.3, -0.2], [0.2, 1.0, 0.4], [-0.5, 0.1, 1.0]]))
COV_3 = _Q @ np.diag([0.30, 0.05, 0.02]) ** 2 @ _Q.T
COV_2 = np.array([[0.04, 0.012, 0.0], [0.012, 0.01, 0.0], [0.0, 0.0, 0.0]])


def _draw(rng: np.random.Generator, cov: np.ndarray, n: int) -> np.ndarray:
    """``n`` errors ``~ N(0, cov)``, (n, 3): Cholesky of the nonzero block, exact zeros in z
    for the ground-plane covariance."""
    k = 3 if cov[2, 2] > 0.0 else 2
    e = np.zeros((n, 3))
    e[:, :k] = rng.standard_normal((n, k)) @ np.linalg.cholesky(cov[:k, :k]).T
    return e


def _numpy_nees(e: np.ndarray, cov: np.ndarray) -> tuple[float, int]:
    """``e^T cov^+ e`` with numpy's pseudo-inverse, and the covariance's rank."""
    pinv = np.linalg.pinv(cov, rcond=1e-9, hermitian=True)
    return float(e @ pinv @ e), int(np.linalg.matrix_rank(cov, hermitian=True))


_BLOB = ConeDetection(
    bbox=(10, 10, 2, 2),
    area_px=4,
    mask=np.ones((2, 2), dtype=bool),
    apex_uv=np.array([10.5, 10.0]),
    base_uv=np.array([10.5, 11.5]),
    centroid_uv=np.array([10.5, 10.5]),
    touches_border=False,
    apex_from_edges=False,
)


def _matched(method: str, e: np.ndarray, cov_declared: np.ndarray | None) -> DetectionRecord:
    """A detection matched to the cone with ``method``'s estimate ``CONE_W + e``; with a
    declared covariance it carries the NEES, without one none (as a method with no
    covariance would)."""
    p = CONE_W + e
    extra = {}
    if cov_declared is not None:
        extra = {
            "covariances_w": {method: cov_declared},
            "nees": {method: _numpy_nees(e, cov_declared)},
        }
    return DetectionRecord(
        _BLOB,
        {method: p},
        cone_index=0,
        errors_m={method: float(np.linalg.norm(e))},
        range_m=10.0,
        p_c_true=np.array([0.0, 0.0, 10.0]),
        **extra,
    )


@functools.cache
def _spec():
    """``frame-problem``'s spec, parsed once; its one cone is ``CONE_W``."""
    spec = from_dict(builtin.REGISTRY["frame-problem"]())
    assert np.array_equal(np.array(spec.scene.cones_w[0]), CONE_W)
    return spec


def _run(detections: list[DetectionRecord]) -> RunResult:
    """The detections spread over camera ticks of ``PER_TICK``, with ``frame-problem``'s spec
    (its one cone is ``CONE_W``) so that ``report.build`` can be called on the run."""
    spec = _spec()
    T = np.eye(4)
    chunks = [detections[i : i + PER_TICK] for i in range(0, len(detections), PER_TICK)] or [[]]
    ticks = [
        TickRecord(
            tick=k,
            t_s=0.1 * k,
            T_w_b=T,
            T_w_b_est=T,
            T_b_c=T,
            T_b_c_est=T,
            quat_xyzw=np.array([0.0, 0.0, 0.0, 1.0]),
            rpy_rad=np.zeros(3),
            gimbal_locked=False,
            cones_in_view=[0],
            detections=chunk,
        )
        for k, chunk in enumerate(chunks)
    ]
    return RunResult(spec=spec, seed=0, ticks=ticks)


def _hand_made(scale: float) -> tuple[RunResult, dict[str, list[tuple[float, int]]]]:
    """A run whose errors are drawn from ``COV_3`` / ``COV_2`` and whose declared covariances
    are ``scale`` times those, with the NEES values per method as built.

    ``depth_image``: 3 dof; ``ground_plane``: 2 dof; ``known_height``: 200 of 3 dof and 100
    of 2 (mean 8/3); ``naive``: matched estimates without covariance, so no NEES. An unmatched
    detection, which has no error and so no NEES, is added to each tick's end.
    """
    rng = np.random.default_rng(REFERENCE_SEED)
    plan = {
        "depth_image": [(COV_3, N)],
        "ground_plane": [(COV_2, N)],
        "known_height": [(COV_3, 2 * N // 3), (COV_2, N // 3)],
    }
    detections, values = [], {}
    for method, parts in plan.items():
        values[method] = []
        for cov, n in parts:
            for e in _draw(rng, cov, n):
                d = _matched(method, e, scale * cov)
                detections.append(d)
                values[method].append(d.nees[method])
    detections += [_matched("naive", e, None) for e in _draw(rng, COV_3, 40)]
    detections.append(DetectionRecord(_BLOB, {"depth_image": CONE_W + 9.0}))
    return _run(detections), values


@pytest.fixture(scope="module")
def honest():
    """Declared covariances equal to those the errors are drawn from."""
    return _hand_made(1.0)


# --------------------------------------------------------------------- the summary's figures


def test_hand_made_nees_is_what_the_pipeline_computes(honest) -> None:
    """The records' NEES (numpy's pseudo-inverse and rank) equal ``vnav.uncertainty.nees`` of
    the estimate's error against its covariance, which is what ``scenarios.run.evaluate``
    records: the hand-made runs are built like real ones."""
    run, _ = honest
    for d in (d for t in run.ticks for d in t.detections):
        for method, (value, dof) in d.nees.items():
            got = nees(d.estimates_w[method] - CONE_W, d.covariances_w[method])
            assert got[0] == pytest.approx(value, rel=1e-9) and got[1] == dof


@pytest.mark.parametrize("method", ["depth_image", "ground_plane", "known_height"])
def test_summary_count_mean_and_dof_are_numpys(honest, method: str) -> None:
    """count, mean and mean degrees of freedom against numpy on the values the run was built
    with (unmatched detections and other methods left out); the report rounds the mean to 9
    decimals and the dof to 6, hence the absolute tolerances."""
    run, values = honest
    v = np.array([x for x, _ in values[method]])
    dofs = np.array([k for _, k in values[method]])
    summary = report.nees_summary(run, method)
    assert summary["count"] == v.size == N
    assert summary["mean"] == pytest.approx(np.mean(v), abs=1e-9)
    assert summary["dof"] == pytest.approx(np.mean(dofs), abs=1e-6)
    # By construction: 3, 2, and (200 * 3 + 100 * 2) / 300 for the mixed method.
    expected_dof = {"depth_image": 3.0, "ground_plane": 2.0, "known_height": 8.0 / 3.0}
    assert summary["dof"] == pytest.approx(expected_dof[method], abs=1e-6)


@pytest.mark.parametrize("method", ["depth_image", "ground_plane", "known_height"])
def test_band_is_the_chi_square_interval_of_the_mean(honest, method: str) -> None:
    """The band of the mean NEES is ``chi2.ppf([0.025, 0.975], k) / n`` with ``k`` the sum of
    the degrees of freedom: within 0.5% (``nees_band``'s stated Wilson-Hilferty accuracy from
    6 degrees of freedom in all; here k >= 600), and it holds the expected mean, the dof."""
    run, values = honest
    k = sum(dof for _, dof in values[method])
    summary = report.nees_summary(run, method)
    expected = chi2.ppf([0.025, 0.975], k) / N
    assert summary["band"] == pytest.approx(expected, rel=5e-3)
    low, high = summary["band"]
    assert low < summary["dof"] < high


# ----------------------------------------------------------------------- consistent or not


def _scipy_verdict(values: list[tuple[float, int]]) -> tuple[bool, float]:
    """Whether the sum of the NEES values lies in chi-square(k)'s central 95%, and the
    two-sided probability ``2 min(F, 1 - F)``, exact (SciPy)."""
    total = sum(v for v, _ in values)
    k = sum(dof for _, dof in values)
    F = float(chi2.cdf(total, k))
    low, high = chi2.ppf([0.025, 0.975], k)
    return bool(low <= total <= high), 2.0 * min(F, 1.0 - F)


@pytest.mark.parametrize(
    ("scale", "expected"),
    [(1.0, True), (0.25, False), (4.0, False)],
    ids=["declared-right", "declared-4x-too-small", "declared-4x-too-large"],
)
@pytest.mark.parametrize("method", ["depth_image", "ground_plane", "known_height"])
def test_consistent_only_when_the_declared_covariance_is_right(
    method: str, scale: float, expected: bool
) -> None:
    """Errors drawn from ``C`` and declared with ``C``: the mean NEES is in its 95% band; with
    ``C / 4`` the NEES are 4 times too large (mean ~ 4 dof), with ``4 C`` 4 times too small,
    both far outside a band of about +-11% at 300 samples. The summary's verdict equals
    SciPy's on the exact chi-square quantiles, and the ``consistent`` check (limit 0.05)
    passes exactly when the summary says consistent, its figure the exact two-sided
    probability: the Wilson-Hilferty CDF is within 2.2e-3 of the exact one at k = 6 and its
    error falls roughly as 1/k (under 2e-5 from k = 600), so 1e-3 holds it with room."""
    run, values = _hand_made(scale)
    summary = report.nees_summary(run, method)
    in_band, p_exact = _scipy_verdict(values[method])
    assert summary["consistent"] is expected is in_band
    result = checks.judge(check_kinds.Check("consistent", 0.05, method), run)
    assert result.value == pytest.approx(p_exact, abs=1e-3)
    assert result.passed is expected
    assert result.outcome is (checks.Outcome.PASSED if expected else checks.Outcome.FAILED)


def test_band_holds_95_percent_of_honest_runs() -> None:
    """Over 2000 independent runs of 20 honest 3-dof estimates (k = 60), the share whose mean
    NEES lies in the band is 0.95 within 5 binomial standard errors
    (``sqrt(0.95 * 0.05 / 2000)`` = 0.0049; Wilson-Hilferty's CDF error at k = 60, 2e-4, is
    far below). The check's verdict (p >= 0.05) agrees with the summary's on every run."""
    rng = np.random.default_rng(REFERENCE_SEED + 1)
    runs, n = 2000, 20
    inside = 0
    for _ in range(runs):
        run = _run([_matched("depth_image", e, COV_3) for e in _draw(rng, COV_3, n)])
        consistent = report.nees_summary(run, "depth_image")["consistent"]
        inside += consistent
        assert checks.judge(check_kinds.Check("consistent", 0.05), run).passed is consistent
    sigma = math.sqrt(0.95 * 0.05 / runs)
    assert inside / runs == pytest.approx(0.95, abs=5 * sigma)


# ------------------------------------------------------------------- nothing to judge, inf


def test_a_method_without_nees_has_count_zero_and_nulls(honest) -> None:
    """``naive`` has matched estimates but no covariance: the summary has count 0 and every
    statistic null ("statistics of an empty series are null", the report's docstring), the
    ``consistent`` check has no data (which fails a run), and the report, built and written as
    JSON, holds the same summary for every method as ``nees_summary``."""
    run, _ = honest
    empty = {"count": 0, "mean": None, "dof": None, "band": None, "consistent": None}
    assert report.nees_summary(run, "naive") == empty
    result = checks.judge(check_kinds.Check("consistent", 0.05, "naive"), run)
    assert result.value is None and result.outcome is checks.Outcome.NO_DATA
    assert result.outcome.fails_run
    rep = json.loads(report.dumps(report.build(run, [result])))
    for method in METHOD_NAMES:
        assert rep["methods"][method]["nees"] == report.nees_summary(run, method)
    assert rep["passed"] is False


def test_a_run_without_detections_reports_no_nees() -> None:
    """A run that saw nothing: every method's summary is empty, without an error, and the
    report serialises (no NaN)."""
    run = _run([])
    rep = json.loads(report.dumps(report.build(run, [])))
    for method in METHOD_NAMES:
        assert rep["methods"][method]["nees"]["count"] == 0
        assert rep["methods"][method]["nees"]["mean"] is None


def test_an_error_outside_a_ground_plane_covariance_is_inconsistent() -> None:
    """An error with a z component against a covariance exact in z is impossible under it:
    NEES = inf (``vnav.uncertainty.nees``). One such estimate among honest ones makes the
    method inconsistent: counted, the mean infinite (null in JSON, which has no inf), the
    check's probability 0."""
    rng = np.random.default_rng(REFERENCE_SEED + 2)
    detections = [_matched("ground_plane", e, COV_2) for e in _draw(rng, COV_2, 50)]
    bad_e = np.array([0.01, 0.0, 0.05])
    bad = _matched("ground_plane", bad_e, COV_2)
    bad = dataclasses.replace(bad, nees={"ground_plane": nees(bad_e, COV_2)})
    assert math.isinf(bad.nees["ground_plane"][0])
    run = _run([*detections, bad])
    summary = report.nees_summary(run, "ground_plane")
    assert summary["count"] == 51 and summary["consistent"] is False
    assert summary["mean"] is None
    result = checks.judge(check_kinds.Check("consistent", 0.05, "ground_plane"), run)
    assert result.value == 0.0 and not result.passed
    json.loads(report.dumps(report.build(run, [result])))
