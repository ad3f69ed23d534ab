"""Tests of your frame chain, judged by vnav-sim's pytest plugin: installing vnav-sim gives the
``vnav_judge`` fixture (no conftest needed).

``vnav_judge(fn, scenario=..., seed=1)`` judges ``fn`` on a scenario as ``vnav-demo run
--estimator`` does and returns a verdict: ``verdict.passed``, each check's figure against its
limit (``verdict.checks``), the errors (``verdict.errors``), the frame-bug doctor's
``verdict.diagnosis``, and ``verdict.explain()``, what to read when it fails. Each scenario
flies once per pytest session, however many tests judge a function on it.
"""

import pytest
from my_chain import my_estimate

SCENARIOS = ["frame-problem", "transform-composer", "gimbal-lock"]
"""A yaw (chapter 0), a camera sliding on a turning body (chapter 8), a pitch through
90 degrees (chapter 4): between them every rotation and translation of the chain moves."""


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_my_chain_meets_the_accuracy_bound(vnav_judge, scenario):
    verdict = vnav_judge(my_estimate, scenario=scenario)
    assert verdict.passed, verdict.explain()


def test_the_doctor_finds_the_lectures_chain(vnav_judge):
    verdict = vnav_judge(my_estimate, scenario="transform-composer")
    assert verdict.diagnosis is not None, verdict.explain()
    assert verdict.diagnosis.verdict == "correct", verdict.explain()
