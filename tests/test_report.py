"""scenarios.judge.report: a built-in run's report against its records and the scene's truth (the
errors recomputed from the estimates and the true cones, per method and per range bin)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from scenarios.scenario import builtin
from vnav.methods import METHOD_NAMES


@pytest.mark.parametrize("name", builtin.names())
def test_report_errors_are_distances_to_the_true_cone(runs, name):
    """Recompute every error from the estimates and the scene's cone list (the truth)."""
    spec, result, _, rep = runs[name]
    cones_w = np.array(spec.scene.cones_w)
    for method in METHOD_NAMES:
        errors = []
        for f in result.ticks:
            for d in f.detections:
                if d.cone_index is not None and method in d.estimates_w:
                    errors.append(np.linalg.norm(d.estimates_w[method] - cones_w[d.cone_index]))
        stats = rep["methods"][method]["position_error_m"]
        assert stats["count"] == len(errors)
        if errors:
            assert stats["max"] == pytest.approx(max(errors), abs=1e-8)
            assert stats["rmse"] == pytest.approx(np.sqrt(np.mean(np.square(errors))), abs=1e-8)


@pytest.mark.parametrize("name", builtin.names())
def test_error_against_range_bins_partition_the_detections(runs, name):
    spec, result, _, rep = runs[name]
    cones_w = np.array(spec.scene.cones_w)
    for method in METHOD_NAMES:
        bins = rep["methods"][method]["by_range"]
        assert (
            sum(b["position_error_m"]["count"] for b in bins)
            == (rep["methods"][method]["position_error_m"]["count"])
        )
        for b in bins:
            lo, hi = b["range_m"]
            hi = math.inf if hi is None else hi
            # Recompute this bin from the frames: range from the camera to the true cone.
            errors = [
                np.linalg.norm(d.estimates_w[method] - cones_w[d.cone_index])
                for f in result.ticks
                for d in f.detections
                if d.cone_index is not None
                and method in d.estimates_w
                and lo <= np.linalg.norm(d.p_c_true) < hi
            ]
            assert len(errors) == b["position_error_m"]["count"]
            assert max(errors) == pytest.approx(b["position_error_m"]["max"], abs=1e-8)


@pytest.mark.parametrize("name", builtin.names())
def test_every_matched_detection_has_an_estimate_or_a_reason(runs, name):
    """Per method, the matched detections with an estimate (the error count) and those
    without, counted by reason (``no_estimate``), add up to the matched detections."""
    _, result, _, rep = runs[name]
    matched = [d for f in result.ticks for d in f.detections if d.cone_index is not None]
    assert rep["matched_detections"] == len(matched)
    for method in METHOD_NAMES:
        entry = rep["methods"][method]
        assert entry["position_error_m"]["count"] + sum(entry["no_estimate"].values()) == len(
            matched
        ), method
        with_reason = [d for d in matched if method in d.no_estimate]
        assert not [d for d in with_reason if method in d.estimates_w]
        assert set(entry["no_estimate"]) == {d.no_estimate[method].value for d in with_reason}


def test_check_outcomes_decide_whether_the_report_passed(runs):
    """``passed`` is false exactly when a check failed or had no data; a skipped check does
    not fail the run."""
    from scenarios.judge import checks, report

    _, result, judged, _ = runs["frame-problem"]
    skipped = dataclasses.replace(judged[0], outcome=checks.Outcome.SKIPPED)
    no_data = dataclasses.replace(judged[0], outcome=checks.Outcome.NO_DATA)
    assert report.build(result, judged)["passed"] is True
    assert report.build(result, [skipped, *judged[1:]])["passed"] is True
    assert report.build(result, [no_data, *judged[1:]])["passed"] is False
    assert report.build(result, [no_data])["checks"][0]["outcome"] == "no data"


@pytest.mark.parametrize("name", builtin.names())
def test_report_nees_is_recomputed_from_the_estimates_covariances_and_the_truth(runs, name):
    """Each method's NEES summary against a recomputation: ``e^T C^+ e`` with numpy's
    pseudo-inverse over matched estimates, ``e`` the error against the scene's cone and the
    degrees of freedom the covariance's rank; the band against SciPy's chi-square quantiles
    (Wilson-Hilferty, 1%); ``consistent`` the mean inside it."""
    from scipy.stats import chi2

    spec, result, _, rep = runs[name]
    cones_w = np.array(spec.scene.cones_w)
    for method in METHOD_NAMES:
        values, dofs = [], []
        for f in result.ticks:
            for d in f.detections:
                if d.cone_index is None or method not in d.covariances_w:
                    continue
                cov = d.covariances_w[method]
                e = d.estimates_w[method] - cones_w[d.cone_index]
                values.append(float(e @ np.linalg.pinv(cov, rcond=1e-9, hermitian=True) @ e))
                dofs.append(np.linalg.matrix_rank(cov, tol=1e-9 * np.abs(cov).max()))
        summary = rep["methods"][method]["nees"]
        assert summary["count"] == len(values)
        if not values:
            assert summary["mean"] is None and summary["consistent"] is None
            continue
        assert summary["mean"] == pytest.approx(np.mean(values), rel=1e-6)
        assert summary["dof"] == pytest.approx(np.mean(dofs))
        k = summary["dof"] * len(values)
        expected_band = chi2.ppf([0.025, 0.975], k) / len(values)
        assert summary["band"] == pytest.approx(expected_band, rel=0.01)
        low, high = summary["band"]
        assert summary["consistent"] == (low <= summary["mean"] <= high)


def test_run_table_gives_the_estimates_with_the_recovered_mount(runs):
    """``vnav-demo run``'s table of a calibrated run: after each method's row with the
    declared mount, the rows of the same images estimated again with the recovered mount,
    with the report's figures; a run not calibrated has no such rows."""
    from pathlib import Path

    from scenarios.commands.run import summary

    _, _, _, rep = runs["calibration"]
    lines = summary(rep, Path("c.rrd"), Path("c.json")).splitlines()
    marker = next(i for i, line in enumerate(lines) if "camera mount calibration recovered" in line)
    rows = {}
    for line in lines[marker:]:
        cells = line.split()
        if cells and cells[0] in METHOD_NAMES and cells[0] not in rows:
            rows[cells[0]] = cells[1:]
    by_mount = rep["calibration"]["position_error_m"]
    for method in METHOD_NAMES:
        s = by_mount["recovered_mount"][method]
        assert rows[method] == [
            str(s["count"]),
            *(f"{s[k]:.3f}" for k in ("mean", "median", "rmse", "max")),
        ], method
    declared = next(line for line in lines if line.split()[:1] == ["depth_image"])
    mean = by_mount["declared_mount"]["depth_image"]["mean"]
    assert declared.split()[2] == f"{mean:.3f}"
    _, _, _, plain = runs["orbit"]
    assert "calibration recovered" not in summary(plain, Path("o.rrd"), Path("o.json"))
