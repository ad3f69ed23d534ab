"""A navigating flight's recording shows its closed loop, read back from the ``avoid`` and
``avoid-naive`` built-ins' ``.rrd`` and compared with what the run recorded and reported:
the plan at every camera tick, the map with its keep-out circles in the colour of the method
that made it, the true clearance against the report and the geometry, the contact where
MuJoCo found it, and the outcome in words; other recordings hold none of it."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import read_rows

from scenarios.record.viewer import entity
from scenarios.scenario import builtin
from vnav.cone import TRAFFIC_CONE
from vnav.methods import method

FLOAT32_ATOL = 1e-5
"""Rerun stores positions as float32: a few micrometres at 20 m."""
NAVIGATING = tuple(n for n in builtin.names() if builtin.load(n).flight.mode == "navigate")


def _report(run) -> dict:
    return json.loads(run.json_path.read_text())["navigation"]


def _rows(run, path: str) -> list[dict]:
    """The rows logged at ``path`` on a timeline (not the static ones), in tick order."""
    rows = [r for r in read_rows(run.rrd, path) if "tick" in r]
    return sorted(rows, key=lambda r: r["tick"])


def _scalars(run, path: str) -> dict[int, float]:
    return {r["tick"]: r["Scalars:scalars"][0] for r in _rows(run, path)}


def _rgba(packed: int) -> tuple[int, int, int]:
    """Rerun's packed 0xRRGGBBAA colour as (r, g, b)."""
    return ((packed >> 24) & 0xFF, (packed >> 16) & 0xFF, (packed >> 8) & 0xFF)


def _static(run, path: str, column: str):
    return next(r[column] for r in read_rows(run.rrd, path) if column in r and "tick" not in r)


@pytest.mark.parametrize("name", NAVIGATING)
def test_plan_is_logged_at_every_tick_from_the_estimated_position_to_the_goal(builtin_runs, name):
    """One plan per camera tick (the report's ticks), each the run's, at the flight altitude,
    from the drone's estimated position to the report's goal, drawn with its estimated
    position; its length per tick is the report's."""
    run = builtin_runs[name]
    nav, report = run.result.navigation, _report(run)
    rows = _rows(run, entity.NAV_PLAN)
    assert len(rows) == len(nav.ticks) == len(report["per_tick"]["t_s"])
    goal_w = np.array(report["goal_w"])
    positions = _rows(run, entity.NAV_POSITION_EST)
    for row, record, k, t_s, position in zip(
        rows, run.result.ticks, nav.ticks, report["per_tick"]["t_s"], positions, strict=True
    ):
        assert row["tick"] == record.tick
        assert abs(row["sim_time"] - round(t_s * 1e9)) <= 1
        (plan_w,) = (np.array(s) for s in row["LineStrips3D:strips"])
        np.testing.assert_allclose(plan_w, k.plan_w, atol=FLOAT32_ATOL)
        np.testing.assert_allclose(plan_w[:, 2], goal_w[2], atol=FLOAT32_ATOL)
        np.testing.assert_allclose(plan_w[-1], goal_w, atol=FLOAT32_ATOL)
        np.testing.assert_allclose(plan_w[0, :2], k.position_w_est[:2], atol=FLOAT32_ATOL)
        np.testing.assert_allclose(position["Points3D:positions"], [k.position_w_est], atol=1e-5)
    lengths = _scalars(run, entity.NAV_PLAN_LENGTH)
    assert list(lengths.values()) == pytest.approx(report["per_tick"]["plan_length_m"], abs=1e-8)
    for row, length_m in zip(rows, lengths.values(), strict=True):
        plan_w = np.array(row["LineStrips3D:strips"][0], dtype=np.float64)
        assert np.linalg.norm(np.diff(plan_w, axis=0), axis=1).sum() == pytest.approx(length_m)


