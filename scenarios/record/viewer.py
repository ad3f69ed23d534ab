"""What the viewer shows and how: entity paths, frames, sizes, colours, the layout and the eye.

Everything here is a viewer concern, declared once and shared by the recording
(``scenarios.record.recording``) and the tests that read a recording back:

- ``entity``: every Rerun entity path;
- ``FRAME``: the named transform frames (the same names as ``vnav.frames`` and
  docs/CONVENTIONS.md: world, body, camera, and the image plane);
- ``AXIS_LENGTH_M``: how long each frame's drawn axes are (world > body > camera), the
  camera's drawn thin (``CAMERA_AXES_UI_POINTS``); each cone's pin (``PIN_TOP_M``);
- colours: each method's from ``vnav.methods``, the truth's, the rays', the x/y/z axes',
  the newest pose's (runs with latency: ``NEWEST_POSE_COLOR``);
- ``STREAM_*``: the pose stream's plots against the image stamps (runs with latency);
- ``blueprint``: the default layout; ``eye_for``: where the 3D view looks from, at the tick
  ``shown_tick`` picks; ``legend_entries``: the 3D views' colours, named in a strip over them;
- ``describe``: the markdown shown beside the recording, with the checks' verdicts
  (``checks_text``) once the run is judged;
- a run with an ``[imu]``: its tab (``imu_tab``: ``IMU_SERIES`` beside ``IMU_CHAIN``, the
  noise-free prediction) and its paragraph (``describe_imu``); ``imu_views`` logs them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from types import SimpleNamespace
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from scenarios.judge.checks import CheckResult, Outcome
from scenarios.scenario.schema import ESTIMATE_MISTAKES, VIEW_NAMES
from scenarios.scenario.spec import ScenarioSpec
from vnav import se3, so3
from vnav.cone import TRAFFIC_CONE
from vnav.methods import METHODS, NAIVE, NEWEST_POSE_METHOD, PREFERENCE, active_methods, method

if TYPE_CHECKING:
    from scenarios.run.records import RunResult

__all__ = [
    "AXES_NOTE",
    "AXIS_COLORS",
    "AXIS_LENGTH_M",
    "CAMERA_AXES_UI_POINTS",
    "CAMERA_NAME_Z_M",
    "CLEARANCE_COLOR",
    "CONE0_SERIES",
    "CONTACT_COLOR",
    "DECLARED_MOUNT_COLOR",
    "DEPTH_CLOUD_COLOR",
    "EXPOSURE_POSE_COLOR",
    "FRAME",
    "IMAGE_PLANE_M",
    "IMU_CHAIN",
    "IMU_CHAIN_COLOR",
    "IMU_DECLARED_NAME_X_M",
    "IMU_NAME_Z_M",
    "IMU_SERIES",
    "KEPT_COLOR",
    "MOUNT_AXIS_LENGTH_M",
    "NEES_CLIP_MARK",
    "NEES_TOP",
    "NEWEST_POSE_COLOR",
    "NEWEST_POSE_METHOD",
    "PIN_COLOR",
    "PIN_HEAD_UI_POINTS",
    "PIN_LINE_UI_POINTS",
    "PIN_TOP_M",
    "PLAN_COLOR",
    "POSE_SAMPLE_COLOR",
    "RAY_COLOR",
    "RECOVERED_MOUNT_COLOR",
    "STREAM_QUANTITIES",
    "STREAM_SERIES",
    "STREAM_WINDOW_S",
    "TRAJECTORY_COLOR",
    "TRUTH_COLOR",
    "VERDICT_WORDS",
    "VIEWS",
    "LegendEntry",
    "blueprint",
    "checks_summary",
    "checks_text",
    "describe",
    "describe_imu",
    "entity",
    "eye_for",
    "imu_series_names",
    "imu_tab",
    "legend_entries",
    "moment",
    "navigation_tab",
    "shown_tick",
]


def _part(method: str) -> str:
    """A method's name as an entity path's part: ``user:fn`` (``vnav.plugin``) as ``user_fn``,
    since Rerun escapes a colon in a path (``user\\:fn``); a built-in's name as it is."""
    return method.replace(":", "_")


def _error(method: str) -> str:
    return f"metrics/error/{_part(method)}"


def _allowed(method: str) -> str:
    return f"metrics/allowed/{_part(method)}"


def _error_recovered(method: str) -> str:
    return f"metrics/error_recovered_mount/{_part(method)}"


def _estimate(method: str) -> str:
    return f"world/cones/estimate/{_part(method)}"


def _error_segment(method: str) -> str:
    return f"world/cones/error/{_part(method)}"


def _ellipsoid(method: str) -> str:
    return f"world/cones/uncertainty/{_part(method)}"


def _nees(method: str) -> str:
    return f"metrics/nees/{_part(method)}"


def _nees_mean(method: str) -> str:
    return f"metrics/nees_mean/{_part(method)}"


def _nees_band(method: str) -> str:
    return f"metrics/nees_band/{_part(method)}"


def _nees_clipped(method: str) -> str:
    return f"metrics/nees_clipped/{_part(method)}"


def _cone0(frame_name: str) -> str:
    return f"coordinates/cone0_{frame_name}"


def _stream(quantity: str, series: str) -> str:
    return f"time/{quantity}/{series}"


MISTAKE_MAP_COLOR = (255, 140, 0)
"""A navigating flight's map made by a classic mistake (``estimate = "mistake:..."``): orange."""


def map_color(estimate: str) -> tuple[tuple[int, int, int], str]:
    """The colour (RGB, and its name in words) of the cones ``estimate`` maps: its method's,
    or orange for a classic mistake (``scenarios.scenario.schema.ESTIMATE_MISTAKES``)."""
    if estimate in ESTIMATE_MISTAKES:
        return MISTAKE_MAP_COLOR, "orange"
    m = method(estimate)
    return m.color_rgb, m.color_name


def _nav_obstacles(method: str) -> str:
    return f"world/navigation/obstacles/{_part(method)}"


def _nav_keep_out(method: str) -> str:
    return f"world/navigation/keep_out/{_part(method)}"


