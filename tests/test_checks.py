"""scenarios.judge.checks: the registered check kinds, their figures and verdicts."""

from __future__ import annotations

import dataclasses
import math
import re
from statistics import NormalDist

import numpy as np
import pytest

from scenarios.judge import checks
from scenarios.run.records import (
    CalibrationRecord,
    Contact,
    DetectionRecord,
    ImuCalibrationRecord,
    ImuRecord,
    NavigationRecord,
    RunResult,
    TickRecord,
)
from scenarios.scenario import builtin, check_kinds
from scenarios.scenario.spec import from_dict
from vnav.detect import ConeDetection
from vnav.estimators import NoEstimate, known_height_max_elevation_rad
from vnav.methods import METHODS, extended
from vnav.plugin import function_method, reference_estimate


@pytest.mark.parametrize("kind", sorted(check_kinds.KINDS))
def test_every_registered_check_kind_is_accepted_by_the_parser_and_documented(kind):
    scenario = builtin.REGISTRY["frame-problem"]()
    scenario["checks"] = [{"kind": kind, "limit": 1.0}]
    (check,) = from_dict(scenario).checks
    assert check.kind == kind and check_kinds.KINDS[kind].doc


# ------------------------------------------------------------- each kind on a run by hand


def _detection(
    cone_index,
    errors_m,
    range_m,
    in_contract,
    p_w,
    p_c_true,
    no_estimate=None,
    latest=None,
    nees=None,
):
    mask = np.ones((2, 2), dtype=bool)
    blob = ConeDetection(
        bbox=(10, 10, 2, 2),
        area_px=4,
        mask=mask,
        apex_uv=np.array([10.5, 10.0]),
        base_uv=np.array([10.5, 11.5]),
        centroid_uv=np.array([10.5, 10.5]),
        touches_border=False,
        apex_from_edges=False,
    )
    estimates = {m: np.asarray(p, dtype=np.float64) for m, p in p_w.items()}
    return DetectionRecord(
        blob,
        estimates,
        cone_index,
        errors_m,
        range_m,
        None if p_c_true is None else np.asarray(p_c_true, dtype=np.float64),
        in_contract,
        no_estimate or {},
        # (latest-pose error, its prediction), metres
        latest_error_m=None if latest is None else latest[0],
        predicted_latest_error_m=None if latest is None else latest[1],
        nees=nees or {},
    )


def _tick(k, cones_in_view, detections, gimbal_locked=False, reference_error_m=None):
    T = np.eye(4)
    return TickRecord(
        tick=k,
        t_s=0.1 * k,
        T_w_b=T,
        T_w_b_est=T,
        T_b_c=T,
        T_b_c_est=T,
        quat_xyzw=np.array([0.0, 0.0, 0.0, 1.0]),
        rpy_rad=np.zeros(3),
        gimbal_locked=gimbal_locked,
        cones_in_view=cones_in_view,
        detections=detections,
        reference_error_m=reference_error_m,
    )


def _two_ticks() -> list[TickRecord]:
    """The ticks of ``run``: at tick 0, cone 0 matched at 2 m (in the contract's domain) and
    one detection matched to no cone; at tick 1, gimbal locked, cone 0 matched again at 10 m
    and cone 1 at 30 m, out of the contract's domain (both with their NEES)."""
    return [
        _tick(
            0,
            [0, 1],
            [
                _detection(
                    0,
                    {"depth_image": 0.02, "naive": 3.0},
                    2.0,
                    True,
                    {"depth_image": [1.0, 0.0, 0.0], "naive": [4.0, 0.0, 0.0]},
                    [0.0, 0.0, 5.0],
                    latest=(0.12, 0.1),
                ),
                _detection(None, {}, None, False, {"depth_image": [9.0, 9.0, 0.0]}, None),
            ],
            reference_error_m=0.2,
        ),
        _tick(
            1,
            [0, 1],
            [
                _detection(
                    0,
                    {"depth_image": 0.03, "naive": 5.0},
                    10.0,
                    True,
                    {"depth_image": [1.02, 0.0, 0.0], "naive": [6.0, 0.0, 0.0]},
                    [0.0, 1.0, 5.0],
                    latest=(0.27, 0.3),
                    nees={"depth_image": (2.0, 3)},
                ),
                _detection(
                    1,
                    {"depth_image": 0.5},
                    30.0,
                    False,
                    {"depth_image": [3.0, 3.0, 0.0]},
                    [2.0, 0.0, 30.0],
                    latest=(0.5, 0.0),  # no motion: not judged
                    nees={"depth_image": (4.0, 3)},
                ),
            ],
            gimbal_locked=True,
            reference_error_m=0.7,
        ),
    ]


