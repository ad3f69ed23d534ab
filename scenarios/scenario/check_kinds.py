"""The check kinds a scenario may ask for, declared as data: what each asserts, in which unit
its limit is and in which direction it must be met.

This is the scenario format's half of a check: the parser (``scenarios.scenario.spec``), the
schema's comments (``scenarios.scenario.schema``) and the README read it. The other half, the
figure each kind computes from a finished run, is registered against these names in
``scenarios.judge.checks`` (as ``vnav.methods`` declares the methods and their estimators live
in their own modules); a test holds the two to the same set of names. The accuracy bounds are
those of the perception contract (docs/ACCURACY.md, declared in ``vnav.methods``).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from vnav.methods import METHODS, PREFERENCE, active_methods, method

__all__ = ["KINDS", "Check", "CheckKind", "Unit", "default_checks"]


class Unit(enum.Enum):
    """What a check's figure and its limit are measured in (the report's ``unit``)."""

    METRES = "m"
    FRACTION = "fraction"
    """A share, 0 to 1 (shown in percent)."""
    COUNT = "count"
    RATIO = "ratio"
    """One figure over another (shown as ``12x``)."""
    BOUND = "fraction of bound"
    """An error over the method's accuracy bound at its range (1: at the bound)."""
    DEGREES = "deg"
    SECONDS = "s"
    RELATIVE = "relative error"
    """A difference over the magnitude it is measured against (1e-6: a millionth)."""


_LIMIT_UNIT_DOC = {
    Unit.METRES: "metres",
    Unit.FRACTION: "a fraction (0.95: 95%)",
    Unit.COUNT: "a count",
    Unit.RATIO: "a ratio (10: ten times)",
    Unit.BOUND: "times the method's accuracy bound (1: the bound)",
    Unit.DEGREES: "degrees",
    Unit.SECONDS: "seconds",
    Unit.RELATIVE: "a relative error (1e-6: a millionth)",
}


@dataclass(frozen=True)
class CheckKind:
    """One kind of check: what it asserts and how its figure meets the limit.

    Attributes
    ----------
    name : str
        The ``kind`` a scenario file gives.
    at_most : bool
        True if the figure must be at most the limit, False if at least.
    unit : Unit
        What the figure and the limit are measured in.
    uses_method : bool
        Whether the figure depends on the check's ``method``.
    doc : str
        What the check asserts, one line.
    """

    name: str
    at_most: bool
    unit: Unit
    uses_method: bool
    doc: str

    def passes(self, figure: float, limit: float) -> bool:
        """Whether ``figure`` meets ``limit`` (at the limit, it does)."""
        return figure <= limit if self.at_most else figure >= limit

    @property
    def limit_doc(self) -> str:
        """What the limit is, in words: its direction and unit (``at most, metres``)."""
        return f"{'at most' if self.at_most else 'at least'}, {_LIMIT_UNIT_DOC[self.unit]}"

    @property
    def limit_key(self) -> str:
        """The key a scenario file writes the limit under: ``limit_m`` in metres, else
        ``limit``."""
        return "limit_m" if self.unit is Unit.METRES else "limit"


def _kinds(*kinds: CheckKind) -> dict[str, CheckKind]:
    return {k.name: k for k in kinds}


_AT_MOST, _AT_LEAST = True, False

