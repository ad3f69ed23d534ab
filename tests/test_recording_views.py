"""What a student reads off the recording's views, read back from each built-in's ``.rrd``:
names that do not pile up, camera axes drawn unlike the body's, a pin at every cone, the legend
of the 3D views' colours, NEES values above the plot's top marked, and the instant the 3D views
are framed for (``show_at_s``)."""

from __future__ import annotations

import itertools

import cv2
import numpy as np
import pytest
from helpers import read_rows

from scenarios.record.recording import nees_off_top
from scenarios.record.viewer import (
    AXIS_LENGTH_M,
    CAMERA_AXES_UI_POINTS,
    DECLARED_MOUNT_COLOR,
    FRAME,
    NEES_CLIP_MARK,
    NEES_TOP,
    NEWEST_POSE_COLOR,
    PIN_COLOR,
    PIN_TOP_M,
    PLAN_COLOR,
    RAY_COLOR,
    RECOVERED_MOUNT_COLOR,
    TRUTH_COLOR,
    entity,
)
from scenarios.scenario import builtin
from scenarios.scenario.spec import ScenarioError, from_dict
from vnav import quat, se3
from vnav.cone import TRAFFIC_CONE
from vnav.methods import METHODS

FLOAT32_ATOL = 1e-5
NAME_SPACING_M = 0.2
"""The least distance between two names in the 3D views, m: about 20 points in the drone
close-up (2.6 m away), 45 in the mounts close-up (1.2 m), a name's height; before, the
camera's name sat 0.16 m from the body's and cone 0's on the world's origin."""

NAMES = builtin.names()


def _static(rrd, path: str, column: str):
    """The value of a static column logged at ``path`` (None if there is none)."""
    return next((r[column] for r in read_rows(rrd, path) if column in r and "tick" not in r), None)


def _pose(row) -> np.ndarray:
    R = quat.to_matrix(np.asarray(row["Transform3D:quaternion"][0]), normalize=True)
    return se3.make(R, row["Transform3D:translation"][0])


def _moment(rrd) -> dict:
    (row,) = [r for r in read_rows(rrd, entity.MOMENT) if "camera_tick" in r]
    return {
        k.split(":")[-1]: v[0]
        for k, v in row.items()
        if k.split(":")[-1] in ("camera_tick", "sim_time_s")
    }


def _names_w(run) -> dict[str, np.ndarray]:
    """Where each name of the 3D views is drawn at the recording's moment, world frame: a
    frame's name at its origin (``TransformAxes3D`` with ``show_frame``), an arrow's at its
    middle, a point's at the point."""
    rrd = run.rrd
    tick = _moment(rrd)["camera_tick"]
    # The viewer shows each entity's latest row at or before the moment (a navigating
    # flight's contact is after the last tick).
    body_rows = [r for r in read_rows(rrd, entity.BODY) if r.get("tick", tick + 1) <= tick]
    T_w_b = _pose(max(body_rows, key=lambda r: r["tick"]))
    mount_rows = [r for r in read_rows(rrd, entity.CAMERA) if r.get("Transform3D:translation")]
    at_tick = [r for r in mount_rows if r.get("tick") == tick]
    T_b_c = _pose(at_tick[0] if at_tick else mount_rows[0])
    T_w_c = T_w_b @ T_b_c
    frames = {}
    for path, axes in (
        (entity.CAMERA_DECLARED, entity.CAMERA_DECLARED_AXES),
        (entity.CAMERA_RECOVERED, entity.CAMERA_RECOVERED_AXES),
    ):
        rows = [r for r in read_rows(rrd, path) if r.get("Transform3D:translation")]
        if rows:
            frames[axes] = T_w_b @ _pose(rows[0])
    # A run with an [imu]: the IMU's name and its declared mount's, each in its own frame.
    named_points = [(entity.CONE_PIN_HEADS, np.eye(4)), (entity.CAMERA_NAME, T_w_c)]
    for path, name_path in (
        (entity.IMU, entity.IMU_NAME),
        (entity.IMU_DECLARED, entity.IMU_DECLARED_NAME),
    ):
        rows = [r for r in read_rows(rrd, path) if r.get("Transform3D:translation")]
        if rows:
            named_points.append((name_path, T_w_b @ _pose(rows[0])))
    names: dict[str, np.ndarray] = {}
    for name, path, origin_w in (
        ("world", entity.WORLD, np.zeros(3)),
        ("body", entity.BODY, T_w_b[:3, 3]),
    ):
        if _static(rrd, path, "TransformAxes3D:show_frame") == [True]:
            names[name] = origin_w
    for path, T_w_f in frames.items():
        vectors = np.array(_static(rrd, path, "Arrows3D:vectors"))
        for label, v in zip(_static(rrd, path, "Arrows3D:labels"), vectors, strict=True):
            if label:
                names[label] = se3.apply(T_w_f, 0.5 * v)
    for path, T_w_f in named_points:
        points = np.array(_static(rrd, path, "Points3D:positions"))
        for label, p in zip(_static(rrd, path, "Points3D:labels"), points, strict=True):
            if label:
                names[label] = se3.apply(T_w_f, p)
    # A navigating flight's goal (static) and contact (from its time on), in the world frame.
    labelled = [r for r in read_rows(rrd, entity.NAV_GOAL) if "Points3D:labels" in r]
    labelled += [
        r
        for r in read_rows(rrd, entity.NAV_CONTACT)
        if "Points3D:labels" in r and r.get("tick", tick) <= tick
    ]
    for row in labelled:
        for label, p in zip(row["Points3D:labels"], row["Points3D:positions"], strict=True):
            if label:
                names[label] = np.array(p)
    return names