@pytest.fixture(scope="module")
def run() -> RunResult:
    """Two ticks, two cones: cone 0 seen twice, cone 1 once (out of the contract's domain),
    one unmatched detection."""
    return RunResult(
        spec=None,  # the checks read the ticks (and the calibration, the navigation) only
        seed=0,
        # A navigating flight that touched cone 0 at 4.2 s, 3.5 m short of its goal.
        navigation=NavigationRecord(
            contact=Contact(4.2, 0, np.array([10.0, 0.0, 0.5])),
            min_clearance_m=0.25,
            final_distance_m=3.5,
        ),
        # An IMU whose sensors were at most 3e-15 (relative) from vnav.imu's chain.
        imu=ImuRecord(np.zeros(2), np.zeros((2, 3)), np.zeros((2, 3)), 3e-15, 2),
        calibration=CalibrationRecord(
            np.eye(4),
            0.03,
            0.3,
            10,
            {"rotation_deg": 0.02, "translation_m": 0.004, "time_offset_s": 0.0005},
        ),
        imu_calibration=ImuCalibrationRecord(
            T_i_c=np.eye(4),
            time_offset_s=0.012,
            reprojection_rms_px=0.5,
            frames_used=300,
            errors={"rotation_deg": 0.04, "translation_m": 0.003, "time_offset_s": 0.0002},
        ),
        ticks=_two_ticks(),
    )


# The figure of each kind on `run`, computed by hand.
FIGURES = {
    "max_error": 0.5,  # over every matched detection
    "median_error": 0.03,  # of 0.02, 0.03, 0.5
    # max(0.02 / max(5 cm, 1% of 2 m), 0.03 / max(5 cm, 1% of 10 m)): in the contract only
    "error_bound": 0.4,
    # naive (``METHOD_OF``) against depth_image on the same detection, over depth_image's
    # bound there: cone 0 at 3 m apart at 2 m range (bound 5 cm), 4.98 m apart at 10 m (bound
    # 10 cm); max(60, 49.8). Cone 1 has no naive estimate, the unmatched detection no range.
    "chain_agreement": 3.0 / 0.05,
    "detection_rate": 0.75,  # cone 0 in tick 0; cones 0 and 1 in tick 1; of 2 + 2 in view
    "world_estimate_spread": 0.01,  # cone 0 at x = 1.0 and 1.02 (cone 1 seen once)
    "camera_coords_span": 1.0,  # cone 0's p_c moved 1 m in y
    "naive_worse": 4.0 / 0.03,  # median naive 4.0 over median depth-image 0.03
    "gimbal_lock_seen": 1.0,
    "tracking_error": 0.7,
    "matched_cones": 2.0,
    # |0.12 / 0.1 - 1| = 0.2 and |0.27 / 0.3 - 1| = 0.1; the third had no motion
    "latency_prediction": 0.15,
    # NEES 2 and 4 of 3 dof each: mean 3, sum 6 of chi-square(6). Wilson-Hilferty: the cube
    # root of 6 / 6 is 1, its mean 1 - 2/54, its sd sqrt(2/54), so z = sqrt(2/54) and the
    # two-sided probability 2 (1 - Phi(z)) (SciPy's exact figure, 0.847, in test_uncertainty).
    "consistent": 2.0 * (1.0 - NormalDist().cdf(math.sqrt(2.0 / 54.0))),
    # the run's calibration record, as given
    "calibration_rotation": 0.02,
    "calibration_translation": 0.004,
    "calibration_time_offset": 0.0005,
    # the run's navigation record: its distance from the goal at the end, the one cone it
    # touched (both kinds count it), its smallest true clearance
    "reached_goal": 3.5,
    "no_collision": 1.0,
    "collision": 1.0,
    "min_clearance": 0.25,
    # the run's IMU record, as given
    "imu_consistent": 3e-15,
    # the run's camera-IMU calibration record, as given
    "calibration_imu_rotation": 0.04,
    "calibration_imu_translation": 0.003,
    "calibration_imu_time_offset": 0.0002,
}


