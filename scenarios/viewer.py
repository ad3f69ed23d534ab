"""What the viewer shows and how: entity paths, colours, the layout, the eye and the text.

Everything here is a viewer concern, declared once and shared by the recording
(``scenarios.recording``) and the tests that read a recording back:

- ``entity``: every Rerun entity path (the entity tree is the frame tree, docs/CONVENTIONS.md);
- colours: each method's from ``vnav.methods``, the truth's, the x/y/z axes';
- ``blueprint``: the default layout; ``eye_for``: where the 3D view starts;
- ``describe``: the markdown shown beside the recording.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import rerun.blueprint as rrb

from scenarios.schema import VIEW_NAMES
from scenarios.spec import ScenarioSpec
from vnav.methods import METHODS, PREFERENCE

__all__ = [
    "AXIS_COLORS",
    "CONE0_SERIES",
    "TRUTH_COLOR",
    "VIEWS",
    "blueprint",
    "describe",
    "entity",
    "eye_for",
]


def _error(method: str) -> str:
    return f"metrics/error/{method}"


def _estimate(method: str) -> str:
    return f"world/cones/estimate/{method}"


def _cone0(frame_name: str) -> str:
    return f"coordinates/cone0_{frame_name}"


entity = SimpleNamespace(
    WORLD="world",
    BODY="world/body",
    CAMERA="world/body/camera",
    IMAGE="world/body/camera/image",
    DEPTH="world/body/camera/depth",
    DETECTIONS="world/body/camera/detections",
    KEYPOINTS="world/body/camera/detections/keypoints",
    TRUTH="world/cones/truth",
    DEPTH_CLOUD="world/depth_cloud",
    TRAJECTORY="world/trajectory",
    RANGE="metrics/range_m",
    RPY="attitude/rpy_deg",
    QUAT="attitude/quat_xyzw",
    GIMBAL_LOCK="attitude/gimbal_locked",
    DESCRIPTION="description",
    error=_error,
    estimate=_estimate,
    cone0=_cone0,
)
"""Every entity path of a recording (``entity.error(method)`` and the like for families)."""

CONE0_SERIES: tuple[str, ...] = ("world", "body", "camera", "estimate_world")
"""Cone 0's coordinate series: its truth in three frames and its depth-image estimate."""
TRUTH_COLOR = (255, 255, 255)
AXIS_COLORS = [(230, 80, 80), (80, 200, 80), (80, 120, 240)]
"""x, y, z (and roll, pitch, yaw) in every plot."""


VIEWS: dict[str, int] = {name: i for i, name in enumerate(VIEW_NAMES)}
"""Tabs of the lower left panel, by the name a scenario's ``view`` key uses."""


def blueprint(eye_w=None, look_target_w=None, view: str = "errors") -> rrb.Blueprint:
    """The default layout: plots on the left, the 3D world and the description on the right.

    Parameters
    ----------
    eye_w, look_target_w : array_like, shape (3,), optional
        Where the 3D view's eye starts and what it looks at, world frame (z up).
    view : {"errors", "coordinates", "attitude"}
        The tab shown first below the error plot (see ``VIEWS``).
    """
    if view not in VIEWS:
        raise ValueError(f"view must be one of {list(VIEWS)}, got {view!r}")
    eye = None
    if eye_w is not None and look_target_w is not None:
        eye = rrb.EyeControls3D(position=eye_w, look_target=look_target_w, eye_up=[0, 0, 1])
    checked = [f"+ /{entity.error(m)}" for m in PREFERENCE]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                _image_tabs(),
                rrb.TimeSeriesView(name="position error (m)", origin="metrics", contents=checked),
                _lower_tabs(view),
                row_shares=[3, 2, 3],
            ),
            rrb.Vertical(
                rrb.Spatial3DView(
                    name="world",
                    origin=entity.WORLD,
                    # The depth image would also be drawn back-projected in 3D; the world-frame
                    # cloud computed by vnav (world/depth_cloud) is the one to look at here.
                    contents=["+ $origin/**", f"- /{entity.DEPTH}"],
                    eye_controls=eye,
                ),
                rrb.TextDocumentView(name="scenario", origin=entity.DESCRIPTION),
                row_shares=[4, 1],
            ),
            # Plots left, world right: the viewer's start-up notices (top right) then
            # cover a corner of the large 3D view rather than the camera image.
            column_shares=[2, 3],
        ),
        collapse_panels=True,
    )