entity = SimpleNamespace(
    WORLD="world",
    BODY="world/body",
    DRONE="world/body/drone",
    CAMERA="world/body/camera",
    CAMERA_AXES="world/body/camera/axes",
    CAMERA_NAME="world/body/camera/name",
    CAMERA_DECLARED="world/body/camera_declared",
    CAMERA_DECLARED_AXES="world/body/camera_declared/axes",
    CAMERA_RECOVERED="world/body/camera_recovered",
    CAMERA_RECOVERED_AXES="world/body/camera_recovered/axes",
    IMAGE="world/body/camera/image",
    DEPTH="world/body/camera/depth",
    DETECTIONS="world/body/camera/detections",
    KEYPOINTS="world/body/camera/detections/keypoints",
    CONES="world/cones/mesh",
    TRUTH="world/cones/truth",
    CONE_PINS="world/cones/pins",
    CONE_PIN_HEADS="world/cones/pins/heads",
    RAYS="world/rays",
    GROUND_HITS="world/rays/ground_hits",
    NAIVE_OFFSET="world/naive_offset",
    DEPTH_CLOUD="world/depth_cloud",
    TRAJECTORY="world/trajectory",
    RANGE="metrics/range_m",
    RPY="attitude/rpy_deg",
    QUAT="attitude/quat_xyzw",
    GIMBAL_LOCK="attitude/gimbal_lock",
    QUAT_SIGN="attitude/quat_sign",
    NEWEST_ESTIMATE="world/cones/newest_pose/estimate",
    NEWEST_ERROR_SEGMENT="world/cones/newest_pose/error",
    NEWEST_ERROR="metrics/newest_pose/error",
    STATE="state",
    ERROR_VS_RANGE="plots/error_vs_range",
    DEPTH_SCALE="plots/depth_scale",
    LEGEND="plots/legend",
    MOMENT="moment",
    DESCRIPTION="description",
    POSE_STREAM="estimator/pose_stream",
    MOUNT_DECLARED="estimator/mount",
    STAMP_CAM="estimator/stamp_cam_s",
    MASKS="estimator/masks",
    TRUTH_VALUES="truth",
    NAV_PLAN="world/navigation/plan",
    NAV_POSITION_EST="world/navigation/position_est",
    NAV_GOAL="world/navigation/goal",
    NAV_CONTACT="world/navigation/contact",
    NAV_CONTACT_CROSS="world/navigation/contact/cross",
    NAV_CLEARANCE="metrics/navigation/clearance_true_m",
    NAV_CONTACT_LEVEL="metrics/navigation/contact_level_m",
    NAV_CONTACT_MARK="metrics/navigation/contact",
    NAV_AXIS_DISTANCE="metrics/navigation/axis_distance_m",
    NAV_CLEARANCE_KEPT="metrics/navigation/clearance_m",
    NAV_PLAN_LENGTH="metrics/navigation/plan_length_m",
    IMU="world/body/imu",
    IMU_AXES="world/body/imu/axes",
    IMU_NAME="world/body/imu/name",
    IMU_DECLARED="world/body/imu_declared",
    IMU_DECLARED_AXES="world/body/imu_declared/axes",
    IMU_DECLARED_NAME="world/body/imu_declared/name",
    IMU_SPECIFIC_FORCE="imu/specific_force_i",
    IMU_SPECIFIC_FORCE_CHAIN="imu/specific_force_i_noise_free",
    IMU_ANGULAR_RATE="imu/angular_rate_i",
    IMU_ANGULAR_RATE_CHAIN="imu/angular_rate_i_noise_free",
    error=_error,
    allowed=_allowed,
    error_recovered=_error_recovered,
    estimate=_estimate,
    error_segment=_error_segment,
    ellipsoid=_ellipsoid,
    nees=_nees,
    nees_mean=_nees_mean,
    nees_band=_nees_band,
    nees_clipped=_nees_clipped,
    cone0=_cone0,
    stream=_stream,
    nav_obstacles=_nav_obstacles,
    nav_keep_out=_nav_keep_out,
)
"""Every entity path of a recording (``entity.error(method)`` and the like for families).

``entity.stream(quantity, series)`` is a plot of the pose stream against the image stamps
(runs with latency only): ``quantity`` one of ``STREAM_QUANTITIES``, ``series`` one of
``STREAM_SERIES``. ``entity.NAV_*``, ``entity.nav_obstacles(method)`` and
``entity.nav_keep_out(method)`` are a navigating flight's only (``navigation_views``);
``entity.IMU*`` a run with an ``[imu]``'s only (``imu_views``)."""

FRAME = SimpleNamespace(
    WORLD="world",
    BODY="body",
    CAMERA="camera",
    IMAGE="image",
    CAMERA_DECLARED="camera_declared",
    CAMERA_RECOVERED="camera_recovered",
    IMU="imu",
    IMU_DECLARED="imu_declared",
)
"""Named transform frames: ``T_w_b`` maps body into world, ``T_b_c`` camera into body, and the
pinhole maps the image plane into the camera (docs/CONVENTIONS.md). In a calibrated run two
more camera frames hang from the body: the mount the estimator was told
(``T_b_c_declared``) and the one calibration recovered (``T_b_c_recovered``); ``camera`` is
the true one. A run with an ``[imu]`` hangs the IMU frame ``imu`` (``T_b_i``, where the
simulator's IMU sits: the frame of its readings) from the body, and with an
``[imu.mount_error]`` the mount the estimator is told, ``imu_declared`` (``T_b_i_declared``)."""

AXIS_LENGTH_M = {FRAME.WORLD: 2.0, FRAME.BODY: 1.0, FRAME.CAMERA: 0.5, FRAME.IMU: 0.3}
"""Drawn axis length per frame: the lengths tell the three frames apart where they overlap."""
CAMERA_AXES_UI_POINTS = 1.0
"""The camera's axes are thin arrows (``Arrows3D``, this radius on screen) where the world's
and the body's are drawn thick (``TransformAxes3D``): the camera sits centimetres from the
body's origin, and length alone did not tell their axes apart."""
CAMERA_NAME_Z_M = 0.65
"""The camera's name sits on a small dot of its z axis' colour this far along its optical axis
z, m, past the axis' tip (``entity.CAMERA_NAME``): the body's name is at the body's origin, and
in a calibrated run the declared mount's on its x axis and the recovered one's on its y axis.
Half-way along z, a camera looking 80 deg down put its name just under the body's in the
close-up."""

PIN_TOP_M = 1.7
"""Each cone has a pin: an orange line from its apex up to this height above the ground, m,
topped by a head of fixed size on screen. Seen from the world view's tens of metres a 0.7 m
cone is a few pixels: the pin shows where it stands; cone 0's name sits on its head, a metre
above the world frame's name where cone 0 stands at the origin."""
PIN_HEAD_UI_POINTS = 3.5
PIN_LINE_UI_POINTS = 0.8
IMAGE_PLANE_M = 0.2
"""Distance of the drawn image plane from the camera centre (the frustum's depth): small
enough that the frustum does not hide the drone in the close-up."""

DECLARED_MOUNT_COLOR = (255, 200, 0)
"""Yellow: the camera mount the estimator was told, drawn as one-coloured axes (calibrated
runs); no axis colour is near it."""
IMU_NAME_Z_M = 0.4
"""The IMU's name sits on a dot this far along its z axis, m, past the axis' tip (as the
camera's, ``CAMERA_NAME_Z_M``): the IMU sits centimetres from the body's origin, where the
body is named.
"""
IMU_DECLARED_NAME_X_M = 0.45
"""The declared IMU mount's name sits on a yellow dot this far along its x axis, m, past the
axis' tip: its z is within a degree or two of the true IMU's, where that one is named, and the
middle of an axis is a few centimetres from the body's name."""
RECOVERED_MOUNT_COLOR = (0, 225, 225)
"""Cyan: the camera mount calibration recovered, drawn as one-coloured axes (calibrated runs)."""
MOUNT_AXIS_LENGTH_M = {
    FRAME.CAMERA_DECLARED: AXIS_LENGTH_M[FRAME.CAMERA],
    FRAME.CAMERA_RECOVERED: 1.2 * AXIS_LENGTH_M[FRAME.CAMERA],
    FRAME.IMU_DECLARED: AXIS_LENGTH_M[FRAME.IMU],
}
"""The declared mount's axes are as long as the true camera's (0.5 m), so that its tips show
how far it is off; the recovered mount's are longer, so that where they lie on the true axes
their ends still show beyond them. The IMU's declared mount (``imu_declared``, yellow too) is as
long as the true IMU's axes (0.3 m)."""