METHOD_OF = {"chain_agreement": "naive"}
"""The method a kind's figure is computed for, where the default (depth_image) would judge
nothing: depth_image agrees with itself."""


def test_every_kind_has_a_figure_by_hand() -> None:
    assert set(FIGURES) == set(check_kinds.KINDS)


@pytest.mark.parametrize("kind", sorted(FIGURES))
def test_figure_and_verdict(run: RunResult, kind: str) -> None:
    figure = FIGURES[kind]

    def check(limit: float) -> check_kinds.Check:
        return check_kinds.Check(kind, limit, METHOD_OF.get(kind, "depth_image"))

    result = checks.judge(check(figure), run)
    assert result.value == pytest.approx(figure, rel=1e-12)
    assert checks.judge(check(result.value), run).passed  # at the limit: passes
    le = check_kinds.KINDS[kind].at_most
    stricter = figure * (0.99 if le else 1.01)
    assert not checks.judge(check(stricter), run).passed
    looser = figure * (1.01 if le else 0.99)
    assert checks.judge(check(looser), run).passed


def test_a_check_with_nothing_to_judge_has_no_data_and_fails(run: RunResult) -> None:
    # The naive method has no accuracy bound; no tick of an empty run has errors.
    result = checks.judge(check_kinds.Check("error_bound", 1e9, "naive"), run)
    assert result.value is None and result.outcome is checks.Outcome.NO_DATA
    assert not result.passed and result.outcome.fails_run
    empty = RunResult(spec=None, seed=0, ticks=[_tick(0, [], [])])
    for kind in ("reached_goal", "no_collision", "collision", "min_clearance"):
        result = checks.judge(check_kinds.Check(kind, 1.0), empty)
        assert result.outcome is checks.Outcome.NO_DATA, kind
        assert result.reason == 'the flight does not navigate (flight.mode is not "navigate")'
    result = checks.judge(check_kinds.Check("imu_consistent", 1e-6), empty)
    assert result.outcome is checks.Outcome.NO_DATA
    assert result.reason == "the scenario declares no [imu]"
    for kind in ("max_error", "median_error", "detection_rate", "tracking_error"):
        result = checks.judge(check_kinds.Check(kind, 1e9), empty)
        assert result.value is None and result.outcome is checks.Outcome.NO_DATA, kind
        assert result.reason and result.shown == result.reason
    assert result.as_dict() == {
        "name": "tracking_error",
        "kind": "tracking_error",
        "outcome": "no data",
        "passed": False,
        "value": None,
        "limit": 1e9,
        "unit": "m",
        "shown": "the flight has no reference to track (kinematic keyframes are exact)",
        "reason": "the flight has no reference to track (kinematic keyframes are exact)",
    }
    assert checks.judge(check_kinds.Check("max_error", 1.0), empty).reason == (
        "no cone was detected in any camera image"
    )
    assert (
        "no cone was fully in view"
        in checks.judge(check_kinds.Check("detection_rate", 1), empty).shown
    )


