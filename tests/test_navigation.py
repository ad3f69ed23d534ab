"""Closed-loop navigation (``flight.mode = "navigate"``) end to end: the built-ins' outcomes as
their JSON reports them, checked against the simulator's truth; random cones on the line that
the depth image's map always avoids; and bad navigate flights refused on the command line.

The built-ins run once per session (``builtin_runs`` in conftest.py, at the test camera rate).
"""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from scenarios.cli import main
from scenarios.scenario.builtin import load
from scenarios.scenario.schema import ESTIMATE_MISTAKES
from scenarios.scenario.spec import GOAL_RADIUS_M
from sim.world import CONE_MESH_SEGMENTS, World
from vnav.cone import TRAFFIC_CONE
from vnav.diagnose import hypothesis_names

NAVIGATING = ("avoid", "avoid-naive", "avoid-yawed")


def _nav(builtin_runs, name: str) -> dict:
    """The navigation section of ``name``'s JSON file, as written."""
    report = json.loads(builtin_runs[name].json_path.read_text(encoding="utf-8"))
    return report["navigation"]


def _cone_radius_m(z_m: float) -> float:
    """The cone body's radius at height ``z_m`` above the ground (vnav.cone.TRAFFIC_CONE: a
    circle of body_radius_m on the base plate, narrowing linearly to the apex)."""
    c = TRAFFIC_CONE
    return c.body_radius_m * (c.height_m - z_m) / (c.height_m - c.base_thickness_m)


@pytest.mark.parametrize("name", NAVIGATING)
def test_builtin_min_clearance_bounds_every_ticks(builtin_runs, name):
    """The flight's smallest true clearance (every physics step) is at most every camera
    tick's, and negative exactly when the drone touched a cone."""
    nav = _nav(builtin_runs, name)
    per_tick = nav["per_tick"]["min_clearance_true_m"]
    assert per_tick and nav["min_clearance_m"] <= min(per_tick)
    assert (nav["min_clearance_m"] <= 0.0) == nav["collided"]


def test_builtin_avoid_reaches_the_goal_round_the_cone(builtin_runs):
    nav = _nav(builtin_runs, "avoid")
    spec = builtin_runs["avoid"].spec
    assert nav["reached_goal"] and not nav["collided"]
    assert nav["first_contact_s"] is None and nav["first_contact_point_w"] is None
    assert nav["min_clearance_m"] >= 0.3
    assert nav["final_distance_to_goal_m"] <= GOAL_RADIUS_M
    # It went round: longer than the straight line, less the goal's radius.
    assert nav["path_length_m"] > spec.flight.straight_m - GOAL_RADIUS_M
    # Where the drone ended, from the pose stream (noise-free here: the truth; the drone is
    # held where the flight ended while the last images arrive): within the goal radius.
    result = builtin_runs["avoid"].result
    assert spec.noise.position_std_m == 0.0 and spec.noise.attitude_std_deg == 0.0
    last_w = result.poses.T_w_b[-1, :3, 3]
    assert np.linalg.norm(last_w - np.array(spec.flight.goal_w)) <= GOAL_RADIUS_M
    assert result.poses.stamps_s[-1] >= nav["time_to_goal_s"]
    # The depth image mapped one cone, where it stands (within depth_image's accuracy here).
    obstacles = result.navigation.ticks[-1].obstacles_w
    cone_w = np.array(spec.scene.cones_w[0])
    assert len(obstacles) == 1 and np.linalg.norm(obstacles[0, :2] - cone_w[:2]) < 0.1