@pytest.mark.parametrize("name", NAMES)
def test_names_in_the_3d_views_do_not_pile_up(builtin_runs, name):
    """Every name drawn in 3D (world, body, camera, cone 0 and, calibrated, the two mounts;
    navigating, the goal and the contact) stands at least ``NAME_SPACING_M`` from every other
    at the instant the views show; the cones' truth points carry none (eight of them from afar
    were one blot)."""
    run = builtin_runs[name]
    names = _names_w(run)
    assert {"world", "body", "camera", "cone 0"} <= set(names)
    if run.spec.checks_calibration:
        assert {"declared", "recovered"} <= set(names)
    if run.spec.scene.imu is not None:
        assert {"imu (true)", "imu declared"} <= set(names)
    if run.result.navigation is not None:
        assert "goal" in names
        contact = run.result.navigation.contact
        if contact is not None:
            assert f"contact, t = {contact.t_s:.2f} s" in names
    for (a, p), (b, q) in itertools.combinations(names.items(), 2):
        assert np.linalg.norm(p - q) >= NAME_SPACING_M, (a, b, p, q)
    assert _static(run.rrd, entity.TRUTH, "Points3D:labels") is None


@pytest.mark.parametrize("name", NAMES)
def test_camera_axes_drawn_thin_and_unlike_the_bodys(builtin_runs, name):
    """The body's axes are a ``TransformAxes3D`` (thick, named at the origin); the camera's
    are three thin arrows (a radius on screen, not in metres) along the camera's own axes,
    half the body's length, and its name is past the tip of the optical axis, so that the two
    frames read apart."""
    rrd = builtin_runs[name].rrd
    assert _static(rrd, entity.BODY, "TransformAxes3D:axis_length") == [AXIS_LENGTH_M[FRAME.BODY]]
    assert _static(rrd, entity.CAMERA, "TransformAxes3D:axis_length") is None
    assert _static(rrd, entity.CAMERA_AXES, "CoordinateFrame:frame") == [FRAME.CAMERA]
    vectors = np.array(_static(rrd, entity.CAMERA_AXES, "Arrows3D:vectors"))
    np.testing.assert_allclose(vectors, AXIS_LENGTH_M[FRAME.CAMERA] * np.eye(3), atol=1e-6)
    assert AXIS_LENGTH_M[FRAME.CAMERA] <= 0.5 * AXIS_LENGTH_M[FRAME.BODY]
    # Rerun stores a radius in UI points as its negative.
    assert _static(rrd, entity.CAMERA_AXES, "Arrows3D:radii") == pytest.approx(
        [-CAMERA_AXES_UI_POINTS]
    )
    assert _static(rrd, entity.CAMERA_AXES, "Arrows3D:labels") is None
    assert _static(rrd, entity.CAMERA_NAME, "CoordinateFrame:frame") == [FRAME.CAMERA]
    (name_c,) = _static(rrd, entity.CAMERA_NAME, "Points3D:positions")
    assert name_c[:2] == [0.0, 0.0] and name_c[2] > AXIS_LENGTH_M[FRAME.CAMERA]
    assert _static(rrd, entity.CAMERA_NAME, "Points3D:labels") == ["camera"]


