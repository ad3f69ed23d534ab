"""What a navigating flight's recording adds: the closed loop, tick by tick, and its outcome.

A ``NavigateFlight`` (``scenarios.scenario.spec``) is steered by what its estimator mapped
(``scenarios.run.navigation``). Its recording draws, from the run's ``NavigationRecord``, sent
once the run is over (``scenarios.record.recording.Recording.finish``)::

    world/navigation/plan                  in world: the plan at each camera tick, at the flight
                                           altitude, from the estimated position to the goal
    world/navigation/position_est          in world: where the drone thought it was
    world/navigation/obstacles/<method>    in world: the mapped cones' estimated base centres,
                                           per method that put them in the map
    world/navigation/keep_out/<method>     in world: each mapped cone's keep-out circle of
                                           radius clearance_m at the flight altitude, and its
                                           axis from the mapped base up through it
    world/navigation/goal                  in world (static): the goal and its radius
    world/navigation/contact, contact/cross  in world: MuJoCo's contact point and a cross on
                                           it, and its name on a stalk off it, from the
                                           contact on
    metrics/navigation/clearance_true_m    Scalars: MuJoCo's smallest distance between the
                                           drone's and a cone's collision geometry, m
    metrics/navigation/contact_level_m     Scalars: 0, the contact level
    metrics/navigation/contact             SeriesPoints: 0 at the contact's time
    metrics/navigation/axis_distance_m     Scalars: the drone's centre to the nearest true
                                           cone's axis, in the plane, m (truth)
    metrics/navigation/clearance_m         Scalars: what the planner keeps from each mapped
                                           axis, m
    metrics/navigation/plan_length_m       Scalars: the plan's length, m

Every per-tick row is logged at its camera tick (``tick`` and ``sim_time``). The contact
happens between two camera ticks, after the last: it is logged at its own ``sim_time`` and,
on ``tick``, at the tick after the last (which the flight never reached), so that it shows
on either timeline from the contact on. The state panel's navigation block is
``scenarios.record.panel.navigation_lines``; the plots' tab ``viewer.navigation_tab``.
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from scenarios.record.panel import nearest_axis_m
from scenarios.record.viewer import (
    CLEARANCE_COLOR,
    CONTACT_COLOR,
    FRAME,
    KEPT_COLOR,
    PLAN_COLOR,
    entity,
    map_color,
)
from scenarios.run.records import NavigationRecord, RunResult, TickRecord
from scenarios.scenario.spec import GOAL_RADIUS_M, NavigateFlight

__all__ = ["CIRCLE_SEGMENTS", "CONTACT_CROSS_M", "circle_w", "send_navigation"]

CIRCLE_SEGMENTS = 64
"""Segments of a drawn circle: a 1 m circle's chords are within 1.2 mm of it."""
CONTACT_CROSS_M = 0.3
"""Half the length of each arm of the contact's cross, m: a cone is 0.7 m tall."""
CONTACT_LABEL_OFFSET_M = np.array([0.0, -0.8, 1.0])
"""The contact's name sits on a red stalk from the contact point, this far off it in the world
(m: to the right of a flight along world x, and up): at the point itself it lay on the drone's
name, and straight above it on cone 0's."""
PLAN_UI_POINTS = rr.Radius.ui_points(2.0)
KEEP_OUT_UI_POINTS = rr.Radius.ui_points(1.5)


def circle_w(center_w: np.ndarray, radius_m: float) -> np.ndarray:
    """A horizontal circle about ``center_w`` (3,) as a closed polyline, shape
    (CIRCLE_SEGMENTS + 1, 3)."""
    angle = np.linspace(0.0, 2.0 * np.pi, CIRCLE_SEGMENTS + 1)
    ring = np.column_stack([np.cos(angle), np.sin(angle), np.zeros_like(angle)])
    return np.asarray(center_w, dtype=np.float64) + radius_m * ring


def _indexes(records: list[TickRecord]) -> list[rr.TimeColumn]:
    return [
        rr.TimeColumn("tick", sequence=[t.tick for t in records]),
        rr.TimeColumn("sim_time", duration=[t.t_s for t in records]),
    ]


