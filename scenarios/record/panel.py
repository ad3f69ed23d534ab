"""The state panel: the lecture's quantities at one camera tick, as text for the viewer.

At the time cursor the recording shows, as numbers (VNAV lecture 1):

- the poses ``T_w_b``, ``T_b_c`` and their composition ``T_w_c = T_w_b T_b_c`` (chapter 8),
  4x4, rounded (rotation to 3 decimals, translation to the centimetre);
- cone 0 as the camera sees it and through the chain ``p_c -> p_b = T_b_c p_c ->
  p_w = T_w_b p_b`` (chapter 0), next to the naive ``t_w_b + p_c``;
- the attitude ``R_w_b`` as roll, pitch, yaw (chapter 4) with the gimbal-lock flag, as a
  quaternion (chapter 6, x y z w) and as axis-angle (chapter 5, Rodrigues' formula);
- the image's time (docs/CONVENTIONS.md, "Time and stamps"): its exposure stamp on the camera
  clock and on the pose clock, its arrival, the stamp of the pose it was given and of the
  newest pose received by then, with the body's true motion in between; for an image that
  was neither late nor stamped on another clock (a synchronous run), one line in the header;
- in a calibrated run (``mount_lines``), the camera mount the estimator was told, the true
  one and the one calibration recovered, side by side, each with its error against the true
  mount, and the clock offset, true and recovered;
- in a navigating flight (``navigation_lines``), the plan from the estimated position, the
  map, the true clearance and distance from the nearest cone's axis, and the flight's outcome
  (``navigation_outcome``: the collision, or the goal reached or not).

All of it is the simulator's truth at that tick (the estimator's noisy pose is not shown),
except the declared and recovered mounts, shown against it, and the navigating drone's
estimated position, map and plan, shown beside it.
"""

from __future__ import annotations

import math

import numpy as np

from scenarios.run.records import (
    CalibrationRecord,
    ImageTiming,
    NavigationRecord,
    NavigationTick,
    TickRecord,
)
from vnav import quat, se3, so3
from vnav.estimators import naive

__all__ = [
    "SYNCHRONOUS_NOTE",
    "mount_lines",
    "navigation_lines",
    "navigation_outcome",
    "nearest_axis_m",
    "state_text",
]


def _number(x: float, decimals: int, width: int) -> str:
    # + 0.0 turns -0.0 into 0.0: a rounded "-0.000" would read as a sign error.
    return f"{round(float(x), decimals) + 0.0:{width}.{decimals}f}"


_COLUMN = 29
"""Width of one 4x4 pose in the panel (three side by side, three spaces apart)."""


def _matrix_rows(T: np.ndarray, translation_decimals: int = 2) -> list[str]:
    """Four rows of a 4x4 pose: rotation to 3 decimals | translation to the centimetre (or
    to ``translation_decimals``)."""
    return [
        " ".join(_number(T[i, j], 3, 6) for j in range(3))
        + " |"
        + _number(T[i, 3], translation_decimals, 7)
        for i in range(4)
    ]


def _side_by_side(titles: list[str], blocks: list[list[str]]) -> list[str]:
    """Columns of text, ``_COLUMN`` wide, three spaces apart: a title over each block."""
    rows = [titles, *zip(*blocks, strict=True)]
    return ["   ".join(f"{cell:<{_COLUMN}}" for cell in row).rstrip() for row in rows]


def _vector(p: np.ndarray, decimals: int = 2, width: int = 7) -> str:
    return "[" + " ".join(_number(x, decimals, width) for x in p) + "]"


_NO_ROTATION_DEG = 0.05
"""Below this angle (it prints as 0.0 deg) the axis of the axis-angle is meaningless."""


def _axis(axis: np.ndarray, angle_rad: float) -> str:
    """The rotation axis, or a note where there is no rotation to have an axis (every axis
    is then as good, and the one computed is rounding noise)."""
    shown = _vector(axis, 3, 6)
    if math.degrees(angle_rad) < _NO_ROTATION_DEG:
        return f"{'any (no rotation)':<{len(shown)}}"
    return shown


def _ms(dt_s: float) -> str:
    return f"{1e3 * dt_s + 0.0:.0f} ms"


SYNCHRONOUS_NOTE = "image processed at its exposure: no latency, the newest pose is its pose"
"""What the panel's header says of an image that was neither late nor stamped on another clock
(a synchronous run): its time needs no block of its own."""