@pytest.mark.parametrize("name", NAMES)
def test_every_cone_has_a_pin_from_its_apex(builtin_runs, name):
    """Each cone gets a line from its apex straight up to ``PIN_TOP_M`` and a head of fixed
    size on screen there: found from afar, where the cone itself is a few pixels."""
    run = builtin_runs[name]
    cones_w = np.array(run.spec.scene.cones_w, dtype=np.float64)
    strips = [np.array(s) for s in _static(run.rrd, entity.CONE_PINS, "LineStrips3D:strips")]
    assert len(strips) == len(cones_w)
    for strip, cone in zip(strips, cones_w, strict=True):
        np.testing.assert_allclose(
            strip[0], cone + np.array([0.0, 0.0, TRAFFIC_CONE.height_m]), atol=FLOAT32_ATOL
        )
        np.testing.assert_allclose(strip[1], [cone[0], cone[1], PIN_TOP_M], atol=FLOAT32_ATOL)
    heads = np.array(_static(run.rrd, entity.CONE_PIN_HEADS, "Points3D:positions"))
    np.testing.assert_allclose(heads, [s[1] for s in strips], atol=FLOAT32_ATOL)
    assert _static(run.rrd, entity.CONE_PIN_HEADS, "Points3D:radii")[0] < 0.0  # UI points
    assert PIN_TOP_M > TRAFFIC_CONE.height_m


def _has_colour(image_rgb: np.ndarray, rgb, tolerance: int = 12, at_least: int = 6) -> bool:
    close = np.all(np.abs(image_rgb.astype(int) - np.array(rgb)) <= tolerance, axis=2)
    return int(close.sum()) >= at_least


@pytest.mark.parametrize("name", NAMES)
def test_legend_shows_every_colour_of_the_3d_views(builtin_runs, name):
    """The legend strip (an image over the 3D views) holds a mark of each method's colour, the
    truth's, the rays' and the pins'; the newest pose's only where images arrive late, the
    mounts' only in a calibrated run (the declared one's colour also where an IMU's declared
    mount is drawn, an ``[imu.mount_error]``)."""
    run = builtin_runs[name]
    png = _static(run.rrd, entity.LEGEND, "EncodedImage:blob")
    assert png is not None
    blob = np.asarray(png[0] if isinstance(png[0], list) else png, dtype=np.uint8)
    bgr = cv2.imdecode(blob, cv2.IMREAD_COLOR)
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    for colour in [TRUTH_COLOR, RAY_COLOR, PIN_COLOR, *(m.color_rgb for m in METHODS)]:
        assert _has_colour(rgb, colour), colour
    assert _has_colour(rgb, NEWEST_POSE_COLOR) == run.spec.timing.delivers_late
    imu = run.spec.scene.imu
    imu_declared = imu is not None and not imu.mount_error.is_zero
    assert _has_colour(rgb, DECLARED_MOUNT_COLOR) == (run.spec.checks_calibration or imu_declared)
    assert _has_colour(rgb, RECOVERED_MOUNT_COLOR) == run.spec.checks_calibration
    assert _has_colour(rgb, PLAN_COLOR) == (run.result.navigation is not None)