CONE0_SERIES: tuple[str, ...] = ("world", "body", "camera", "estimate_world")
"""Cone 0's coordinate series: its truth in three frames and its depth-image estimate."""
TRUTH_COLOR = (255, 255, 255)
RAY_COLOR = (255, 210, 60)
"""The viewing ray through each detection and its ground hit."""
AXIS_COLORS = [(230, 80, 80), (80, 200, 80), (80, 120, 240)]
"""x, y, z (and roll, pitch, yaw) in every plot."""
NEWEST_POSE_COLOR = (150, 90, 255)
"""Violet: what the newest pose at an image's arrival gives, in 3D and in the plots (no
method uses it; a pipeline ignoring stamps would)."""
EXPOSURE_POSE_COLOR = method(NEWEST_POSE_METHOD).color_rgb
"""The pose looked up at the exposure stamp: the colour of the estimate it makes."""
POSE_SAMPLE_COLOR = (190, 190, 190)
PIN_COLOR = tuple(round(255 * c) for c in TRAFFIC_CONE.color_rgb)
"""A cone's pin (``PIN_TOP_M``) has the cone's own colour."""
DEPTH_CLOUD_COLOR = (150, 150, 200)
TRAJECTORY_COLOR = (170, 170, 185)
PLAN_COLOR = (255, 130, 200)
"""Pink: a navigating drone's plan at the time cursor, the estimated position it starts from,
the goal, and the plan's length in its plot (no method and no frame axis is pink)."""
CONTACT_COLOR = (255, 0, 0)
"""The contact with a cone, drawn as a cross with its name (naive's red dots are points in the
sky, with no name)."""
CLEARANCE_COLOR = (235, 235, 235)
"""The true clearance (MuJoCo's, geometry to geometry) in the navigation plots."""
KEPT_COLOR = (150, 150, 150)
"""The planner's ``clearance_m`` in the navigation plots, grey like a contract's bound."""


@dataclass(frozen=True)
class LegendEntry:
    """One line of the 3D views' legend: what is drawn, in which colour, and how (``dot``: a
    point, with a segment from the true cone for an estimate; ``line``: a line)."""

    text: str
    color_rgb: tuple[int, int, int]
    mark: str


AXES_NOTE = "axes x y z: red green blue; body thick, camera thin"
"""The legend's last line: how the frames' axes read."""


def legend_entries(
    *,
    latency: bool = False,
    mounts: bool = False,
    navigation: str | None = None,
    imu_declared: bool = False,
) -> list[list[LegendEntry]]:
    """Every colour of the 3D views, in the legend's two rows (``entity.LEGEND``): the truth
    and each method's estimate (``vnav.methods.active_methods``), with ``latency`` the newest-pose
    estimate and with ``mounts`` the declared and recovered camera mounts; then the rays, the
    cones' pins, the depth cloud and the flown path (and ``AXES_NOTE``). A navigating flight
    (``navigation``: the method its map takes) adds its plan, its map's keep-out circles and
    the contact; ``imu_declared`` (an ``[imu.mount_error]``) the IMU's declared mount."""
    estimates = [LegendEntry("truth", TRUTH_COLOR, "dot")]
    estimates += [LegendEntry(m.name, m.color_rgb, "dot") for m in active_methods()]
    if latency:
        estimates.append(LegendEntry("newest pose", NEWEST_POSE_COLOR, "dot"))
    if mounts:
        estimates += [
            LegendEntry("declared mount", DECLARED_MOUNT_COLOR, "line"),
            LegendEntry("recovered mount", RECOVERED_MOUNT_COLOR, "line"),
        ]
    drawn = [
        LegendEntry("ray to the ground", RAY_COLOR, "line"),
        LegendEntry("cone pin", PIN_COLOR, "line"),
        LegendEntry("depth image", DEPTH_CLOUD_COLOR, "dot"),
        LegendEntry("flown path", TRAJECTORY_COLOR, "line"),
    ]
    if navigation is not None:
        estimates += [
            LegendEntry("plan", PLAN_COLOR, "line"),
            LegendEntry("keep-out", map_color(navigation)[0], "line"),
            LegendEntry("contact", CONTACT_COLOR, "line"),
        ]
    if imu_declared:
        estimates.append(LegendEntry("IMU declared", DECLARED_MOUNT_COLOR, "line"))
    return [estimates, drawn]


STREAM_QUANTITIES: tuple[str, ...] = ("yaw_deg", "position_m")
"""The pose stream is plotted as the body's yaw (degrees) and its position x, y, z (metres)."""
STREAM_SERIES: tuple[str, ...] = ("pose_samples", "exposure", "arrival")
"""Per quantity: every pose sample at its stamp; at each image's exposure the pose it was
given; at each image's arrival the newest pose received by then."""
STREAM_WINDOW_S = (-0.35, 0.15)
"""The pose-stream plots show this window around the time cursor, seconds: wide enough for a
few camera ticks at 10 Hz, narrow enough that 50 ms of latency is a visible gap."""


VIEWS: dict[str, int] = {name: i for i, name in enumerate(VIEW_NAMES)}
"""Tabs of the lower left panel, by the name a scenario's ``view`` key uses (further tabs
follow these)."""


def blueprint(
    eye_w=None,
    look_target_w=None,
    view: str = "errors",
    *,
    T_w_b=None,
    close_up_cone_w=None,
    error_top_m: dict[str, float | None] | None = None,
    cone0_top_m: float | None = None,
    latency: bool = False,
    verdict: str | None = None,
    mounts_T_w_c: np.ndarray | None = None,
    navigation: bool = False,
    imu: bool = False,
) -> rrb.Blueprint:
    """The default layout: images and plots on the left; the world, a close-up of the drone
    and the state panel on the right; the time panel as ``_time_panel`` sets it.

    Parameters
    ----------
    eye_w, look_target_w : array_like, shape (3,), optional
        Where the 3D view's eye starts and what it looks at, world frame (z up).
    view : {"errors", "coordinates", "attitude", "nees"}
        The tab shown first in the lower left panel (see ``VIEWS``).
    T_w_b, close_up_cone_w, mounts_T_w_c : array_like, optional
        What the close-up looks at (``_close_up_view``). ``mounts_T_w_c`` (a calibrated run)
        also gives the state panel the room its mounts block needs, and each error plot the
        error with the recovered mount (``entity.error_recovered``).
    error_top_m : dict of str to float or None, optional
        Top of each method's error plot, metres (None: the method gave no estimate), and of
        the range plot under the key ``entity.RANGE``.
    cone0_top_m : float, optional
        The cone-0 coordinate plots' y axes run from minus this to this, metres.
    latency, navigation, imu : bool
        The run delivered its images late (its ``[timing]`` is not synchronous), flies by
        its own map, has an ``[imu]``: see ``_left_column`` and ``_time_panel``; with
        ``imu`` the world view leaves out the IMU's name and declared mount (the close-up
        shows them).
    verdict : str, optional
        The run's verdict in a few words (``checks_summary``): the scenario document's tab
        names it, so that it shows without opening the tab.
    """
    if view not in VIEWS:
        raise ValueError(f"view must be one of {list(VIEWS)}, got {view!r}")
    world = _world_view(eye_w, look_target_w, imu=imu)
    close_up = _close_up_view(T_w_b, close_up_cone_w, mounts_T_w_c)
    mounts = mounts_T_w_c is not None
    return rrb.Blueprint(
        rrb.Horizontal(
            _left_column(view, error_top_m or {}, cone0_top_m, latency, mounts, navigation, imu),
            _right_column(world, close_up, verdict, latency=latency, mounts=mounts),
            column_shares=[2, 3],
        ),
        _time_panel(latency, navigation, imu),
        collapse_panels=True,
    )


def _close_up_view(T_w_b, close_up_cone_w, mounts_T_w_c) -> rrb.Spatial3DView:
    """The close-up view: the camera mounts, else a cone, else the drone.

    Parameters
    ----------
    T_w_b : array_like, shape (4, 4), optional
        The drone's pose at the tick the views are framed for (``shown_tick``: the scenario's
        ``show_at_s``, else the last): the close-up view starts behind it, to its left and
        above (``CLOSE_UP_EYE_B``).
    close_up_cone_w : array_like, shape (3,), optional
        A cone's base centre: the close-up looks at it instead of the drone, from its side
        (``cone_close_up``), to show the estimates around it and their ellipsoids.
    mounts_T_w_c : array_like, shape (4, 4), optional
        The true camera's pose at that tick of a calibrated run: the close-up then looks at
        the declared, true and recovered camera mounts (``mounts_close_up``).

    Returns
    -------
    rerun.blueprint.Spatial3DView
        The view, first of the three that applies.
    """
    if mounts_T_w_c is not None:
        return mounts_close_up(mounts_T_w_c)
    if close_up_cone_w is not None:
        return cone_close_up(close_up_cone_w, T_w_b)
    return _close_up(T_w_b)