def _steep_run(reason: NoEstimate, in_contract: bool = True) -> RunResult:
    """Three ticks, one cone seen each time; depth_image estimates it, known_height refuses
    every time for ``reason``."""
    ticks = [
        _tick(
            k,
            [0],
            [
                _detection(
                    0,
                    {"depth_image": 0.01},
                    10.0,
                    in_contract,
                    {"depth_image": [1.0, 0.0, 0.0]},
                    [0.0, 0.0, 10.0],
                    {"known_height": reason},
                )
            ],
        )
        for k in range(3)
    ]
    return RunResult(spec=None, seed=0, ticks=ticks)


def test_default_check_skips_a_method_the_geometry_rules_out() -> None:
    """known_height refused every view as too steep: the default bound is skipped (the run is
    not failed for it) and says why; the same check written by a user has no data and fails."""
    run = _steep_run(NoEstimate.STEEP)
    defaults = {c.method: c for c in check_kinds.default_checks() if c.kind == "error_bound"}
    skipped = checks.judge(defaults["known_height"], run)
    assert skipped.outcome is checks.Outcome.SKIPPED and not skipped.outcome.fails_run
    limit_deg = math.degrees(known_height_max_elevation_rad())
    assert skipped.reason == (
        f"no known_height estimates for the 3 detections in the contract's domain: all 3 seen "
        f"steeper than {limit_deg:.0f} deg (the apex over the base plate)"
    )
    written = checks.judge(dataclasses.replace(defaults["known_height"], default=False), run)
    assert written.outcome is checks.Outcome.NO_DATA and written.reason == skipped.reason
    # The other methods are judged as usual.
    assert checks.judge(defaults["depth_image"], run).outcome is checks.Outcome.PASSED


def test_default_check_fails_when_no_data_is_not_the_geometry() -> None:
    run = _steep_run(NoEstimate.NO_APEX)
    (kh,) = [c for c in check_kinds.default_checks() if c.method == "known_height"]
    result = checks.judge(kh, run)
    assert result.outcome is checks.Outcome.NO_DATA and "no apex found" in result.reason
    # Outside the contract's domain nothing is promised: the default bound is skipped.
    result = checks.judge(kh, _steep_run(NoEstimate.NO_APEX, in_contract=False))
    assert result.outcome is checks.Outcome.SKIPPED and "contract's domain" in result.reason


def test_world_spread_without_motion_in_the_camera_has_no_data() -> None:
    """The cone's camera coordinates never moved: a constant world estimate shows nothing
    (the naive estimate would be constant too)."""
    run = _steep_run(NoEstimate.STEEP)
    result = checks.judge(check_kinds.Check("world_estimate_spread", 0.1), run)
    assert result.outcome is checks.Outcome.NO_DATA
    assert "camera coordinates moved 0 m" in result.reason


def _numbers(text: str) -> list[float]:
    return [float(x) for x in re.findall(r"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?", text)]


@pytest.mark.parametrize(
    ("kind", "unit_text"),
    [
        ("max_error", " m (must be <= "),
        ("detection_rate", "% (must be >= "),
        ("naive_worse", "x (must be >= "),
        ("gimbal_lock_seen", " (must be >= "),
        ("matched_cones", " (must be >= "),
        ("imu_consistent", "e-15 (must be <= "),
    ],
)
def test_shown_values_carry_units_next_to_the_limit(run: RunResult, kind: str, unit_text: str):
    result = checks.judge(check_kinds.Check(kind, 0.5), run)
    assert unit_text in result.shown
    value, limit = _numbers(result.shown)
    scale = 100.0 if check_kinds.KINDS[kind].unit is check_kinds.Unit.FRACTION else 1.0
    assert value == pytest.approx(scale * FIGURES[kind], rel=5e-3)
    assert limit == pytest.approx(scale * 0.5)
    if check_kinds.KINDS[kind].unit is check_kinds.Unit.COUNT:
        assert isinstance(result.value, int) and str(result.value) == result.shown.split()[0]