def test_nees_above_the_plots_top_is_marked(builtin_runs):
    """A tick's NEES above the plot's top (``NEES_TOP``) would be cut off unmarked: it gets a
    mark just under the top, and no other tick does."""
    run = builtin_runs["uncertainty"]
    for m in ("depth_image", "ground_plane", "known_height"):
        nees = {
            r["tick"]: r["Scalars:scalars"][0]
            for r in read_rows(run.rrd, entity.nees(m))
            if "tick" in r
        }
        marks = {
            r["tick"]: r["Scalars:scalars"][0]
            for r in read_rows(run.rrd, entity.nees_clipped(m))
            if "tick" in r
        }
        assert marks.keys() == nees.keys()
        for tick, value in nees.items():
            if value > NEES_TOP:
                assert marks[tick] == pytest.approx(NEES_CLIP_MARK)
            else:
                assert np.isnan(marks[tick])


def test_nees_marks_are_exactly_the_values_off_the_top():
    """The marks the recording logs: one just under the top for each value above it, none for
    a value at or under it, or none at all (a tick without an estimate)."""
    values = [1.0, NEES_TOP, NEES_TOP + 1e-9, 250.0, float("nan")]
    marks = nees_off_top(values)
    assert marks[2] == marks[3] == NEES_CLIP_MARK
    assert all(np.isnan(marks[i]) for i in (0, 1, 4))
    assert 10.0 < NEES_CLIP_MARK < NEES_TOP  # inside the plot, above its last labelled tick


@pytest.mark.parametrize("name", NAMES)
def test_moment_is_the_tick_at_show_at_s(builtin_runs, name):
    """The recording names the instant its 3D views are framed for (screenshots move the time
    cursor there): the last tick at or before the scenario's ``show_at_s``, else the last
    or, for a navigating flight that ended at a contact, the contact."""
    run = builtin_runs[name]
    moment = _moment(run.rrd)
    ticks = run.result.ticks
    nav = run.result.navigation
    if run.spec.show_at_s is None and nav is not None and nav.contact is not None:
        # The contact falls after the last tick: it is logged at the tick after it.
        assert moment["camera_tick"] == ticks[-1].tick + 1
        assert moment["sim_time_s"] == pytest.approx(nav.contact.t_s)
        return
    if run.spec.show_at_s is None:
        expected = ticks[-1]
    else:
        expected = max(
            (t for t in ticks if t.t_s <= run.spec.show_at_s + 1e-9), key=lambda t: t.t_s
        )
    assert moment["camera_tick"] == expected.tick
    assert moment["sim_time_s"] == pytest.approx(expected.t_s)


def test_show_at_s_beyond_the_run_is_refused():
    """A scenario cannot frame its views after its own end: a ScenarioError names the key."""
    data = builtin.REGISTRY["transform-composer"]()
    data["show_at_s"] = 8.5
    with pytest.raises(ScenarioError, match="show_at_s: must be at most the run's end, 8 s"):
        from_dict(data, where="x.toml")
    data["show_at_s"] = -1.0
    with pytest.raises(ScenarioError, match="show_at_s"):
        from_dict(data, where="x.toml")


def test_depth_scale_and_legend_are_drawn_once_per_process_as_a_fresh_draw():
    """The depth scale and the legend are memoised: a second call with equal (not the same)
    arguments hands out the bytes a fresh draw gives, and other arguments draw another."""
    from scenarios.record import plots
    from scenarios.record.viewer import AXES_NOTE, legend_entries

    plots.depth_scale_png.cache_clear()
    plots._legend_png.cache_clear()
    first = plots.legend_png(legend_entries(latency=True), AXES_NOTE)
    again = plots.legend_png(legend_entries(latency=True), AXES_NOTE)
    assert plots._legend_png.cache_info().hits == 1
    rows = legend_entries(latency=True)
    key = tuple(tuple((e.text, tuple(e.color_rgb), e.mark) for e in row) for row in rows)
    assert again == first == plots._legend_png.__wrapped__(key, AXES_NOTE, 200.0)
    assert plots.legend_png(legend_entries(latency=False), AXES_NOTE) != first
    scale = plots.depth_scale_png(7.5, "viridis")
    assert plots.depth_scale_png(7.5, "viridis") == scale
    assert plots.depth_scale_png.__wrapped__(7.5, "viridis") == scale
    assert plots.depth_scale_png(10.0, "viridis") != scale