def _left_column(
    view: str,
    error_top_m: dict[str, float | None],
    cone0_top_m: float | None,
    latency: bool,
    mounts: bool,
    navigation: bool,
    imu: bool,
) -> rrb.Vertical:
    """The images above the plots' tabs (``_lower_tabs``).

    Parameters
    ----------
    view : {"errors", "coordinates", "attitude", "nees"}
        The tab shown first in the lower panel (see ``VIEWS``).
    error_top_m : dict of str to float or None
        Top of each method's error plot, metres, and of the range plot (``entity.RANGE``).
    cone0_top_m : float or None
        The cone-0 coordinate plots' y axes run from minus this to this, metres.
    latency : bool
        The run delivered its images late: the error tab also plots the newest-pose
        estimate's error and the pose stream against the image stamps, and the plots get
        more room.
    mounts : bool
        A calibrated run: each error plot also draws the error with the recovered mount.
    navigation : bool
        A navigating flight: the lower panel opens on its tab (``navigation_tab``: the true
        clearance, the drone's distance from the cones' axes, the plan's length).
    imu : bool
        The run has an ``[imu]``: the lower panel opens on its tab (``imu_tab``: the readings
        in the IMU frame).

    Returns
    -------
    rerun.blueprint.Vertical
        The left column of the layout.
    """
    # With latency the plots and the state panel (its time block) get more room.
    return rrb.Vertical(
        _image_tabs(),
        _lower_tabs(
            view,
            error_top_m,
            cone0_top_m,
            latency,
            recovered_mount=mounts,
            navigation=navigation,
            imu=imu,
        ),
        row_shares=[4, 6] if latency else [3, 5],
    )


def _time_panel(latency: bool, navigation: bool, imu: bool) -> rrb.TimePanel:
    """The time panel, collapsed and "following": the viewer opens at the last tick, where
    the lesson has played out, and any tick can be picked on the timeline.

    Parameters
    ----------
    latency, navigation, imu : bool
        The run delivered its images late, flies by its own map, has an ``[imu]``: the panel
        then starts on ``sim_time`` (a pose sample has no tick, the contact falls between two
        camera ticks, a reading has no tick), else on ``tick``.

    Returns
    -------
    rerun.blueprint.TimePanel
        The panel's settings.
    """
    return rrb.TimePanel(
        state="collapsed",
        play_state="following",
        timeline="sim_time" if latency or navigation or imu else "tick",
    )


def _world_view(eye_w, look_target_w, imu: bool = False) -> rrb.Spatial3DView:
    """The world in 3D, its eye at ``eye_w`` looking at ``look_target_w`` (world frame); with
    ``imu``, without the IMU's name and declared mount (centimetres from the body's origin)."""
    eye = None
    if eye_w is not None and look_target_w is not None:
        eye = rrb.EyeControls3D(position=eye_w, look_target=look_target_w, eye_up=[0, 0, 1])
    return rrb.Spatial3DView(
        name="world",
        origin=entity.WORLD,
        # The depth image would also be drawn back-projected in 3D; the world-frame cloud
        # computed by vnav (world/depth_cloud) is the one to look at here. The mounts are
        # centimetres apart: seen from metres away they are one frame with three labels.
        # Seen from metres away the camera's name would sit on the body's (they are 15 cm
        # apart): the close-up names both.
        contents=[
            "+ $origin/**",
            f"- /{entity.DEPTH}",
            f"- /{entity.CAMERA_NAME}",
            *_NO_MOUNTS,
            *([f"- /{entity.IMU_NAME}", f"- /{entity.IMU_DECLARED}/**"] if imu else []),
        ],
        eye_controls=eye,
    )


def _right_column(
    world: rrb.Spatial3DView,
    close_up: rrb.Spatial3DView,
    verdict: str | None,
    *,
    latency: bool,
    mounts: bool,
) -> rrb.Vertical:
    """The legend of the 3D views' colours (``entity.LEGEND``) over the world and the
    close-up, the state panel and the scenario document below. With latency (the time block)
    or a calibrated run's mounts the panel gets half the height."""
    views_share = 1 if latency or mounts else 3
    panel_share = 1 if latency or mounts else 2
    return rrb.Vertical(
        # A strip as wide as the two 3D views: a legend drawn in 3D would move with the eye.
        rrb.Spatial2DView(name="legend", origin=entity.LEGEND, titlebar=False),
        # A calibrated run's lesson is in the mounts close-up: it gets half the width.
        rrb.Horizontal(world, close_up, column_shares=[1, 1] if mounts else [3, 2]),
        rrb.Tabs(
            rrb.TextDocumentView(name="state at the time cursor", origin=entity.STATE),
            rrb.TextDocumentView(
                name="scenario" if verdict is None else f"scenario, checks: {verdict}",
                origin=entity.DESCRIPTION,
            ),
        ),
        row_shares=[LEGEND_SHARE * (views_share + panel_share), views_share, panel_share],
    )


LEGEND_SHARE = 0.055
"""The legend strip's height as a fraction of the 3D views' and the panel's together: two
lines of text in a window 900 points high."""

_NO_MOUNTS = [f"- /{entity.CAMERA_DECLARED}/**", f"- /{entity.CAMERA_RECOVERED}/**"]
"""Views that show the world leave out the declared and recovered mounts (calibrated runs)."""

CLOSE_UP_EYE_B = np.array([-2.0, 1.2, 1.2])
"""Where the close-up's eye starts in the drone's yaw frame: behind, to the left, above (m)."""


_CLOSE_UP_CONTENTS = [
    "+ $origin/**",
    f"- /{entity.DEPTH}",
    f"- /{entity.DEPTH_CLOUD}",
    f"- /{entity.TRAJECTORY}",
    *_NO_MOUNTS,
]
"""What a close-up shows: the world without the depth image, its cloud and the flown path."""


def _close_up(T_w_b) -> rrb.Spatial3DView:
    """The drone at the last tick, its three frames and the start of each ray, from 2.6 m.

    The eye does not track the drone (Rerun 0.41's ``tracking_entity`` misplaces an entity
    drawn in a named frame): scrubbing back in a flight, the drone leaves this view; the
    world view shows it everywhere.
    """
    eye = None
    if T_w_b is not None:
        T_w_b = np.asarray(T_w_b, dtype=np.float64)
        drone_w = T_w_b[:3, 3]
        # Turned by the drone's heading only, so the eye stays above whatever the attitude.
        yaw = float(np.arctan2(T_w_b[1, 0], T_w_b[0, 0]))
        offset_w = so3.rot_z(yaw) @ CLOSE_UP_EYE_B
        eye = rrb.EyeControls3D(
            position=drone_w + offset_w,
            look_target=drone_w,
            eye_up=[0, 0, 1],
        )
    return rrb.Spatial3DView(
        name="drone close-up",
        origin=entity.WORLD,
        contents=_CLOSE_UP_CONTENTS,
        eye_controls=eye,
    )


CONE_CLOSE_UP_EYE_M = np.array([0.5, 3.0, 1.8])
"""Where the cone close-up's eye starts from the cone, m: back along the drone's line of sight
to it, to that line's left, above; it looks at the cone's middle."""