def _image_tabs() -> rrb.Tabs:
    """The camera image and the depth image, each with the detections drawn on it."""
    return rrb.Tabs(
        *[
            rrb.Spatial2DView(
                name=name,
                origin=entity.CAMERA,
                contents=[f"+ /{image}", f"+ /{entity.DETECTIONS}/**"],
            )
            for name, image in (("camera", entity.IMAGE), ("depth", entity.DEPTH))
        ]
    )


def _lower_tabs(view: str) -> rrb.Tabs:
    """The tabs below the error plot, in ``VIEWS`` order, ``view`` shown first."""
    return rrb.Tabs(
        rrb.TimeSeriesView(
            name="naive error and range (m)",
            origin="metrics",
            contents=[f"+ /{entity.error('naive')}", f"+ /{entity.RANGE}"],
        ),
        rrb.Grid(
            *[
                rrb.TimeSeriesView(name=f"cone 0 in {f} (m)", origin=entity.cone0(f))
                for f in CONE0_SERIES
            ],
            name="cone 0 in each frame",
        ),
        rrb.Vertical(
            rrb.TimeSeriesView(name="roll, pitch, yaw (deg)", origin=entity.RPY),
            rrb.TimeSeriesView(name="quaternion xyzw", origin=entity.QUAT),
            rrb.TimeSeriesView(name="gimbal lock", origin=entity.GIMBAL_LOCK),
            name="attitude",
        ),
        active_tab=VIEWS[view],
    )


def eye_for(spec: ScenarioSpec) -> tuple[np.ndarray, np.ndarray]:
    """Where the 3D view's eye starts and what it looks at, world frame, each (3,).

    Behind and above the start, looking at the point between the drone and the cones.
    """
    cones_w = np.array(spec.scene.cones_w, dtype=np.float64).reshape(-1, 3)
    start_w = np.asarray(spec.scene.start_position_w)
    target_w = 0.5 * (start_w + cones_w.mean(axis=0))
    heading_w = cones_w.mean(axis=0) - start_w
    heading_w[2] = 0.0
    norm = np.linalg.norm(heading_w)
    heading_w = heading_w / norm if norm > 1e-6 else np.array([1.0, 0.0, 0.0])
    distance_m = max(8.0, 1.5 * float(np.linalg.norm(cones_w.mean(axis=0) - start_w)))
    side_w = np.array([-heading_w[1], heading_w[0], 0.0])
    eye_w = target_w - distance_m * heading_w + 0.6 * distance_m * side_w
    eye_w[2] = target_w[2] + 0.7 * distance_m
    return eye_w, target_w


def describe(spec: ScenarioSpec, seed: int) -> str:
    """Markdown shown beside the recording: what the scenario is and teaches."""
    cam = spec.scene.camera
    lines = [f"# {spec.name}", "", spec.description, ""]
    if spec.lesson:
        lines += [spec.lesson.strip(), ""]
    estimates = ", ".join(
        f"**{m.name}** ({m.color_name}{': ' + m.depth_from if m.bound is None else ''})"
        for m in METHODS
    )
    lines += [
        f"- flight: {spec.flight.mode}, {spec.end_s:g} s simulated, camera at "
        f"{spec.camera_rate_hz:g} Hz, seed {seed}",
        f"- camera: {cam.width}x{cam.height}, fovy {cam.fovy_deg:g} deg, pitched "
        f"{cam.pitch_down_deg:g} deg down at {list(cam.position_b)} m in the body frame",
        f"- cones (base centres, world): {[list(c) for c in spec.scene.cones_w]}",
        "",
        f"Estimates: {estimates}. Truth: white.",
    ]
    return "\n".join(lines)