def _bound_run(errors_m: list[float], ranges_m: list[float]) -> RunResult:
    ticks = [
        _tick(
            k, [0], [_detection(0, {"depth_image": e}, r, True, {"depth_image": [0, 0, 0]}, None)]
        )
        for k, (e, r) in enumerate(zip(errors_m, ranges_m, strict=True))
    ]
    return RunResult(spec=None, seed=0, ticks=ticks)


def test_error_bound_shown_in_percent_of_range_or_metres() -> None:
    """depth_image: every error <= max(5 cm, 1% of range), 5 m the crossover."""
    check = check_kinds.Check("error_bound", 1.0, "depth_image")
    far = checks.judge(check, _bound_run([0.02, 0.1], [10.0, 20.0]))
    # Beyond 5 m the bound is 1% of range: the figure is the worst error in % of range.
    assert (
        far.shown
        == f"worst {100 * max(0.02 / 10.0, 0.1 / 20.0):g}% of range (must be <= 1% of range)"
    )
    near = checks.judge(check, _bound_run([0.01, 0.02], [2.0, 3.0]))
    assert near.shown == "worst 0.02 m (must be <= 0.05 m)"  # the floor: metres
    mixed = checks.judge(check, _bound_run([0.02, 0.05], [2.0, 10.0]))
    assert mixed.shown == "worst 50% of the bound (must be <= 100% of the bound)"


def test_check_labels_and_bad_checks() -> None:
    assert check_kinds.Check("max_error", 0.1, "ground_plane").label == "ground_plane max_error"
    assert check_kinds.Check("detection_rate", 0.9).label == "detection_rate"
    assert check_kinds.Check("max_error", 0.1, name="mine").label == "mine"
    with pytest.raises(ValueError, match=r"unknown check 'min_error'; valid: \["):
        check_kinds.Check("min_error", 0.1)
    with pytest.raises(ValueError, match=r"unknown method 'lidar'"):
        check_kinds.Check("max_error", 0.1, "lidar")


def test_default_checks_are_every_bound_and_the_detection_rate() -> None:
    defaults = check_kinds.default_checks()
    bounds = [c for c in defaults if c.kind == "error_bound"]
    assert [c.method for c in bounds] == [m.name for m in METHODS if m.bound is not None]
    assert all(c.limit == 1.0 for c in bounds)
    (rate,) = [c for c in defaults if c.kind == "detection_rate"]
    assert rate.limit == 0.95
    assert all(c.default for c in defaults)


def test_calibration_checks_without_a_calibration_have_no_data() -> None:
    """A run not calibrated, and one whose flight was refused: no data, with the reason."""
    plain = RunResult(spec=None, seed=0, ticks=[_tick(0, [], [])])
    result = checks.judge(check_kinds.Check("calibration_rotation", 0.05), plain)
    assert result.outcome is checks.Outcome.NO_DATA and "not calibrated" in result.reason
    refused = RunResult(
        spec=None,
        seed=0,
        ticks=[_tick(0, [], [])],
        calibration=CalibrationRecord(None, None, None, 0, {}, refused="too few cones seen"),
    )
    result = checks.judge(check_kinds.Check("calibration_time_offset", 0.001), refused)
    assert result.outcome is checks.Outcome.NO_DATA and "too few cones seen" in result.reason
    shown = checks.judge(
        check_kinds.Check("calibration_time_offset", 0.001),
        RunResult(
            spec=None,
            seed=0,
            ticks=[],
            calibration=CalibrationRecord(
                np.eye(4),
                0.0,
                0.3,
                1,
                {"rotation_deg": 0.0, "translation_m": 0.0, "time_offset_s": 0.0005},
            ),
        ),
    ).shown
    assert shown == "0.5 ms (must be <= 1 ms)"