def cone_close_up(cone_w, T_w_b=None) -> rrb.Spatial3DView:
    """A cone, its truth and estimates and their ellipsoids, seen from across the line of
    sight (an estimate's error along and across that line are both in view).

    Parameters
    ----------
    cone_w : array_like, shape (3,)
        The cone's base centre, world frame.
    T_w_b : array_like, shape (4, 4), optional
        The drone's pose at the last tick: the line of sight is from it to the cone (else
        along world x).
    """
    cone_w = np.asarray(cone_w, dtype=np.float64)
    bearing = np.array([1.0, 0.0, 0.0])
    if T_w_b is not None:
        b = cone_w - np.asarray(T_w_b, dtype=np.float64)[:3, 3]
        b[2] = 0.0
        if np.linalg.norm(b) > 1e-6:
            bearing = b / np.linalg.norm(b)
    left = np.array([-bearing[1], bearing[0], 0.0])
    up = np.array([0.0, 0.0, 1.0])
    target_w = cone_w + 0.5 * TRAFFIC_CONE.height_m * up
    along, side, above = CONE_CLOSE_UP_EYE_M
    eye_w = cone_w - along * bearing + side * left + above * up
    return rrb.Spatial3DView(
        name="cone close-up",
        origin=entity.WORLD,
        contents=_CLOSE_UP_CONTENTS,
        eye_controls=rrb.EyeControls3D(position=eye_w, look_target=target_w, eye_up=[0, 0, 1]),
        # The world's name would sit on a cone at the origin, among its estimates: here the
        # cone's pin is named, the world's axes are not.
        overrides={entity.WORLD: rr.TransformAxes3D.from_fields(show_frame=False)},
    )


MOUNTS_TARGET_C = np.array([0.2, 0.2, 0.2])
"""What the mounts close-up looks at, in the true camera frame, m: the middle of the axes'
span."""
MOUNTS_EYE_C = MOUNTS_TARGET_C + np.array([0.45, -0.85, -0.7])
"""Where the mounts close-up's eye sits in the true camera frame, m (x right, y down, z
forward): 1.2 m to the right, above and behind the axes, so that none points at it."""


def mounts_close_up(T_w_c: np.ndarray) -> rrb.Spatial3DView:
    """The three camera mounts on the body at the last tick, from 1.2 m: the true
    camera's axes (red, green, blue), the declared mount's (``DECLARED_MOUNT_COLOR``) and the
    recovered one's (``RECOVERED_MOUNT_COLOR``), with the body's axes (not the drone's mesh).

    The eye does not track the drone (see ``_close_up``): scrubbing back in the flight, the
    mounts leave this view.

    Parameters
    ----------
    T_w_c : array_like, shape (4, 4)
        The true camera's pose at the last tick (where the viewer opens).
    """
    T_w_c = np.asarray(T_w_c, dtype=np.float64)
    return rrb.Spatial3DView(
        name="camera mounts (true: rgb axes)",
        origin=entity.WORLD,
        # The true camera's axes and name only: its frustum and the drone's rotors would hide
        # the centimetres between the mounts.
        contents=[
            f"+ /{entity.BODY}/**",
            f"- /{entity.DRONE}",
            f"- /{entity.IMAGE}",
            f"- /{entity.DEPTH}",
            f"- /{entity.DETECTIONS}/**",
        ],
        overrides={
            entity.CAMERA: rrb.EntityBehavior(visible=False),
            entity.CAMERA_AXES: rrb.EntityBehavior(visible=True),
            entity.CAMERA_NAME: rrb.EntityBehavior(visible=True),
        },
        eye_controls=rrb.EyeControls3D(
            position=se3.apply(T_w_c, MOUNTS_EYE_C),
            look_target=se3.apply(T_w_c, MOUNTS_TARGET_C),
            eye_up=[0, 0, 1],
        ),
    )


def _image_tabs() -> rrb.Tabs:
    """The camera image, and the depth image beside its colour scale."""
    camera = rrb.Spatial2DView(
        name="camera",
        origin=entity.CAMERA,
        contents=[f"+ /{entity.IMAGE}", f"+ /{entity.DETECTIONS}/**"],
    )
    depth = rrb.Horizontal(
        rrb.Spatial2DView(
            name="depth (m)",
            origin=entity.CAMERA,
            contents=[f"+ /{entity.DEPTH}", f"+ /{entity.DETECTIONS}/**"],
        ),
        rrb.Spatial2DView(name="z (m)", origin=entity.DEPTH_SCALE),
        column_shares=[6, 1],
        name="depth",
    )
    return rrb.Tabs(camera, depth)


def _series(name: str, paths: list[str], y_range=None, time_range=None) -> rrb.TimeSeriesView:
    """A time-series plot whose title names its curves (a legend would cover the data)."""
    return rrb.TimeSeriesView(
        name=name,
        origin="/",
        contents=[f"+ /{p}" for p in paths],
        axis_y=rrb.ScalarAxis(range=y_range) if y_range is not None else None,
        plot_legend=rrb.PlotLegend(visible=False),
        time_ranges=time_range,
    )


def _gave_none(tops_m: dict[str, float | None], name: str) -> bool:
    """Whether the run is known to have no estimate of method ``name`` (its plots then keep
    only their titles)."""
    return name in tops_m and tops_m[name] is None


def _error_plot(
    name: str,
    tops_m: dict[str, float | None],
    newest_pose: bool = False,
    recovered_mount: bool = False,
) -> rrb.TimeSeriesView:
    """One checked method's mean error per tick, with the contract's bound in grey (and, if
    ``newest_pose``, the newest-pose estimate's error in violet; if ``recovered_mount``, the
    error of the same images estimated again with the mount calibration recovered, in
    ``RECOVERED_MOUNT_COLOR``)."""
    top_m = tops_m.get(name)
    paths = [entity.error(name), entity.allowed(name)]
    if _gave_none(tops_m, name):
        title = f"{name} error (m): no estimate in this run"
    else:
        title = f"{name} error (m), grey: the contract's bound"
    if recovered_mount and not _gave_none(tops_m, name):
        paths.append(entity.error_recovered(name))
        title = f"{name} error (m), grey: bound, cyan: with the recovered mount"
    if newest_pose:
        paths.append(entity.NEWEST_ERROR)
        title = f"{name} error (m), grey: bound, violet: with the newest pose"
        if recovered_mount:
            title += ", cyan: recovered mount"
    return _series(title, paths, y_range=(0.0, top_m) if top_m is not None else None)


_STREAM_TITLES = {
    "yaw_deg": "pose yaw (deg) per sample; o: at exposure, x: newest at arrival",
    "position_m": "pose x y z (m) per sample; o: at exposure, x: newest at arrival",
}


def _stream_plot(quantity: str) -> rrb.TimeSeriesView:
    """One quantity of the pose stream around the time cursor (``STREAM_WINDOW_S``)."""
    start_s, end_s = STREAM_WINDOW_S
    window = rrb.VisibleTimeRange(
        "sim_time",
        start=rrb.TimeRangeBoundary.cursor_relative(seconds=start_s),
        end=rrb.TimeRangeBoundary.cursor_relative(seconds=end_s),
    )
    return _series(
        _STREAM_TITLES[quantity],
        [entity.stream(quantity, series) for series in STREAM_SERIES],
        time_range=window,
    )


_XYZ = "x (red), y (green), z (blue)"
_CONE0_TITLES = {
    "world": f"cone 0 in world, p_w (m): {_XYZ}",
    "body": f"cone 0 in body, p_b (m): {_XYZ}",
    "camera": f"cone 0 in camera, p_c (m): {_XYZ}",
    "estimate_world": f"{PREFERENCE[0]} estimate of p_w (m): {_XYZ}",
}