def _synchronous(timing: ImageTiming) -> bool:
    return (
        timing.image_latency_s == 0.0
        and timing.stamp_cam_s == timing.exposure_pose_s
        and not timing.latest_minus_exposure_s
    )


def _time_lines(timing: ImageTiming) -> list[str]:
    """The image's stamps on both clocks, its arrival, the stamps of the pose it was given and
    of the newest pose by then, and the body's true motion between those two."""
    offset_s = timing.exposure_pose_s - timing.stamp_cam_s
    lead_s = timing.latest_minus_exposure_s
    lines = [
        f"time    exposure  {timing.stamp_cam_s:.3f} s camera clock = "
        f"{timing.exposure_pose_s:.3f} s pose clock "
        f"(t_pose = t_cam {'-' if offset_s < 0.0 else '+'} {_ms(abs(offset_s))})",
        f"        arrival   {timing.arrival_s:.3f} s, {_ms(timing.image_latency_s)} after the "
        "exposure",
    ]
    used = f"        poses     used: {timing.exposure_pose_s:.3f} s, the exposure stamp"
    if timing.latest_pose_s is None or lead_s is None:
        return [*lines, used + "   newest: none received by the arrival"]
    side = "ahead of" if lead_s >= 0.0 else "behind"
    return [
        *lines,
        f"{used}   newest: {timing.latest_pose_s:.3f} s, {_ms(abs(lead_s))} {side} it",
        f"        motion    between the two the body moved {timing.true_motion_m:.3f} m and "
        f"turned {math.degrees(timing.true_motion_rad):.1f} deg",
    ]


def _mount_error(T_b_c: np.ndarray, T_b_c_true: np.ndarray) -> tuple[float, float]:
    """A mount's error against the true one: the angle of the rotation between them (deg)
    and the distance between the camera centres (mm), as ``scenarios.judge.calibration``
    measures the recovered mount's."""
    R_err = T_b_c[:3, :3].T @ T_b_c_true[:3, :3]
    return (
        math.degrees(float(np.linalg.norm(so3.log(R_err)))),
        1e3 * float(np.linalg.norm(T_b_c[:3, 3] - T_b_c_true[:3, 3])),
    )


def _off(deg: float, mm: float) -> str:
    """A mount's error against the true one, to fit under its column."""
    return f"error {deg:.4f} deg, {mm:.2f} mm"


def mount_lines(calibration: CalibrationRecord, camera_clock_offset_s: float) -> list[str]:
    """The state panel's mounts block of a calibrated run: the mount the estimator was told,
    the true one and the one recovered, side by side (translations to the millimetre), each
    with its error against the true one; the clock offset, true and recovered.

    The same at every tick (calibration uses the whole flight): computed once per run.

    Parameters
    ----------
    calibration : CalibrationRecord
        What calibration recovered (or why it refused), with the declared and true mounts.
    camera_clock_offset_s : float
        The true offset of the camera's clock: ``t_pose = t_cam + offset``, seconds.
    """
    c = calibration
    assert c.T_b_c_declared is not None and c.T_b_c_true is not None, "calibrate_run sets them"
    titles = ["T_b_c declared (told)", "T_b_c true (simulator)", "T_b_c recovered (calibrated)"]
    mounts = [c.T_b_c_declared, c.T_b_c_true, c.T_b_c]
    blocks = [
        ["refused", "", "", ""] if T is None else _matrix_rows(T, translation_decimals=3)
        for T in mounts
    ]
    errors = [_off(*_mount_error(c.T_b_c_declared, c.T_b_c_true)), "(the reference)"]
    if c.T_b_c is not None:
        # The report's errors, to the digit: the recovered mount's is what the checks judge.
        errors.append(_off(c.errors["rotation_deg"], 1e3 * c.errors["translation_m"]))
    else:
        errors.append("")
    lines = _side_by_side(titles, [[*b, e] for b, e in zip(blocks, errors, strict=True)])
    true_ms = 1e3 * camera_clock_offset_s
    if c.refused is not None:
        return [
            *lines,
            f"clock   t_pose = t_cam + {true_ms:.3f} ms (true)",
            f"        calibration refused: {c.refused}",
        ]
    assert c.time_offset_s is not None and c.reprojection_rms_px is not None
    return [
        *lines,
        f"clock   t_pose = t_cam + {true_ms:.3f} ms (true), + {1e3 * c.time_offset_s:.3f} ms "
        f"(recovered, off the true {1e3 * c.errors['time_offset_s']:.3f} ms)",
        f"        from the reprojection of every cone apex seen: RMS {c.reprojection_rms_px:.3f} "
        f"px over {c.frames_used} images",
    ]