def test_camera_imu_calibration_checks_without_one_have_no_data():
    """A run whose camera-IMU calibration was not made, and one refused: no data, with the
    reason."""
    plain = RunResult(spec=None, seed=0, ticks=[_tick(0, [], [])])
    result = checks.judge(check_kinds.Check("calibration_imu_rotation", 0.1), plain)
    assert result.outcome is checks.Outcome.NO_DATA and "was not made" in result.reason
    refused = RunResult(
        spec=None,
        seed=0,
        ticks=[_tick(0, [], [])],
        imu_calibration=ImuCalibrationRecord(refused="not enough excitation: hovering"),
    )
    for kind in ("rotation", "translation", "time_offset"):
        result = checks.judge(check_kinds.Check(f"calibration_imu_{kind}", 0.1), refused)
        assert result.outcome is checks.Outcome.NO_DATA, kind
        assert result.reason == "camera-IMU calibration refused: not enough excitation: hovering"


# ------------------------------------------------------- a user's function and the chain


def _user_method(name: str):
    """A user's method ``user:<name>`` (``vnav.plugin``) whose function is never called: the
    records below hold its estimates already."""
    return function_method(reference_estimate, f"tests:{name}", name)


def _chain_run(user: str, offsets_m: list[float], ranges_m: list[float]) -> RunResult:
    """One matched detection per tick at each range: depth_image's estimate 1 cm from the
    cone, the user's that estimate moved by the offset (perpendicular to the first)."""
    ticks = []
    for k, (offset_m, range_m) in enumerate(zip(offsets_m, ranges_m, strict=True)):
        p_w_depth = np.array([range_m, 0.0, 0.01])  # the cone at (range_m, 0, 0)
        p_w_user = p_w_depth + np.array([0.0, offset_m, 0.0])
        errors = {"depth_image": 0.01, user: float(np.hypot(0.01, offset_m))}
        estimates = {"depth_image": p_w_depth, user: p_w_user}
        ticks.append(_tick(k, [0], [_detection(0, errors, range_m, True, estimates, None)]))
    return RunResult(spec=None, seed=0, ticks=ticks)


@pytest.mark.parametrize(
    ("offset_m", "range_m", "figure", "passed", "worst"),
    [
        # depth_image's bound, max(5 cm, 1% of range): 10 cm at 10 m, where the distance is
        # shown in % of range; the 5 cm floor at 2 m, where it is shown in metres.
        (0.02, 10.0, 0.02 / 0.1, True, "worst 0.2% of range"),
        (0.2, 10.0, 0.2 / 0.1, False, "worst 2% of range"),
        (0.02, 2.0, 0.02 / 0.05, True, "worst 0.02 m"),
        (0.2, 2.0, 0.2 / 0.05, False, "worst 0.2 m"),
    ],
    ids=["2cm-at-10m", "20cm-at-10m", "2cm-at-2m", "20cm-at-2m"],
)
def test_chain_agreement_of_a_function_off_the_chain(
    offset_m, range_m, figure, passed, worst
) -> None:
    """A function adding 2 cm to the correct chain's estimate is within depth_image's bound
    of it at 10 m (10 cm) and at 2 m (the 5 cm floor); one adding 20 cm is not."""
    user = _user_method("shifted")
    with extended([user]):
        check = next(c for c in check_kinds.user_checks() if c.kind == "chain_agreement")
        result = checks.judge(check, _chain_run(user.name, [offset_m], [range_m]))
    assert result.value == pytest.approx(figure, rel=1e-12)
    assert result.passed is passed
    assert result.name == (
        "user:shifted every estimate within max(5 cm, 1% of range) of the correct chain's"
    )
    assert result.shown.startswith(f"{worst} from depth_image's estimate (must be <= ")