def _from_zero(tops: dict[str, float | None], key: str) -> tuple[float, float] | None:
    """A y range from 0 (small changes of a large value are not drawn as large ones)."""
    top = tops.get(key)
    return (0.0, top) if top is not None else None


NEES_TOP = 11.2
"""Top of the NEES plots: above 10 (a labelled tick) and between three and six times the
degrees of freedom; the mean is what the ``consistent`` check judges. A tick's NEES above it
would leave the plot unmarked: it is marked at ``NEES_CLIP_MARK`` (``entity.nees_clipped``)."""
NEES_CLIP_MARK = 0.96 * NEES_TOP
"""Where a NEES above ``NEES_TOP`` is marked, an upward triangle just under the plot's top."""


def _nees_tab(error_top_m: dict[str, float | None]) -> rrb.Vertical:
    """Each checked method's NEES per tick (thin), its mean over the run so far (thick) and
    that mean's 95% chi-square band (grey), which narrows around the method's degrees of
    freedom (``vnav.methods.Method.dof``) as estimates add up; a tick above the plot's top
    (``NEES_TOP``) is marked with a triangle at its top.
    A method that gave no estimate keeps only its title."""
    plots, shares = [], []
    for name in PREFERENCE:
        dof = method(name).dof
        none = _gave_none(error_top_m, name)
        title = f"{name} NEES; thick: mean; grey: 95% band around {dof}; ▲ off top"
        paths = [
            entity.nees(name),
            entity.nees_mean(name),
            entity.nees_band(name),
            entity.nees_clipped(name),
        ]
        plots.append(
            _series(
                f"{name} NEES: no estimate in this run" if none else title,
                paths,
                y_range=(0.0, NEES_TOP),
            )
        )
        shares.append(1 if none else 4)
    return rrb.Vertical(*plots, row_shares=shares, name="NEES")


def _coordinates_tab(cone0_top_m: float | None) -> rrb.Vertical:
    """Cone 0 in world, body and camera frames and its estimate, one above the other at full
    width (each title is read whole: it names the colours), on one symmetric scale."""
    cone0_range = None if cone0_top_m is None else (-cone0_top_m, cone0_top_m)
    return rrb.Vertical(
        *[_series(_CONE0_TITLES[f], [entity.cone0(f)], cone0_range) for f in CONE0_SERIES],
        name="cone 0 in each frame",
    )


def _attitude_tab() -> rrb.Vertical:
    """Roll, pitch and yaw in degrees, the quaternion, and the lanes of the gimbal-lock flag
    and the quaternion's plotted sign."""
    return rrb.Vertical(
        _series(
            "R_w_b: roll (red), pitch (green), yaw (blue), deg",
            [entity.RPY],
            y_range=(-180.0, 180.0),
        ),
        _series(
            "R_w_b as a quaternion: x (red), y (green), z (blue), w (white)",
            [entity.QUAT],
            y_range=(-1.05, 1.05),
        ),
        rrb.StateTimelineView(
            name="gimbal lock; quaternion sign",
            origin="/",
            contents=[f"+ /{entity.GIMBAL_LOCK}", f"+ /{entity.QUAT_SIGN}"],
        ),
        row_shares=[3, 3, 3],
        name="attitude",
    )


def _lower_tabs(
    view: str,
    error_top_m: dict[str, float | None],
    cone0_top_m: float | None,
    latency: bool,
    recovered_mount: bool = False,
    navigation: bool = False,
    imu: bool = False,
) -> rrb.Tabs:
    """The tabs below the images: ``VIEWS`` first (in order), then the other plots; a
    navigating flight's tab (``navigation_tab``) and an IMU's (``imu_tab``) after them, the
    last of them shown first.

    With ``latency`` the error tab shows the lesson of time: the depth_image error beside the
    newest pose's, and the pose stream around the time cursor with each image's exposure and
    arrival; the other methods' errors move to a tab of their own after ``VIEWS``.
    """
    errors, extra = _error_tabs(error_top_m, latency, recovered_mount)
    tabs = {
        "errors": errors,
        "coordinates": _coordinates_tab(cone0_top_m),
        "attitude": _attitude_tab(),
        "nees": _nees_tab(error_top_m),
    }
    if navigation:
        extra.append(navigation_tab())
    if imu:
        extra.append(imu_tab())
    return rrb.Tabs(
        *[tabs[name] for name in VIEW_NAMES],
        *extra,
        rrb.Spatial2DView(name="error against range", origin=entity.ERROR_VS_RANGE),
        _naive_range_tab(error_top_m),
        active_tab=len(VIEWS) + len(extra) - 1 if navigation or imu else VIEWS[view],
    )


def _error_tabs(
    error_top_m: dict[str, float | None], latency: bool, recovered_mount: bool
) -> tuple[rrb.Vertical, list[rrb.Vertical]]:
    """The position-error tab, and with ``latency`` the tab of the other methods' errors.

    Parameters
    ----------
    error_top_m : dict of str to float or None
        The top of each plot's y axis, metres, by method (None: no estimate in the run).
    latency : bool
        Show the lesson of time: the depth_image error beside the newest pose's and the pose
        stream around the time cursor; the other methods then move to a tab of their own.
    recovered_mount : bool
        The run's estimates were made again with the recovered mount (plotted beside).

    Returns
    -------
    errors : rerun.blueprint.Vertical
        The error tab, shown under ``VIEWS``' name ``errors``.
    extra : list of rerun.blueprint.Vertical
        The other methods' error tab with ``latency``, else empty.
    """
    # A user's function (vnav.plugin) is plotted after the built-ins it is judged beside.
    users = [m.name for m in active_methods() if m.images == "user"]
    checked = [*PREFERENCE, *users]
    others = [name for name in checked if name != NEWEST_POSE_METHOD]
    extra = []
    if latency:
        errors = rrb.Vertical(
            _error_plot(
                NEWEST_POSE_METHOD, error_top_m, newest_pose=True, recovered_mount=recovered_mount
            ),
            *[_stream_plot(q) for q in STREAM_QUANTITIES],
            name="position error, time",
        )
        extra.append(
            rrb.Vertical(
                *[
                    _error_plot(name, error_top_m, recovered_mount=recovered_mount)
                    for name in others
                ],
                name=", ".join(others),
            )
        )
    else:
        errors = rrb.Vertical(
            *[_error_plot(name, error_top_m, recovered_mount=recovered_mount) for name in checked],
            # A method without an estimate keeps only its title ("no estimate in this run"):
            # the others get the height their axes need to be read.
            row_shares=[1 if _gave_none(error_top_m, name) else 4 for name in checked],
            name="position error",
        )
    return errors, extra


def _naive_range_tab(error_top_m: dict[str, float | None]) -> rrb.Vertical:
    """The naive chain's error above the range to the matched cones.

    Parameters
    ----------
    error_top_m : dict of str to float or None
        The top of each plot's y axis, metres, by method and for ``entity.RANGE``.

    Returns
    -------
    rerun.blueprint.Vertical
        The tab named "naive, range".
    """
    return rrb.Vertical(
        _series(f"{NAIVE} error (m)", [entity.error(NAIVE)], _from_zero(error_top_m, NAIVE)),
        _series(
            "range to the matched cones (m)",
            [entity.RANGE],
            _from_zero(error_top_m, entity.RANGE),
        ),
        name="naive, range",
    )


