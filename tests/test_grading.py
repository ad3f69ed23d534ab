"""A user's function judged from a test (``scenarios.grading``): the verdict against what
``vnav-demo run --estimator`` reports, the stored run left as it was, and the pytest plugin
(the ``vnav_judge`` fixture, ``--vnav-estimator``) in pytest sessions of its own (pytester, in
this process, so that a flight can be counted)."""

from __future__ import annotations

import json
import textwrap

import numpy as np
import pytest
from helpers import plugin_args
from user_functions import SHARED, TRANSPOSED

from scenarios.cli import main
from scenarios.grading import verdict as grading
from vnav.plugin import reference_estimate

DURATION_S = 2.0
"""frame-problem's first 2 s: a hover then the start of its yaw (from 1 s), enough for the
transposed rotation to be wrong by metres."""

USER_FUNCTIONS = "import numpy as np\n\n\n" + SHARED


@pytest.fixture
def user_file(tmp_path):
    path = tmp_path / "mine.py"
    path.write_text(USER_FUNCTIONS, encoding="utf-8")
    return path


def _untimed(entry: dict) -> dict:
    """A report's ``estimators`` entry without its call times (and its second pass's)."""
    out = {k: v for k, v in entry.items() if k != "time_s"}
    if isinstance(out.get("recovered_mount"), dict):
        out["recovered_mount"] = _untimed(out["recovered_mount"])
    return out


@pytest.fixture(scope="session")
def judge() -> grading.Judge:
    """One judge for the tests here: frame-problem flown once for them all (per process)."""
    return grading.Judge()


def _cli_report(tmp_path, spec: str) -> tuple[int, dict]:
    out = tmp_path / "out"
    args = ["run", "frame-problem", "--duration", str(DURATION_S), "--out", str(out), "--quiet"]
    status = main([*args, "--estimator", spec])
    return status, json.loads((out / "frame-problem.json").read_text())


@pytest.mark.parametrize("function", ["transposed", "raises", "nothing", "reference"])
def test_a_verdict_is_what_vnav_demo_run_reports(tmp_path, user_file, judge, function):
    """Same checks (outcomes, figures, words), same statistics of the function's errors, same
    failures and diagnosis, same pass or fail as the run's report and exit status."""
    spec = (
        "vnav.plugin:reference_estimate" if function == "reference" else f"{user_file}:{function}"
    )
    verdict = judge(spec, "frame-problem", seed=1, duration_s=DURATION_S)
    status, report = _cli_report(tmp_path, spec)
    name = verdict.function
    assert verdict.passed == report["passed"] == (status == 0)
    assert verdict.report["checks"] == report["checks"]
    shown = [(c["name"], c["outcome"], c["shown"]) for c in report["checks"]]
    assert [(c.name, c.outcome.value, c.shown) for c in verdict.checks] == shown
    assert verdict.report["methods"][name] == report["methods"][name]
    assert _untimed(verdict.report["estimators"][name]) == _untimed(report["estimators"][name])
    # Call times are the machine's: the same calls were timed, not to the same seconds.
    assert (
        verdict.report["estimators"][name]["time_s"]["calls"]
        == report["estimators"][name]["time_s"]["calls"]
    )
    errors = report["methods"][name]["position_error_m"]
    assert len(verdict.errors) == errors["count"]
    if errors["count"]:
        assert round(verdict.max_error_m, 9) == errors["max"]
    assert verdict.passed == (function == "reference")


def test_a_calibrated_runs_verdict_is_what_vnav_demo_run_reports(tmp_path, user_file):
    """A scenario that checks its calibration estimates every tick again with the recovered
    mount, calling the function there too: the same calls, failures, diagnosis, statistics
    after calibration and checks as the run's report (its first 4 s, enough to calibrate)."""
    spec = f"{user_file}:transposed"
    verdict = grading.Judge()(spec, "calibration", duration_s=4.0)
    out = tmp_path / "out"
    args = ["run", "calibration", "--duration", "4", "--out", str(out), "--quiet"]
    assert main([*args, "--estimator", spec]) == 1
    report = json.loads((out / "calibration.json").read_text())
    assert report["calibration"]["position_error_m"]["recovered_mount"]["user:transposed"]
    for key in ("passed", "checks", "methods", "calibration"):
        assert verdict.report[key] == report[key], key
    (name,) = report["estimators"]
    assert _untimed(verdict.report["estimators"][name]) == _untimed(report["estimators"][name])
    assert not verdict.passed