KINDS: dict[str, CheckKind] = _kinds(
    CheckKind(
        "max_error",
        _AT_MOST,
        Unit.METRES,
        True,
        "largest position error of ``method`` over all matched detections <= limit_m",
    ),
    CheckKind(
        "median_error",
        _AT_MOST,
        Unit.METRES,
        True,
        "median position error of ``method`` <= limit_m",
    ),
    CheckKind(
        "error_bound",
        _AT_MOST,
        Unit.BOUND,
        True,
        "error / accuracy bound of ``method`` (worst or median, as the bound says) <= limit",
    ),
    CheckKind(
        "chain_agreement",
        _AT_MOST,
        Unit.BOUND,
        True,
        "largest distance of ``method``'s estimate from depth_image's / depth_image's "
        "bound <= limit",
    ),
    CheckKind(
        "consistent",
        _AT_LEAST,
        Unit.FRACTION,
        True,
        "chi-square probability of ``method``'s mean NEES, two-sided, >= limit "
        "(0.05: in the 95% band)",
    ),
    CheckKind(
        "calibration_rotation",
        _AT_MOST,
        Unit.DEGREES,
        False,
        "rotation between the recovered camera mount and the true one <= limit (degrees)",
    ),
    CheckKind(
        "calibration_translation",
        _AT_MOST,
        Unit.METRES,
        False,
        "distance between the recovered camera mount's origin and the true one <= limit_m",
    ),
    CheckKind(
        "calibration_time_offset",
        _AT_MOST,
        Unit.SECONDS,
        False,
        "error of the recovered camera clock offset <= limit (seconds)",
    ),
    CheckKind(
        "detection_rate",
        _AT_LEAST,
        Unit.FRACTION,
        False,
        "detections / cones fully in view (summed over camera ticks) >= limit",
    ),
    CheckKind(
        "world_estimate_spread",
        _AT_MOST,
        Unit.METRES,
        True,
        "largest distance of ``method``'s estimates of a cone from their mean <= limit_m",
    ),
    CheckKind(
        "camera_coords_span",
        _AT_LEAST,
        Unit.METRES,
        False,
        "the cone's camera-frame coordinates move by >= limit_m",
    ),
    CheckKind(
        "naive_worse",
        _AT_LEAST,
        Unit.RATIO,
        True,
        "median naive error >= limit x the median error of ``method``",
    ),
    CheckKind(
        "gimbal_lock_seen",
        _AT_LEAST,
        Unit.COUNT,
        False,
        "camera ticks whose roll/pitch/yaw flag gimbal lock >= limit",
    ),
    CheckKind(
        "tracking_error",
        _AT_MOST,
        Unit.METRES,
        False,
        "largest distance of the body from its reference (controlled flights) <= limit_m",
    ),
    CheckKind(
        "matched_cones",
        _AT_LEAST,
        Unit.COUNT,
        False,
        "number of distinct true cones matched at least once >= limit",
    ),
    CheckKind(
        "latency_prediction",
        _AT_MOST,
        Unit.FRACTION,
        False,
        "median |latest-pose error / predicted - 1| <= limit (depth_image with the newest pose)",
    ),
    CheckKind(
        "reached_goal",
        _AT_MOST,
        Unit.METRES,
        False,
        "true distance of the body from the goal when a navigating flight ends <= limit_m",
    ),
    CheckKind(
        "no_collision",
        _AT_MOST,
        Unit.COUNT,
        False,
        "cones the drone touched (MuJoCo contacts) <= limit (0: none)",
    ),
    CheckKind(
        "collision",
        _AT_LEAST,
        Unit.COUNT,
        False,
        "cones the drone touched (MuJoCo contacts) >= limit (1: the run must collide)",
    ),
    CheckKind(
        "min_clearance",
        _AT_LEAST,
        Unit.METRES,
        False,
        "smallest true distance between the drone's and a cone's geometry >= limit_m",
    ),
    CheckKind(
        "imu_consistent",
        _AT_MOST,
        Unit.RELATIVE,
        False,
        "largest relative difference, over every physics step, between MuJoCo's noise-free "
        "IMU sensors and vnav.imu's specific force and rate from the body's motion <= limit",
    ),
    CheckKind(
        "calibration_imu_rotation",
        _AT_MOST,
        Unit.DEGREES,
        False,
        "rotation between the camera-IMU rotation R_i_c recovered from the images and the gyro "
        "and the true one <= limit (degrees)",
    ),
    CheckKind(
        "calibration_imu_translation",
        _AT_MOST,
        Unit.METRES,
        False,
        "distance between the camera's origin in the IMU frame recovered (t_i_c, from the "
        "accelerometer's lever arm) and the true one <= limit_m",
    ),
    CheckKind(
        "calibration_imu_time_offset",
        _AT_MOST,
        Unit.SECONDS,
        False,
        "error of the recovered camera-IMU clock offset (Kalibr's timeshift_cam_imu) <= limit "
        "(seconds)",
    ),
)
"""Every check kind, by name. Its figure is ``scenarios.judge.checks.FIGURES[name]``."""


@dataclass(frozen=True)
class Check:
    """One pass/fail criterion evaluated on a finished run (a kind from ``KINDS``).

    ``default`` marks the checks of ``default_checks``: skipped, not
    failed, when their method cannot apply to the scenario's geometry.

    Raises
    ------
    ValueError
        For a kind not in ``KINDS`` or an unknown method, naming the valid ones.
    """

    kind: str
    limit: float
    method: str = PREFERENCE[0]
    name: str = ""
    default: bool = False

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown check {self.kind!r}; valid: {sorted(KINDS)}")
        method(self.method)  # raises ValueError naming the valid methods

    @property
    def label(self) -> str:
        """The check's name, or one made of its method and kind."""
        if self.name:
            return self.name
        return f"{self.method} {self.kind}" if KINDS[self.kind].uses_method else self.kind


def default_checks() -> tuple[Check, ...]:
    """Checks for a scenario that declares none: every method's bound and the detection rate.

    Each is a ``default`` check: a bound whose method cannot apply to the scenario's geometry
    is skipped with the reason.
    """
    return (
        *(
            Check("error_bound", 1.0, m.name, f"{m.name} {m.promise}", default=True)
            for m in METHODS
            if m.bound
        ),
        Check("detection_rate", 0.95, name="cones in view detected", default=True),
    )


def user_checks(own: tuple[Check, ...] = ()) -> tuple[Check, ...]:
    """The checks of each user function the run judges (``vnav.plugin``, within
    ``vnav.methods.extended``), for a scenario whose own checks are ``own`` (empty: the
    default ones, ``default_checks``).

    A user's function is given the ``depth_image`` estimate in the camera frame, with the
    estimator's pose and mount: the correct chain on those inputs gives that estimate back. So
    it is held, always, to agree with it within ``depth_image``'s accuracy bound at each range
    (``chain_agreement``, limit 1: its frame chain, on the inputs it was given); and to that
    bound against the truth (``error_bound``) only where ``depth_image`` itself is held to it,
    with the same limit (the tightest if several): where the inputs are off (pose noise, a
    declared mount that is wrong) and the scenario does not hold ``depth_image`` to its bound,
    the function is not held to it either. Both are ``default`` checks, as the built-ins'.
    """
    held = [
        c.limit
        for c in (own or default_checks())
        if c.kind == "error_bound" and c.method == "depth_image"
    ]
    out: list[Check] = []
    for m in active_methods():
        if m.images != "user" or m.bound is None:
            continue
        out.append(
            Check(
                "chain_agreement",
                1.0,
                m.name,
                f"{m.name} every estimate within {m.bound.allowed_text} of the correct chain's",
                default=True,
            )
        )
        if held:
            out.append(
                Check("error_bound", min(held), m.name, f"{m.name} {m.promise}", default=True)
            )
    return tuple(out)