def navigation_tab() -> rrb.Vertical:
    """A navigating flight's plots, one above the other (each title names its lines):

    - the true clearance, MuJoCo's distance between the drone's and the nearest cone's
      collision geometry (what a contact is), with its 0 (contact) in red and the contact
      marked where MuJoCo found it;
    - the drone's centre to the nearest true cone's axis, in the plane, against the
      ``clearance_m`` the planner keeps from each *mapped* axis: where the map is right the
      first stays above the second; the two distances differ by the cone's and the drone's
      size;
    - the planned path's length at each camera tick.
    """
    return rrb.Vertical(
        _series(
            "true clearance to the nearest cone (m, MuJoCo); red: 0, contact",
            [entity.NAV_CLEARANCE, entity.NAV_CONTACT_LEVEL, entity.NAV_CONTACT_MARK],
        ),
        _series(
            "centre to nearest cone axis (m, truth); grey: planner's clearance_m",
            [entity.NAV_AXIS_DISTANCE, entity.NAV_CLEARANCE_KEPT],
        ),
        _series("planned path length (m), replanned at each camera tick", [entity.NAV_PLAN_LENGTH]),
        row_shares=[4, 4, 3],
        name="navigation",
    )


IMU_CHAIN_COLOR = (235, 235, 235)
"""White: ``vnav.imu``'s noise-free prediction of each IMU reading, drawn thin over the
readings' x (red), y (green), z (blue)."""
IMU_SERIES = {
    entity.IMU_SPECIFIC_FORCE: ("specific force f_i", "m/s^2"),
    entity.IMU_ANGULAR_RATE: ("angular rate omega_i", "rad/s"),
}
"""The IMU's two plots: each reading's quantity and unit, by entity (its noise-free
prediction's entity is ``IMU_CHAIN[path]``)."""
IMU_CHAIN = {
    entity.IMU_SPECIFIC_FORCE: entity.IMU_SPECIFIC_FORCE_CHAIN,
    entity.IMU_ANGULAR_RATE: entity.IMU_ANGULAR_RATE_CHAIN,
}


def imu_series_names(path: str) -> list[str]:
    """The three curves of an IMU plot (``IMU_SERIES``) named per axis, each "in the IMU
    frame"; the noise-free prediction's (``IMU_CHAIN``) say so."""
    if path in IMU_SERIES:
        quantity, unit = IMU_SERIES[path]
        return [f"{quantity} {a} in the IMU frame ({unit})" for a in "xyz"]
    (reading,) = [p for p, chain in IMU_CHAIN.items() if chain == path]
    quantity, unit = IMU_SERIES[reading]
    return [f"{quantity} {a} in the IMU frame, noise-free chain ({unit})" for a in "xyz"]


def imu_tab() -> rrb.Vertical:
    """A run with an ``[imu]``: its readings, in the IMU frame, at their stamps on the IMU's
    clock (``sim_time``): the specific force over the angular rate, x (red), y (green), z
    (blue), each with ``vnav.imu``'s noise-free prediction in thin white."""
    plots = [
        _series(
            f"IMU {quantity} ({unit}) in the IMU frame: x (red), y (green), z (blue); "
            "white: noise-free chain",
            [path, IMU_CHAIN[path]],
        )
        for path, (quantity, unit) in IMU_SERIES.items()
    ]
    return rrb.Vertical(*plots, name="IMU")


def shown_tick(spec: ScenarioSpec, result: RunResult) -> int:
    """Index in ``result.ticks`` of the tick the 3D views are framed for: the last at or before
    the scenario's ``show_at_s``, or the last tick of the run."""
    if spec.show_at_s is None or not result.ticks:
        return len(result.ticks) - 1
    at_or_before = [i for i, t in enumerate(result.ticks) if t.t_s <= spec.show_at_s + 1e-9]
    return at_or_before[-1] if at_or_before else 0


def moment(spec: ScenarioSpec, result: RunResult) -> tuple[int, float]:
    """The instant the recording opens its screenshot at (``entity.MOMENT``): the camera tick
    and its simulated time, s, of ``shown_tick``; but for a navigating flight that ended at a
    contact, with no ``show_at_s``, the contact itself: its time, and the tick after the last,
    where the contact is logged on the ``tick`` timeline (``navigation_views``)."""
    nav = result.navigation
    last = result.ticks[-1]
    if spec.show_at_s is None and nav is not None and nav.contact is not None:
        return last.tick + 1, nav.contact.t_s
    shown = result.ticks[shown_tick(spec, result)]
    return shown.tick, shown.t_s