def test_the_reference_passes_where_the_inputs_are_noisy(tmp_path):
    """uncertainty's pose noise puts depth_image beyond its bound against the truth, and the
    scenario does not hold it there: the reference solution, given depth_image's estimate, is
    held to the correct chain on its inputs only, and passes, as in the run's report."""
    spec = "vnav.plugin:reference_estimate"
    verdict = grading.Judge()(spec, "uncertainty", duration_s=DURATION_S)
    out = tmp_path / "out"
    args = ["run", "uncertainty", "--duration", str(DURATION_S), "--out", str(out), "--quiet"]
    assert main([*args, "--estimator", spec]) == 0
    report = json.loads((out / "uncertainty.json").read_text())
    assert verdict.report["checks"] == report["checks"] and verdict.passed
    assert [c.kind for c in verdict.own_checks] == ["chain_agreement"]
    assert verdict.check.value < 1e-9  # the chain's own estimate, to rounding
    assert max(e.chain_m for e in verdict.errors) < 1e-9
    assert verdict.worst.ratio > 1.0  # against the truth it misses the bound, as depth_image
    assert "not a check here" in verdict.explain()


def test_judging_leaves_the_stored_run_as_it_was(user_file, judge):
    """Judged twice, a function gets the same verdict; the stored run holds no estimate of it,
    and an estimate of one function never shows in another's verdict."""
    spec = f"{user_file}:transposed"
    first = judge(spec, "frame-problem", duration_s=DURATION_S)
    judge("vnav.plugin:reference_estimate", "frame-problem", duration_s=DURATION_S)
    again = judge(spec, "frame-problem", duration_s=DURATION_S)
    assert first == again
    stored = judge.cache.get("frame-problem", 1, DURATION_S)
    names = {m for t in stored.result.ticks for d in t.detections for m in d.estimates_w}
    assert not any(n.startswith("user:") for n in names)
    assert "user:reference_estimate" not in first.report["methods"]


def test_the_worst_error_is_the_truths_distance_at_its_time(judge):
    """The verdict's errors, checked against the truth independently: a function that adds a
    known offset to the reference gives errors within that offset of the reference's, and the
    worst is the largest ratio to the bound over the contract's domain."""
    offset_w = np.array([0.0, 0.03, 0.04])  # 5 cm

    def shifted(obs):
        return reference_estimate(obs) + offset_w

    ref = judge(reference_estimate, "frame-problem", duration_s=DURATION_S)
    moved = judge(shifted, "frame-problem", duration_s=DURATION_S)
    a = np.array([e.error_m for e in ref.errors])
    b = np.array([e.error_m for e in moved.errors])
    assert a.size == b.size > 0
    assert np.all(np.abs(b - a) <= 0.05 + 1e-12)
    worst = moved.worst
    assert worst.ratio == max(e.error_m / e.allowed_m for e in moved.errors if e.in_contract)
    assert f"at t = {worst.t_s:.3f} s" in moved.explain()


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda j: j(3), "fn must be a function"),
        (lambda j: j("no_such_module_here:fn"), "does not import"),
        (lambda j: j(reference_estimate, "no-such-scenario"), "unknown scenario"),
        (lambda j: j(reference_estimate, seed=-1), "seed must be an integer"),
        (lambda j: j(reference_estimate, duration_s=0.0), "duration_s must be a positive"),
    ],
)
def test_bad_input_is_a_value_error_before_anything_flies(call, message):
    judge = grading.Judge()
    with pytest.raises(ValueError, match=message):
        call(judge)
    assert judge.flights == 0


# ------------------------------------------------------------------------- the plugin

INNER_TESTS = (
    textwrap.dedent(f"""\
    import numpy as np
    import pytest

    from vnav.plugin import reference_estimate

    DURATION_S = {DURATION_S}


""")
    + TRANSPOSED
    + textwrap.dedent("""\


    def test_the_reference_passes(vnav_judge):
        verdict = vnav_judge(reference_estimate, "frame-problem", duration_s=DURATION_S)
        assert verdict.passed, verdict.explain()


    def test_a_transposed_rotation(vnav_judge):
        verdict = vnav_judge(transposed, scenario="frame-problem", duration_s=DURATION_S)
        assert verdict.passed, verdict.explain()


    @pytest.mark.parametrize("k", range(8))
    def test_offsets(vnav_judge, k):
        def offset(obs):
            return reference_estimate(obs) + np.array([0.0, 0.0, 0.001 * k])

        verdict = vnav_judge(offset, "frame-problem", seed=1, duration_s=DURATION_S)
        assert verdict.passed, verdict.explain()
""")
)