@pytest.mark.parametrize("name", ["avoid-naive", "avoid-yawed"])
def test_builtin_wrong_map_flies_into_the_cone_touching_its_surface(builtin_runs, name):
    """MuJoCo's contact point lies on the cone's body: its distance from the cone's axis at
    its height is the radius of vnav.cone's profile there, within what the collision can add:

    - a contact is found the physics step it starts, so the surfaces overlap by at most one
      step's travel, ``v dt`` (v measured here from the truth), and MuJoCo's point lies midway:
      within ``v dt / 2`` of the surface;
    - the mesh is a 64-gon (sim.world.cone_mesh_vertices), inside the circle by at most
      ``r (1 - cos(pi / 64))``;
    - a distance along the slanted surface's normal is ``1 / cos(half angle)`` as long
      horizontally.
    """
    run = builtin_runs[name]
    nav = _nav(builtin_runs, name)
    assert nav["collided"] and not nav["reached_goal"]
    assert nav["first_contact_cone"] == 0 and nav["min_clearance_m"] < 0.0
    p_w = np.array(nav["first_contact_point_w"])
    cone_w = np.array(run.spec.scene.cones_w[0])
    c = TRAFFIC_CONE
    assert c.base_thickness_m < p_w[2] < c.height_m  # the conical body, not the base plate
    ticks = run.result.ticks
    v_mps = np.linalg.norm(ticks[-1].T_w_b[:3, 3] - ticks[-2].T_w_b[:3, 3]) / (
        ticks[-1].t_s - ticks[-2].t_s
    )
    assert v_mps < 1.5 * run.spec.flight.speed_mps  # flying at about its speed
    dt_s = float(World.from_config(run.spec.scene).model.opt.timestep)
    half_angle = math.atan2(c.body_radius_m, c.height_m - c.base_thickness_m)
    sag_m = c.body_radius_m * (1.0 - math.cos(math.pi / CONE_MESH_SEGMENTS))
    tolerance_m = (1.5 * run.spec.flight.speed_mps * dt_s / 2.0 + sag_m) / math.cos(half_angle)
    from_axis_m = float(np.linalg.norm(p_w[:2] - cone_w[:2]))
    assert abs(from_axis_m - _cone_radius_m(p_w[2])) <= tolerance_m, (from_axis_m, tolerance_m)
    # It touched the cone the run says, at the time it says: the flight ended there.
    assert nav["first_contact_s"] <= ticks[-1].t_s + 1.0 / run.spec.camera_rate_hz


def test_builtin_naive_map_stays_empty(builtin_runs):
    """The naive chain puts the cone in the sky: no tick maps it, the plan stays straight."""
    nav = _nav(builtin_runs, "avoid-naive")
    assert set(nav["per_tick"]["mapped_cones"]) == {0}
    rejected_in_sky = [
        d.estimates_w["naive"][2]
        for t in builtin_runs["avoid-naive"].result.ticks
        for d in t.detections
        if "naive" in d.estimates_w
    ]
    assert rejected_in_sky and min(rejected_in_sky) > 0.5 + 0.5  # above altitude + margin


def test_builtin_avoid_yawed_maps_a_phantom_off_to_the_side(builtin_runs):
    """The lecture's other case: heading north (yaw 90 deg), the body-frame numbers taken for
    world numbers put the cone along world x, as far to the drone's right as it really is
    ahead; the planner keeps away from phantoms never in its way, and flies straight."""
    run = builtin_runs["avoid-yawed"]
    nav = _nav(builtin_runs, "avoid-yawed")
    assert nav["estimate"] == "mistake:body-rotation-dropped"
    spec, record = run.spec, run.result.navigation
    start_w, goal_w = np.array(spec.flight.start_w), np.array(spec.flight.goal_w)
    cone_w = np.array(spec.scene.cones_w[0])
    assert math.isclose(spec.flight.start_yaw_rad, math.pi / 2)
    # The first tick, the drone at rest at the start, level and heading north: the phantom is
    # the true cone turned -90 deg about the start (x <- y, y <- -x), within depth_image's error.
    ahead_m = cone_w[:2] - start_w[:2]
    phantom_xy = start_w[:2] + np.array([ahead_m[1], -ahead_m[0]])
    first = record.ticks[0].obstacles_w
    assert len(first) == 1 and np.linalg.norm(first[0, :2] - phantom_xy) < 0.1
    assert np.linalg.norm(first[0, :2] - cone_w[:2]) > 10.0  # nowhere near the cone
    # Every phantom stays beyond the clearance from the straight line (x = 0): never in the
    # way, so each plan is the straight line from the estimated position to the goal.
    for tick in record.ticks:
        assert np.all(np.abs(tick.obstacles_w[:, 0] - start_w[0]) > spec.flight.clearance_m)
        straight_m = np.linalg.norm(goal_w[:2] - tick.position_w_est[:2])
        assert tick.plan_length_m == pytest.approx(straight_m, abs=1e-9)
        assert np.all(tick.obstacles_w[:, 0] > 0.0)  # all on the drone's right (east)


def test_every_mistake_is_a_valid_estimate():
    """``mistake:<name>`` exists for every mistake of the doctor, none for the correct chain."""
    assert sorted(ESTIMATE_MISTAKES.values()) == sorted(set(hypothesis_names()) - {"correct"})
    assert "mistake:body-rotation-dropped" in ESTIMATE_MISTAKES
    assert " " not in "".join(ESTIMATE_MISTAKES)


# ------------------------------------------------------------------ random cones on the line