def eye_for(spec: ScenarioSpec, result: RunResult | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Where the 3D view's eye starts and what it looks at, world frame, each (3,).

    The eye frames the lesson at the tick shown (``shown_tick``: the scenario's ``show_at_s``
    or the last): the cones, the drone and, if ``result`` is given, every estimate of that
    tick, the naive one included, seen from behind the drone's heading, to the side and above.
    A navigating flight's goal is framed too, and the eye looks along the start-goal line.
    """
    cones_w = np.array(spec.scene.cones_w, dtype=np.float64).reshape(-1, 3)
    drone_w = np.asarray(spec.scene.start_position_w, dtype=np.float64)
    points = [cones_w]
    if result is not None and result.ticks:
        last = result.ticks[shown_tick(spec, result)]
        drone_w = last.T_w_b[:3, 3]
        points += [last.estimates_w(m.name) for m in METHODS]
    points.append(drone_w[None, :])
    heading_w = cones_w.mean(axis=0) - drone_w
    if spec.flight.mode == "navigate":
        goal_w = np.asarray(spec.flight.goal_w, dtype=np.float64)
        points.append(goal_w[None, :])
        heading_w = goal_w - np.asarray(spec.flight.start_w, dtype=np.float64)
    points_w = np.concatenate(points)
    low, high = points_w.min(axis=0), points_w.max(axis=0)
    target_w = 0.5 * (low + high)
    radius_m = max(4.0, 0.5 * float(np.linalg.norm(high - low)))
    heading_w[2] = 0.0
    norm = np.linalg.norm(heading_w)
    heading_w = heading_w / norm if norm > 1e-6 else np.array([1.0, 0.0, 0.0])
    side_w = np.array([-heading_w[1], heading_w[0], 0.0])
    # About 2.2 radii away the bounding sphere fills most of the viewer's default field of view.
    # A navigating flight is seen from higher up: its map and plan lie in a horizontal plane.
    up = 1.6 if spec.flight.mode == "navigate" else 0.7
    direction_w = -heading_w + 0.8 * side_w + np.array([0.0, 0.0, up])
    eye_w = target_w + 2.2 * radius_m * direction_w / np.linalg.norm(direction_w)
    return eye_w, target_w


VERDICT_WORDS = {
    Outcome.PASSED: "passed",
    Outcome.FAILED: "FAILED",
    Outcome.NO_DATA: "NO DATA",
    Outcome.SKIPPED: "skipped",
}
"""How the scenario document marks each check's outcome: what fails the run in capitals, as
``vnav-demo run`` prints it."""


def checks_summary(judged: Sequence[CheckResult]) -> str:
    """The run's verdict in a few words: ``all 4 passed``, ``3 passed, 1 skipped``, ``FAILED:
    1 of 4`` (a check that had no data fails the run too), ``no checks``."""
    if not judged:
        return "no checks"
    failing = sum(c.outcome.fails_run for c in judged)
    if failing:
        return f"FAILED: {failing} of {len(judged)}"
    skipped = sum(c.outcome is Outcome.SKIPPED for c in judged)
    if skipped:
        return f"{len(judged) - skipped} passed, {skipped} skipped"
    return f"all {len(judged)} passed"


def checks_text(judged: Sequence[CheckResult]) -> str:
    """Markdown: each check's verdict, its name and its figure next to its limit (the JSON
    report's ``checks``: ``outcome``, ``name``, ``shown``), under the run's verdict."""
    lines = [f"## Checks: {checks_summary(judged)}", ""]
    # "*", not "-": a list with another marker is another list, and the description's list
    # follows this one (in markdown a blank line alone would join the two).
    lines += [f"* **{VERDICT_WORDS[c.outcome]}** {c.name}: {c.shown}" for c in judged]
    return "\n".join(lines)


def describe(spec: ScenarioSpec, seed: int, judged: Sequence[CheckResult] | None = None) -> str:
    """Markdown shown beside the recording: what the scenario is, teaches, and what is drawn;
    with ``judged`` (the run's checks, known when the recording is finished) each verdict
    under the lesson."""
    cam = spec.scene.camera
    lines = [f"# {spec.name}", "", spec.description, ""]
    if spec.lesson:
        lines += [spec.lesson.strip(), ""]
    if judged is not None:
        lines += [checks_text(judged), ""]
    estimates = ", ".join(
        f"**{m.name}** ({m.color_name}{': ' + m.depth_from if m.bound is None else ''})"
        for m in active_methods()
    )
    lines += [
        f"- flight: {spec.flight.mode}, {spec.end_s:g} s simulated, camera at "
        f"{spec.camera_rate_hz:g} Hz, seed {seed}",
        f"- camera: {cam.width}x{cam.height}, fovy {cam.fovy_deg:g} deg, pitched "
        f"{cam.pitch_down_deg:g} deg down at {list(cam.position_b)} m in the body frame",
        f"- cones (base centres, world): {[list(c) for c in spec.scene.cones_w]}",
        "",
        "Drawn: the world, body and camera frames (axes 2 m, 1 m, 0.5 m; x red, y green, "
        "z blue; the camera's thin, named past the tip of its optical axis), the drone and "
        "cones as built "
        "in MuJoCo, each cone with an orange pin up to "
        f"{PIN_TOP_M:g} m (cone 0's named), the ray from the camera through "
        "each detection's base pixel to the ground (yellow), each method's estimate with a "
        "segment from the true cone, and a line from the drone to the naive estimate. The "
        "strip over the 3D views names their colours.",
        "",
        f"Estimates: {estimates}. Truth: white.",
        "",
        _describe_timing(spec),
    ]
    if spec.flight.mode == "navigate":
        lines += ["", _describe_navigation(spec)]
    if spec.scene.imu is not None:
        lines += ["", describe_imu(spec)]
    if spec.show_at_s is not None:
        lines += [
            "",
            f"The 3D views are framed at t = {spec.show_at_s:g} s, where the lesson shows (the "
            "screenshot's instant); the viewer opens at the end: move the time cursor there.",
        ]
    if spec.checks_calibration:
        lines += ["", _describe_mounts()]
    return "\n".join(lines)


def _describe_navigation(spec: ScenarioSpec) -> str:
    """One paragraph on what a navigating flight's recording draws of its closed loop."""
    f = spec.flight
    color_name = map_color(f.estimate)[1]
    return (
        f"Navigation: at each camera tick the cones **{f.estimate}** estimates update the map "
        f"({color_name}: each mapped cone's base, its axis and its keep-out circle of "
        f"clearance_m = {f.clearance_m:g} m at the flight altitude), and the path to the goal "
        "is planned again from the drone's estimated position (**pink**: the plan at the "
        "time cursor and the estimated position). A contact with a cone is a red cross at "
        "MuJoCo's contact point, named with its time. The navigation tab plots the true "
        "clearance (MuJoCo's distance between the drone's and the cones' geometry: 0 is a "
        "contact), the drone's centre to the nearest cone axis against clearance_m (what the "
        "planner keeps from each *mapped* axis) and the plan's length."
    )


def describe_imu(spec: ScenarioSpec) -> str:
    """One paragraph on a run's IMU: its frame (mount, declared and true), clock, rate and
    noise figures in Kalibr's units, and what the recording draws of it."""
    imu = spec.scene.imu
    assert imu is not None
    error = imu.mount_error
    mount = (
        f"declared at {list(imu.position_b)} m in the body frame with axes R_b_i = Rz(yaw) "
        f"Ry(pitch) Rx(roll) of rpy_deg {list(imu.rpy_deg)}"
    )
    if error.is_zero:
        drawn = "its axes (thin, x red, y green, z blue, named **imu** past the tip of z)"
    else:
        mount += (
            f"; the true mount is {error.angle_deg:.2f} deg and {1e3 * error.offset_m:.0f} mm "
            "off it (T_b_i = T_b_i_declared E, the error in the IMU frame)"
        )
        drawn = (
            "the true IMU's axes (thin, x red, y green, z blue, named **imu (true)**) and the "
            "declared mount's (**yellow**, named **imu declared**; the estimator is told "
            "that one)"
        )
    noise = imu.noise
    return (
        f"IMU: frame `imu`, {mount}. It reads at {imu.rate_hz:g} Hz, stamped on its own clock: "
        f"t_imu = t_cam + {1e3 * imu.time_offset_s:g} ms (Kalibr's timeshift_cam_imu). Noise "
        "(Kalibr's model, per axis): accelerometer_noise_density "
        f"{noise.accelerometer_noise_density:g} m/s^2/sqrt(Hz), accelerometer_random_walk "
        f"{noise.accelerometer_random_walk:g} m/s^3/sqrt(Hz), gyroscope_noise_density "
        f"{noise.gyroscope_noise_density:g} rad/s/sqrt(Hz), gyroscope_random_walk "
        f"{noise.gyroscope_random_walk:g} rad/s^2/sqrt(Hz). Drawn on the body: {drawn}. The "
        "IMU tab plots each reading, the specific force f_i (+9.81 m/s^2 up at rest) and the "
        "angular rate omega_i, in the IMU frame, on sim_time at its stamp on the IMU's clock, "
        "with vnav.imu's noise-free prediction from the body's true motion in thin white."
    )


def _describe_mounts() -> str:
    """One paragraph on what a calibrated run draws of the camera mounts."""
    declared_m = MOUNT_AXIS_LENGTH_M[FRAME.CAMERA_DECLARED]
    recovered_m = MOUNT_AXIS_LENGTH_M[FRAME.CAMERA_RECOVERED]
    return (
        "Camera mounts (the close-up beside the world): the true camera's axes (red, green, "
        f"blue, {AXIS_LENGTH_M[FRAME.CAMERA]:g} m), the mount the estimator was told "
        f"(**yellow**, {declared_m:g} m: its tips show how far it is off) and the one "
        f"calibration recovered from the flight (**cyan**, {recovered_m:g} m and thinner: "
        "where it lies on the true axes only its ends show). The state panel gives the three "
        "T_b_c side by side, each one's error against the true mount, and the clock offset."
    )


def _describe_timing(spec: ScenarioSpec) -> str:
    """One paragraph on the run's clocks and links, and what the viewer draws of them."""
    t = spec.timing
    if t.synchronous:
        return (
            "Time: synchronous, each image is processed at its exposure with the pose of that "
            "instant (no latency, no clock offset)."
        )
    return (
        f"Time: an image arrives {1e3 * t.image_latency_s:g} ms after its exposure, stamped "
        f"on the camera clock: t_pose = t_cam + {1e3 * t.camera_clock_offset_s:g} ms on the "
        f"pose clock. Poses are sampled at {t.pose_rate_hz:g} Hz and "
        f"arrive {1e3 * t.pose_latency_s:g} ms late, each arrival with "
        f"{1e3 * t.jitter_s:g} ms of jitter. Each image stays on the time line at its "
        "exposure. **Violet**: the depth_image estimate made with the newest pose received "
        "when the image arrived (what a pipeline ignoring stamps computes), with a segment "
        "from the true cone; the pose-stream plots show every pose sample (grey) at its stamp, "
        "the pose used at each exposure (blue circle) and the newest pose at each arrival "
        "(violet cross)."
    )