@pytest.fixture
def flights(monkeypatch) -> list:
    """Every flight the plugin runs in this process, counted at the simulator's loop."""
    flown = []
    run_scenario = grading.run_scenario

    def counted(spec, **kwargs):
        flown.append((spec.name, kwargs.get("seed")))
        return run_scenario(spec, **kwargs)

    monkeypatch.setattr(grading, "run_scenario", counted)
    return flown


def test_ten_functions_one_flight_and_the_doctor_in_the_failure(pytester, flights):
    """Ten functions judged in one session: one flight. The reference and small offsets pass;
    the transposed rotation fails, its report naming the doctor's mistake and chapter."""
    pytester.makepyfile(test_inner=INNER_TESTS)
    result = pytester.runpytest_inprocess(*plugin_args(), "-p", "no:cacheprovider")
    result.assert_outcomes(passed=9, failed=1)
    assert flights == [("frame-problem", 1)]
    result.stdout.fnmatch_lines(["*FAILED test_inner.py::test_a_transposed_rotation*"])
    output = " ".join(result.stdout.str().split())
    assert "Mistake: rotation transposed (MIT 16.485 VNAV, lecture 1, chapters 2 and 3)" in output
    assert "FAILED user:transposed every error <= max(5 cm, 1% of range)" in output


def test_vnav_estimator_adds_one_test_per_builtin_with_detections(pytester, builtin_runs):
    """One test per SPEC and built-in whose run detected a cone (every built-in's run in the
    session's ``builtin_runs``), named by both; collecting flies nothing."""
    with_detections = [
        name for name, r in builtin_runs.items() if any(t.detections for t in r.result.ticks)
    ]
    specs = ["vnav.plugin:reference_estimate", "mine.py:transposed"]
    pytester.makepyfile(mine=USER_FUNCTIONS)
    args = [a for s in specs for a in ("--vnav-estimator", s)]
    result = pytester.runpytest_inprocess(*plugin_args(), *args, "--collect-only", "-q")
    assert result.ret == pytest.ExitCode.OK
    collected = [line for line in result.stdout.lines if line.startswith("vnav-estimator::")]
    assert collected == [f"vnav-estimator::{s}[{n}]" for s in specs for n in with_detections]


def test_vnav_estimator_tests_fail_with_the_explanation(pytester, flights):
    """Two SPECs on frame-problem (``-k``, shortened): the reference passes, the transposed
    rotation fails with the verdict's explanation (the doctor's finding, the worst error);
    one flight for both."""
    pytester.makepyfile(mine=USER_FUNCTIONS)
    result = pytester.runpytest_inprocess(
        *plugin_args(),
        "--vnav-estimator=vnav.plugin:reference_estimate",
        "--vnav-estimator=mine.py:transposed",
        "--vnav-duration",
        str(DURATION_S),
        "-k",
        "frame-problem",
        "-p",
        "no:cacheprovider",
    )
    # Each SPEC's test on every other built-in with a cone is deselected.
    others = len(grading.judged_builtins()) - 1
    result.assert_outcomes(passed=1, failed=1, deselected=2 * others)
    assert flights == [("frame-problem", 1)]
    result.stdout.fnmatch_lines(
        [
            "*mine.py:transposed on frame-problem*",
            "user:transposed on frame-problem (seed 1, 2 s): FAILED",
            "*FAILED*user:transposed every estimate within * of the correct chain's*",
            "*FAILED*user:transposed every error <= *",
            "farthest from the correct chain: * at t = *",
            "worst error against the truth: * at t = *",
            "frame-bug doctor: Mistake: rotation transposed*",
            "FAILED vnav-estimator::mine.py:transposed[[]frame-problem[]]*",
        ]
    )


def test_a_vnav_estimator_that_does_not_load_is_a_usage_error(pytester, flights):
    result = pytester.runpytest_inprocess(*plugin_args(), "--vnav-estimator", "nowhere_here:fn")
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines(["*--vnav-estimator: estimator 'nowhere_here:fn'*not import*"])
    assert flights == []