def test_mapped_cone_and_its_keep_out_circle_in_the_methods_colour(builtin_runs):
    """``avoid``'s map holds the cone it saw at each tick (the report's count), on the true
    cone, coloured as its method; its keep-out circle lies at the report's ``clearance_m``
    from the mapped axis, at the flight altitude, with the axis drawn up through it."""
    run = builtin_runs["avoid"]
    report = _report(run)
    m = report["estimate"]
    color = method(m).color_rgb
    obstacles = _rows(run, entity.nav_obstacles(m))
    counts = [len(r.get("Points3D:positions") or []) for r in obstacles]
    assert counts == report["per_tick"]["mapped_cones"]
    assert max(counts) == 1
    cone_w = np.array(run.spec.scene.cones_w[0])
    altitude_m, clearance_m = report["goal_w"][2], report["clearance_m"]
    for row, k in zip(_rows(run, entity.nav_keep_out(m)), run.result.navigation.ticks, strict=True):
        strips = [np.array(s) for s in row.get("LineStrips3D:strips") or []]
        assert len(strips) == 2 * len(k.obstacles_w)
        for p_w, circle, axis in zip(k.obstacles_w, strips[::2], strips[1::2], strict=True):
            # The depth image's map sits on the true cone: within its contract, a few cm.
            assert np.linalg.norm(p_w[:2] - cone_w[:2]) < 0.05
            radius_m = np.linalg.norm(circle[:, :2] - p_w[:2], axis=1)
            np.testing.assert_allclose(radius_m, clearance_m, atol=FLOAT32_ATOL)
            np.testing.assert_allclose(circle[:, 2], altitude_m, atol=FLOAT32_ATOL)
            np.testing.assert_allclose(axis[0], p_w, atol=FLOAT32_ATOL)
            np.testing.assert_allclose(axis[1, :2], p_w[:2], atol=FLOAT32_ATOL)
            assert axis[1, 2] > altitude_m
    for path, column in (
        (entity.nav_obstacles(m), "Points3D:colors"),
        (entity.nav_keep_out(m), "LineStrips3D:colors"),
    ):
        assert [_rgba(c) for c in _static(run, path, column)] == [color]


def test_naive_map_is_empty_and_the_panel_says_why(builtin_runs):
    """``avoid-naive``'s map stays empty (the report's counts): nothing of it is drawn, and
    the state panel counts the naive estimates it dropped, above the flight band."""
    run = builtin_runs["avoid-naive"]
    report = _report(run)
    assert set(report["per_tick"]["mapped_cones"]) == {0}
    assert not read_rows(run.rrd, "world/navigation/obstacles/**")
    assert not read_rows(run.rrd, "world/navigation/keep_out/**")
    panels = [r["TextDocument:text"][0] for r in _rows(run, entity.STATE)]
    dropped = np.cumsum([k.rejected for k in run.result.navigation.ticks])
    assert dropped[-1] > 0
    # The naive bases dropped: those outside the flight band (docs/CONVENTIONS.md,
    # "Navigation"), from 0.5 m under the ground to 0.5 m over the drone's altitude.
    naive_z = np.concatenate([t.estimates_w("naive")[:, 2] for t in run.result.ticks])
    outside = (naive_z < -0.5) | (naive_z > report["goal_w"][2] + 0.5)
    assert dropped[-1] == np.count_nonzero(outside)
    for text, n in zip(panels, dropped, strict=True):
        assert "naive's map: 0 cones" in text
        assert (f"{n} estimate(s) dropped so far" in text) == (n > 0)


@pytest.mark.parametrize("name", NAVIGATING)
def test_true_clearance_plot_is_the_reports_and_below_the_axis_distance(builtin_runs, name):
    """The plotted true clearance is the report's per tick; the planner's ``clearance_m`` is
    the report's; the drone's centre to the nearest cone axis, which the plot sets beside it,
    is at least the true clearance wherever the drone flies within the cone's height (its
    centre and the axis there lie inside the two geometries MuJoCo measures between)."""
    run = builtin_runs[name]
    report = _report(run)
    clearance = _scalars(run, entity.NAV_CLEARANCE)
    expected = report["per_tick"]["min_clearance_true_m"]
    assert list(clearance.values()) == pytest.approx(expected, abs=1e-9)
    kept = _scalars(run, entity.NAV_CLEARANCE_KEPT)
    assert set(kept.values()) == {report["clearance_m"]}
    axis = _scalars(run, entity.NAV_AXIS_DISTANCE)
    cones_xy = np.array(run.spec.scene.cones_w)[:, :2]
    for t in run.result.ticks:
        p_w = t.T_w_b[:3, 3]
        truth_m = np.min(np.linalg.norm(cones_xy - p_w[:2], axis=1))
        assert axis[t.tick] == pytest.approx(truth_m)
        if 0.0 < p_w[2] < TRAFFIC_CONE.height_m:
            assert axis[t.tick] >= clearance[t.tick]
    levels = _scalars(run, entity.NAV_CONTACT_LEVEL)
    assert set(levels.values()) == {0.0}
    if report["collided"]:
        assert min(clearance.values()) > report["min_clearance_m"]  # the contact is after
    else:
        assert min(clearance.values()) >= report["min_clearance_m"] - 1e-9