def _navigate_toml(
    name: str,
    cone_xy: tuple[float, float],
    goal_xy: tuple[float, float],
    estimate: str = "depth_image",
    extra: str = "",
) -> str:
    return textwrap.dedent(f"""\
        name = "{name}"
        camera_rate_hz = 5.0

        [camera]
        pitch_down_deg = 15.0

        [[cones]]
        position_w = [{cone_xy[0]!r}, {cone_xy[1]!r}, 0.0]

        [flight]
        mode = "navigate"
        start_w = [0.0, 0.0, 0.5]
        goal_w = [{goal_xy[0]!r}, {goal_xy[1]!r}, 0.5]
        speed_mps = 2.0
        clearance_m = 1.0
        estimate = "{estimate}"
        {extra}
        [[checks]]
        kind = "reached_goal"
        limit_m = {GOAL_RADIUS_M}

        [[checks]]
        kind = "no_collision"
        limit = 0
        """)


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_depth_image_map_never_collides_with_a_random_cone_on_the_line(tmp_path, capsys, seed):
    """A cone 4-7 m along a 10 m line of random heading, up to 0.6 m off it (seeded): flying
    on the depth image's map, the drone reaches the goal without touching it."""
    rng = np.random.default_rng(seed)
    heading = rng.uniform(-math.pi, math.pi)
    along_m, off_m = rng.uniform(4.0, 7.0), rng.uniform(-0.6, 0.6)
    u = np.array([math.cos(heading), math.sin(heading)])
    left = np.array([-u[1], u[0]])
    cone_xy = along_m * u + off_m * left
    goal_xy = 10.0 * u
    path = tmp_path / "line.toml"
    path.write_text(
        _navigate_toml(f"line-{seed}", tuple(map(float, cone_xy)), tuple(map(float, goal_xy)))
    )
    status = main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet"])
    nav = json.loads((tmp_path / "out" / f"line-{seed}.json").read_text())["navigation"]
    assert status == 0, (capsys.readouterr(), nav)
    assert nav["reached_goal"] and not nav["collided"] and nav["min_clearance_m"] > 0.0
    assert nav["final_distance_to_goal_m"] <= GOAL_RADIUS_M
    assert max(nav["per_tick"]["mapped_cones"]) == 1  # one cone, one obstacle


# ------------------------------------------------------------------ bad input


_GOOD = _navigate_toml("bad", (5.0, 0.0), (10.0, 0.0))


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (("goal_w = [10.0, 0.0, 0.5]", "goal_w = [0.0, 0.0, 0.5]"), r"flight\.goal_w: must be"),
        (("goal_w = [10.0, 0.0, 0.5]", "goal_w = [10.0, 0.0, -1.0]"), r"flight\.goal_w: must be"),
        (
            ('estimate = "depth_image"', 'estimate = "telepathy"'),
            r"flight\.estimate: must be one of \[.*'depth_image'.*"
            r"'mistake:body-rotation-dropped'.*\], got 'telepathy'",
        ),
        (
            ('estimate = "depth_image"', 'estimate = "mistake:correct"'),
            r"flight\.estimate: must be one of .*got 'mistake:correct'",
        ),
        (("clearance_m = 1.0", "clearance_m = 0.0"), r"flight\.clearance_m: must be > 0"),
        (("clearance_m = 1.0", "clearance_m = -2.0"), r"flight\.clearance_m: must be > 0"),
        (
            ("speed_mps = 2.0", "speed_mps = 2.0\nkeyframes = []"),
            r"flight\.keyframes: unknown key",
        ),
    ],
)
def test_bad_navigate_flight_exit_2_one_line(tmp_path, capsys, change, message):
    old, new = change
    assert old in _GOOD
    bad = tmp_path / "bad.toml"
    bad.write_text(_GOOD.replace(old, new))
    out = tmp_path / "out"
    assert main(["run", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert re.search(message, err), err
    assert not out.exists() or not any(out.iterdir())


def test_bad_navigate_flight_in_a_process(tmp_path):
    """The installed command: exit 2, one line on stderr, no traceback, nothing written."""
    bad = tmp_path / "bad.toml"
    bad.write_text(_GOOD.replace("clearance_m = 1.0", "clearance_m = 0.0"))
    out = tmp_path / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "scenarios", "run", str(bad), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
        env=os.environ | {"PYTHONWARNINGS": "ignore"},
    )
    assert proc.returncode == 2, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and "Traceback" not in proc.stderr
    assert "flight.clearance_m" in proc.stderr
    assert not out.exists() or not any(out.iterdir())


def test_yawed_builtin_loads_its_mistake():
    assert load("avoid-yawed").flight.estimate == "mistake:body-rotation-dropped"