def _keep_out_strips(
    obstacles_w: np.ndarray, altitude_m: float, clearance_m: float
) -> list[np.ndarray]:
    """Per mapped cone its keep-out circle at the flight altitude and its axis, from the mapped
    base up through the circle."""
    strips = []
    for p_w in obstacles_w:
        strips.append(circle_w([p_w[0], p_w[1], altitude_m], clearance_m))
        top_m = max(altitude_m, float(p_w[2])) + 0.5
        strips.append(np.array([p_w, [p_w[0], p_w[1], top_m]]))
    return strips


def _log_styles(rec: rr.RecordingStream, methods: list[str]) -> None:
    """Frames, colours and names of the navigation entities, static."""
    paths = [entity.NAV_PLAN, entity.NAV_POSITION_EST, entity.NAV_GOAL, entity.NAV_CONTACT]
    paths += [entity.NAV_CONTACT_CROSS]
    paths += [entity.nav_obstacles(m) for m in methods] + [entity.nav_keep_out(m) for m in methods]
    for path in paths:
        rec.log(path, rr.CoordinateFrame(FRAME.WORLD), static=True)
    rec.log(
        entity.NAV_PLAN,
        rr.LineStrips3D.from_fields(colors=[PLAN_COLOR], radii=PLAN_UI_POINTS),
        static=True,
    )
    rec.log(
        entity.NAV_POSITION_EST,
        rr.Points3D.from_fields(colors=[PLAN_COLOR], radii=0.1),
        static=True,
    )
    for m in methods:
        color = map_color(m)[0]
        rec.log(
            entity.nav_obstacles(m), rr.Points3D.from_fields(colors=[color], radii=0.1), static=True
        )
        rec.log(
            entity.nav_keep_out(m),
            rr.LineStrips3D.from_fields(colors=[color], radii=KEEP_OUT_UI_POINTS),
            static=True,
        )
    series = {
        entity.NAV_CLEARANCE: (CLEARANCE_COLOR, "true clearance", 2.0),
        entity.NAV_CONTACT_LEVEL: (CONTACT_COLOR, "0: contact", 1.0),
        entity.NAV_AXIS_DISTANCE: (PLAN_COLOR, "drone centre to nearest cone axis", 2.0),
        entity.NAV_CLEARANCE_KEPT: (KEPT_COLOR, "clearance_m, kept from each mapped axis", 1.0),
        entity.NAV_PLAN_LENGTH: (PLAN_COLOR, "planned path length", 2.0),
    }
    for path, (color, name, width) in series.items():
        rec.log(path, rr.SeriesLines(colors=[color], names=[name], widths=[width]), static=True)
    rec.log(
        entity.NAV_CONTACT_MARK,
        rr.SeriesPoints(
            colors=[CONTACT_COLOR], names=["contact"], markers=["cross"], marker_sizes=[8.0]
        ),
        static=True,
    )


def _log_goal(rec: rr.RecordingStream, goal_w: np.ndarray) -> None:
    """The goal, named, and the circle the body's origin must reach (``GOAL_RADIUS_M``)."""
    rec.log(
        entity.NAV_GOAL,
        rr.Points3D(
            [goal_w],
            colors=[PLAN_COLOR],
            radii=rr.Radius.ui_points(4.0),
            labels=["goal"],
            show_labels=True,
        ),
        rr.LineStrips3D(
            [circle_w(goal_w, GOAL_RADIUS_M)], colors=[PLAN_COLOR], radii=KEEP_OUT_UI_POINTS
        ),
        static=True,
    )