def navigation_outcome(nav: NavigationRecord) -> str:
    """How a navigating flight ended, in the words ``vnav-demo run`` prints: ``collision with
    cone 0 at t = 5.15 s``, ``reached the goal at t = 10.12 s`` or ``did not reach the goal``
    (with how far from it)."""
    if nav.contact is not None:
        return (
            f"collision with cone {nav.contact.cone_index} at t = {nav.contact.t_s:.2f} s, at "
            f"{_vector(nav.contact.point_w, 2, 6)} (MuJoCo's contact point)"
        )
    if nav.reached_goal_s is not None:
        return f"reached the goal at t = {nav.reached_goal_s:.2f} s, no collision"
    return f"did not reach the goal: {nav.final_distance_m:.2f} m from it at the end, no collision"


def nearest_axis_m(p_w: np.ndarray, cones_w: np.ndarray) -> tuple[float, int]:
    """The horizontal distance from ``p_w`` (3,) to the nearest cone's vertical axis, m, and
    that cone's index, over the true cones' base centres ``cones_w`` (N, 3), N >= 1: what the
    planner's ``clearance_m`` bounds from a mapped cone (docs/CONVENTIONS.md, "Navigation")."""
    d_m = np.linalg.norm(np.asarray(cones_w)[:, :2] - np.asarray(p_w)[:2], axis=1)
    i = int(np.argmin(d_m))
    return float(d_m[i]), i


def navigation_lines(
    nav_tick: NavigationTick,
    record: TickRecord,
    nav: NavigationRecord,
    cones_w: np.ndarray,
    *,
    estimate: str,
    goal_w: np.ndarray,
    clearance_m: float,
    dropped: int = 0,
) -> list[str]:
    """The state panel's navigation block at one camera tick.

    Parameters
    ----------
    nav_tick : NavigationTick
        The tick's map and plan (the navigator's record of ``record``).
    record : TickRecord
        The same camera tick (its true body pose).
    nav : NavigationRecord
        The whole flight (its outcome).
    cones_w : ndarray, shape (N, 3)
        The true cones' base centres, m.
    estimate : str
        The method the map takes.
    goal_w : ndarray, shape (3,)
    clearance_m : float
        What the planner keeps from each mapped cone's axis, m.
    dropped : int
        The estimates the map dropped up to this tick (``NavigationTick.rejected`` summed).
    """
    n = len(nav_tick.obstacles_w)
    why = ""
    if dropped:
        why = f"; {dropped} estimate(s) dropped so far: base outside the flight band"
    lines = [
        f"navigate  plan {nav_tick.plan_length_m:.2f} m: estimated position "
        f"{_vector(nav_tick.position_w_est, 2, 6)} -> goal {_vector(goal_w, 2, 6)}",
        f"          {estimate}'s map: {n} cone{'' if n == 1 else 's'}{why}",
    ]
    if len(cones_w):
        c = int(np.argmin(nav_tick.clearance_true_m))
        axis_m, a = nearest_axis_m(record.T_w_b[:3, 3], cones_w)
        lines += [
            f"truth     clearance {nav_tick.clearance_true_m[c]:.3f} m to cone {c} (MuJoCo, "
            "geometry to geometry; 0: contact)",
            f"          drone centre {axis_m:.2f} m from cone {a}'s axis; the planner keeps "
            f"{clearance_m:.2f} m from each mapped axis",
        ]
    return [*lines, f"outcome   {navigation_outcome(nav)}"]


def _cone0_lines(record: TickRecord, cone0_w: np.ndarray) -> list[str]:
    """Cone 0 through the chain ``p_w = T_w_b T_b_c p_c``, and the naive mistake beside it.

    Parameters
    ----------
    record : TickRecord
        The tick (its true poses).
    cone0_w : ndarray, shape (3,)
        Cone 0's true base centre in the world, metres.

    Returns
    -------
    list of str
        Four lines: camera, body, world coordinates, the naive sum.
    """
    p = record.coordinates_of(cone0_w)
    return [
        f"cone 0  p_c               {_vector(p['camera'])}  camera: x right, y down, z fwd",
        f"        p_b = T_b_c p_c   {_vector(p['body'])}  body: x fwd, y left, z up",
        f"        p_w = T_w_b p_b   {_vector(p['world'])}  world: z up",
        f"naive   t_w_b + p_c       {_vector(naive(p['camera'], record.T_w_b[:3, 3]))}"
        "  wrong: p_c is not a world offset",
    ]


