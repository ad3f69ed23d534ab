"""scenarios.report: a built-in run's report against its records and the scene's truth (the
errors recomputed from the estimates and the true cones, per method and per range bin)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scenarios import builtin
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