def _send_ticks(
    rec: rr.RecordingStream, result: RunResult, nav: NavigationRecord, methods: list[str]
) -> None:
    """Each camera tick's plan, estimated position, map and the plotted figures."""
    flight = result.spec.flight
    assert isinstance(flight, NavigateFlight)
    altitude_m = float(flight.goal_w[2])
    records = result.ticks
    index = _indexes(records)
    ticks = nav.ticks
    rec.send_columns(
        entity.NAV_PLAN,
        indexes=index,
        columns=rr.LineStrips3D.columns(strips=[k.plan_w for k in ticks]),
    )
    rec.send_columns(
        entity.NAV_POSITION_EST,
        indexes=index,
        columns=rr.Points3D.columns(positions=np.array([k.position_w_est for k in ticks])),
    )
    for m in methods:
        mine = [k.obstacles_w[[o == m for o in k.obstacle_methods]].reshape(-1, 3) for k in ticks]
        rec.send_columns(
            entity.nav_obstacles(m),
            indexes=index,
            columns=rr.Points3D.columns(positions=np.concatenate(mine)).partition(
                [len(p) for p in mine]
            ),
        )
        strips = [_keep_out_strips(p, altitude_m, flight.clearance_m) for p in mine]
        rec.send_columns(
            entity.nav_keep_out(m),
            indexes=index,
            columns=rr.LineStrips3D.columns(strips=[s for tick in strips for s in tick]).partition(
                [len(s) for s in strips]
            ),
        )
    cones_w = result.cones_w
    scalars = {
        entity.NAV_CLEARANCE: [float(np.min(k.clearance_true_m, initial=np.inf)) for k in ticks],
        entity.NAV_CONTACT_LEVEL: [0.0] * len(ticks),
        entity.NAV_PLAN_LENGTH: [k.plan_length_m for k in ticks],
        entity.NAV_CLEARANCE_KEPT: [flight.clearance_m] * len(ticks),
    }
    if len(cones_w):
        scalars[entity.NAV_AXIS_DISTANCE] = [
            nearest_axis_m(t.T_w_b[:3, 3], cones_w)[0] for t in records
        ]
    for path, values in scalars.items():
        # An infinite clearance (no cone at all) would only break the plot's scale: a gap.
        values = [v if np.isfinite(v) else np.nan for v in values]
        rec.send_columns(path, indexes=index, columns=rr.Scalars.columns(scalars=values))


def _send_contact(rec: rr.RecordingStream, result: RunResult, nav: NavigationRecord) -> None:
    """MuJoCo's contact point, named, with a cross on it, and its mark on the clearance plot,
    from the contact on (at its ``sim_time``; on ``tick``, the tick after the last)."""
    contact = nav.contact
    if contact is None:
        return
    next_tick = result.ticks[-1].tick + 1 if result.ticks else 0
    rec.set_time("tick", sequence=next_tick)
    rec.set_time("sim_time", duration=contact.t_s)
    p_w = np.asarray(contact.point_w, dtype=np.float64)
    label_w = p_w + CONTACT_LABEL_OFFSET_M
    rec.log(
        entity.NAV_CONTACT,
        rr.Points3D(
            [p_w, label_w],
            colors=[CONTACT_COLOR],
            radii=rr.Radius.ui_points(4.0),
            labels=["", f"contact, t = {contact.t_s:.2f} s"],
            show_labels=True,
        ),
    )
    arms = CONTACT_CROSS_M * np.eye(3)
    rec.log(
        entity.NAV_CONTACT_CROSS,
        rr.LineStrips3D(
            [*(np.array([p_w - a, p_w + a]) for a in arms), np.array([p_w, label_w])],
            colors=[CONTACT_COLOR],
            radii=PLAN_UI_POINTS,
        ),
    )
    rec.log(entity.NAV_CONTACT_MARK, rr.Scalars(0.0))
    rec.log(entity.NAV_CONTACT_LEVEL, rr.Scalars(0.0))
    rec.reset_time()


def send_navigation(rec: rr.RecordingStream, result: RunResult) -> None:
    """Everything a navigating flight's recording adds (see the module); nothing for any
    other flight.

    Parameters
    ----------
    rec : rerun.RecordingStream
    result : RunResult
        The finished run: its ``navigation`` has one ``NavigationTick`` per tick of
        ``ticks``, in order (``scenarios.run.runner``).
    """
    nav = result.navigation
    if nav is None:
        return
    assert len(nav.ticks) == len(result.ticks), "one navigation tick per camera tick"
    methods = sorted({m for k in nav.ticks for m in k.obstacle_methods})
    _log_styles(rec, methods)
    _log_goal(rec, np.asarray(result.spec.flight.goal_w, dtype=np.float64))
    if nav.ticks:
        _send_ticks(rec, result, nav, methods)
    _send_contact(rec, result, nav)