def test_chain_agreement_is_the_worst_ratio_over_every_matched_detection() -> None:
    """Over the detections, in the contract's domain or not: the largest distance over the
    bound at its range, by hand."""
    user = _user_method("mixed")
    run = _chain_run(user.name, [0.04, 0.09, 0.3], [3.0, 12.0, 40.0])
    ticks = [*run.ticks[:2], dataclasses.replace(run.ticks[2])]
    outside = dataclasses.replace(ticks[2].detections[0], in_contract=False)  # 40 m: beyond it
    ticks[2] = dataclasses.replace(ticks[2], detections=[outside])
    run = RunResult(spec=None, seed=0, ticks=ticks)
    with extended([user]):
        result = checks.judge(check_kinds.Check("chain_agreement", 1.0, user.name), run)
    assert result.value == pytest.approx(max(0.04 / 0.05, 0.09 / 0.12, 0.3 / 0.4), rel=1e-12)
    assert result.passed  # 0.8, 0.75, 0.75 of the bound
    assert (
        result.shown
        == "worst 80% of the bound from depth_image's estimate (must be <= 100% of the bound)"
    )


def test_chain_agreement_of_a_function_that_failed_or_gave_nothing() -> None:
    """A function that failed on a detection agrees with nothing (infinite, failed); one that
    gave no estimate anywhere leaves nothing to judge (no data, which fails the run)."""
    user = _user_method("broken")
    run = _chain_run(user.name, [0.0, 0.0], [10.0, 10.0])
    failed = dataclasses.replace(
        run.ticks[1].detections[0],
        estimates_w={"depth_image": run.ticks[1].detections[0].estimates_w["depth_image"]},
        errors_m={"depth_image": 0.01},
        no_estimate={user.name: NoEstimate.FUNCTION_ERROR},
    )
    broken = RunResult(
        spec=None,
        seed=0,
        ticks=[run.ticks[0], dataclasses.replace(run.ticks[1], detections=[failed])],
    )
    none = RunResult(
        spec=None,
        seed=0,
        ticks=[
            dataclasses.replace(
                t,
                detections=[
                    dataclasses.replace(
                        d,
                        estimates_w={"depth_image": d.estimates_w["depth_image"]},
                        errors_m={"depth_image": 0.01},
                        no_estimate={user.name: NoEstimate.FUNCTION_NONE},
                    )
                    for d in t.detections
                ],
            )
            for t in run.ticks
        ],
    )
    with extended([user]):
        check = check_kinds.Check("chain_agreement", 1.0, user.name, default=True)
        result = checks.judge(check, broken)
        assert result.value == math.inf and result.outcome is checks.Outcome.FAILED
        assert result.shown.startswith("the function failed on 1 of 2 detections")
        result = checks.judge(check, none)
    assert result.outcome is checks.Outcome.NO_DATA and result.outcome.fails_run


def test_a_users_checks_follow_what_the_scenario_holds_depth_image_to() -> None:
    """The chain always; the truth's bound, with depth_image's limit, only where the scenario
    holds depth_image to it (its own error_bound, or the default checks)."""
    user = _user_method("mine")

    def kinds(own: tuple[check_kinds.Check, ...]) -> list[tuple[str, float]]:
        with extended([user]):
            out = check_kinds.user_checks(own)
        assert all(c.method == user.name and c.default for c in out)
        return [(c.kind, c.limit) for c in out]

    both = [("chain_agreement", 1.0), ("error_bound", 1.0)]
    assert kinds(()) == both  # the default checks hold depth_image to its bound
    assert kinds(builtin.load("frame-problem").checks) == both
    assert kinds(builtin.load("uncertainty").checks) == [("chain_agreement", 1.0)]
    assert kinds(builtin.load("calibration").checks) == [("chain_agreement", 1.0)]
    looser = (
        check_kinds.Check("error_bound", 2.0, "depth_image"),
        check_kinds.Check("error_bound", 1.0, "ground_plane"),
    )
    assert kinds(looser) == [("chain_agreement", 1.0), ("error_bound", 2.0)]
    assert check_kinds.user_checks(()) == ()  # no user's function, no check