def test_error_against_range_on_a_reused_figure_is_a_fresh_figures_png():
    """The plot is drawn on this process's figure of as many panels, cleared of the last
    run's artists: each PNG is, byte for byte, the one a new figure gives, whatever came
    before (a panel with no matched estimate, its note; the recovered mount's crosses)."""
    import dataclasses

    from scenarios import pipeline
    from scenarios.record import plots

    def short(name: str, duration_s: float):
        spec = dataclasses.replace(builtin.load(name), duration_s=duration_s)
        return pipeline.run(spec, seed=1).result

    frame, multi = short("frame-problem", 0.5), short("multi-cone", 1.0)
    assert not frame.errors("known_height").size  # a panel saying "no matched estimate"
    # The crosses of any run: only their drawing is compared here.
    cases = [(frame, None), (multi, frame), (multi, None), (frame, multi), (frame, None)]
    fresh = []
    for result, recovered in cases:
        plots._range_figures.clear()
        fresh.append(plots.error_against_range_png(result, recovered))
    plots._range_figures.clear()
    reused = [plots.error_against_range_png(r, rec) for r, rec in cases]
    assert len(plots._range_figures) == 1  # one figure drew them all
    assert reused == fresh
    assert len(set(fresh)) == 4  # the cases differ (the last repeats the first)


def test_ellipsoids_of_a_batch_are_each_ellipsoid_to_the_last_bit():
    """``ellipsoids_axes`` (one decomposition of a stack) against ``ellipsoid_axes`` one by
    one: full-rank, ground-plane (rank 2, exact in z), rank-1 and zero covariances, and
    eigenvector frames of both handednesses."""
    from scenarios.record.recording import ellipsoid_axes, ellipsoids_axes

    rng = np.random.default_rng(7)
    covs = []
    for rank in (3, 3, 2, 2, 1, 0) * 20:
        A = rng.normal(0.0, rng.uniform(0.01, 1.0), (3, rank))
        cov = A @ A.T
        if rank == 2:  # a ground-plane covariance: exact in z
            cov[2, :] = cov[:, 2] = 0.0
        covs.append(cov)
    half_sizes, rotations = ellipsoids_axes(np.array(covs))
    flipped = 0
    for cov, h, R in zip(covs, half_sizes, rotations, strict=True):
        h_one, R_one = ellipsoid_axes(cov.copy())
        assert np.array_equal(h, h_one) and np.array_equal(R, R_one)
        flipped += np.linalg.det(np.linalg.eigh(cov)[1]) < 0.0
    assert 0 < flipped < len(covs)  # both branches ran
    empty_h, empty_R = ellipsoids_axes(np.zeros((0, 3, 3)))
    assert empty_h.shape == (0, 3) and empty_R.shape == (0, 3, 3)


@pytest.mark.parametrize("shapes", [[(2, 3)] * 7, [(2, 3), (3, 3), (2, 3)], []])
def test_strips_sent_as_one_array_are_the_strips_sent_one_by_one(shapes):
    """``_strips`` stacks strips of one shape into one array for Rerun: the Arrow columns
    are those of the strips given one by one (strips of several shapes stay a list)."""
    import rerun as rr

    from scenarios.record.recording import _strips

    rng = np.random.default_rng(3)
    flat = [rng.normal(0.0, 5.0, shape) for shape in shapes]
    per_tick = [flat[:2], [], flat[2:]]
    got = list(_strips(per_tick))
    want = list(rr.LineStrips3D.columns(strips=flat).partition([len(t) for t in per_tick]))
    assert len(got) == len(want) == 1
    assert got[0].as_arrow_array().equals(want[0].as_arrow_array())