def _attitude_lines(record: TickRecord, quat_xyzw: np.ndarray) -> list[str]:
    """``R_w_b`` three ways: roll, pitch, yaw (with the gimbal lock), quaternion, axis-angle.

    Parameters
    ----------
    record : TickRecord
        The tick (its true attitude and gimbal-lock flag).
    quat_xyzw : ndarray, shape (4,)
        The attitude as plotted (the sign that keeps the plot continuous).

    Returns
    -------
    list of str
        Three lines.
    """
    roll, pitch, yaw = np.degrees(record.rpy_rad)
    axis, angle = quat.to_axis_angle(quat_xyzw, normalize=True)
    lock = "LOCKED: only yaw - roll is defined" if record.gimbal_locked else "no"
    flipped = quat_xyzw[3] < 0.0
    return [
        f"R_w_b   roll {_number(roll, 1, 6)}  pitch {_number(pitch, 1, 6)}  "
        f"yaw {_number(yaw, 1, 6)} deg    gimbal lock: {lock}",
        f"        quaternion xyzw {_vector(quat_xyzw, 3, 6)}"
        + ("  (w < 0: -q is the same rotation)" if flipped else ""),
        f"        axis-angle  axis {_axis(axis, angle)}  angle "
        f"{_number(math.degrees(angle), 1, 6)} deg  (R = I + sin(a) K + (1 - cos(a)) K^2)",
    ]


def state_text(
    record: TickRecord,
    quat_xyzw: np.ndarray,
    cone0_w: np.ndarray,
    mounts: list[str] | None = None,
    navigation: list[str] | None = None,
) -> str:
    """Markdown for the state panel at one tick.

    Parameters
    ----------
    record : TickRecord
        The tick (its true ``T_w_b``, ``T_b_c``, attitude and gimbal-lock flag are shown).
    quat_xyzw : ndarray, shape (4,)
        The attitude as plotted: ``record.quat_xyzw`` with the sign that keeps the plotted
        quaternion continuous (``q`` and ``-q`` are the same rotation).
    cone0_w : ndarray, shape (3,)
        Cone 0's true base centre in the world, metres.
    mounts : list of str, optional
        A calibrated run's mounts block (``mount_lines``), shown under the poses.
    navigation : list of str, optional
        A navigating flight's block at this tick (``navigation_lines``), shown under the
        poses.
    """
    T_w_b, T_b_c = record.T_w_b, record.T_b_c
    T_w_c = T_w_b @ T_b_c
    names = ["T_w_b: body in world", "T_b_c: camera in body", "T_w_c = T_w_b T_b_c"]
    lines = _side_by_side(names, [_matrix_rows(T) for T in (T_w_b, T_b_c, T_w_c)])
    if mounts is not None:
        lines += ["", *mounts]
    if navigation is not None:
        lines += ["", *navigation]

    lines += ["", *_cone0_lines(record, cone0_w)]
    lines += ["", *_attitude_lines(record, quat_xyzw)]
    mount_off = se3.invert(record.T_b_c_est) @ T_b_c
    # With the mounts block the declared mount's error is shown there, beside the recovered one.
    if mounts is None and not np.allclose(mount_off, np.eye(4), atol=1e-9):
        off_deg, off_mm = _mount_error(record.T_b_c_est, T_b_c)
        lines += [
            "",
            f"mount   the estimator is told a T_b_c {off_deg:.2f} deg and {off_mm:.1f} mm off "
            "this one (the truth)",
        ]
    header = f"**tick {record.tick}, t = {record.t_s:.2f} s** (simulator truth)"
    if record.timing is not None and _synchronous(record.timing):
        # One line in the header: the panel keeps its height in the common case.
        header += f"; time: {SYNCHRONOUS_NOTE}"
    elif record.timing is not None:
        lines += ["", *_time_lines(record.timing)]
    return header + "\n\n```\n" + "\n".join(lines) + "\n```\n"