def test_contact_is_marked_where_and_when_mujoco_found_it(builtin_runs):
    """``avoid-naive``'s contact: a point at the report's contact point, named with its time,
    from the contact's time on (``sim_time``; on ``tick`` the tick after the last), a mark on
    the clearance plot at 0 then; the recording opens there, and the scenario document and
    the state panel say "collision with cone 0 at t = ... s"."""
    run = builtin_runs["avoid-naive"]
    report = _report(run)
    assert report["collided"]
    t_ns = round(report["first_contact_s"] * 1e9)
    after_last = run.result.ticks[-1].tick + 1
    (row,) = _rows(run, entity.NAV_CONTACT)
    assert abs(row["sim_time"] - t_ns) <= 1 and row["tick"] == after_last
    np.testing.assert_allclose(
        row["Points3D:positions"][0], report["first_contact_point_w"], atol=FLOAT32_ATOL
    )
    assert f"contact, t = {report['first_contact_s']:.2f} s" in row["Points3D:labels"]
    (cross,) = _rows(run, entity.NAV_CONTACT_CROSS)
    assert cross["sim_time"] == row["sim_time"]
    centres = [np.mean(np.array(s), axis=0) for s in cross["LineStrips3D:strips"][:3]]
    np.testing.assert_allclose(centres, [report["first_contact_point_w"]] * 3, atol=FLOAT32_ATOL)
    (mark,) = _rows(run, entity.NAV_CONTACT_MARK)
    assert mark["sim_time"] == row["sim_time"] and mark["Scalars:scalars"] == [0.0]
    moment = {
        k.split(":")[-1]: v[0]
        for r in read_rows(run.rrd, entity.MOMENT)
        for k, v in r.items()
        if k.split(":")[-1] in ("camera_tick", "sim_time_s")
    }
    assert moment["camera_tick"] == after_last
    assert moment["sim_time_s"] == pytest.approx(report["first_contact_s"], abs=1e-9)
    words = (
        f"collision with cone {report['first_contact_cone']} at "
        f"t = {report['first_contact_s']:.2f} s"
    )
    document = [r["TextDocument:text"][0] for r in read_rows(run.rrd, entity.DESCRIPTION)][-1]
    assert f"## Navigation: {words}" in document
    assert f"smallest true clearance {report['min_clearance_m']:.3f} m" in document
    panels = [r["TextDocument:text"][0] for r in _rows(run, entity.STATE)]
    assert all(f"outcome   {words}" in text for text in panels)


def test_goal_reached_is_said_and_no_contact_drawn(builtin_runs):
    """``avoid`` reaches its goal: no contact is drawn, the goal is (static, named, with its
    radius), and the document and panel say when it was reached."""
    run = builtin_runs["avoid"]
    report = _report(run)
    assert report["reached_goal"] and not report["collided"]
    assert not _rows(run, entity.NAV_CONTACT) and not _rows(run, entity.NAV_CONTACT_MARK)
    assert _static(run, entity.NAV_GOAL, "Points3D:positions") == [report["goal_w"]]
    assert _static(run, entity.NAV_GOAL, "Points3D:labels") == ["goal"]
    words = f"reached the goal at t = {report['time_to_goal_s']:.2f} s"
    document = [r["TextDocument:text"][0] for r in read_rows(run.rrd, entity.DESCRIPTION)][-1]
    assert f"## Navigation: {words}" in document
    panels = [r["TextDocument:text"][0] for r in _rows(run, entity.STATE)]
    assert all(words in text for text in panels)


@pytest.mark.parametrize("name", [n for n in builtin.names() if n not in NAVIGATING])
def test_other_recordings_hold_no_navigation(builtin_runs, name):
    """A flight that does not navigate draws and plots nothing of it, and its state panel
    has no navigation block."""
    run = builtin_runs[name]
    assert run.result.navigation is None
    assert not read_rows(run.rrd, "world/navigation/**")
    assert not read_rows(run.rrd, "metrics/navigation/**")
    panels = [r["TextDocument:text"][0] for r in _rows(run, entity.STATE)]
    assert panels and not any("navigate  plan" in text for text in panels)
