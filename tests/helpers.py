"""Shared test helpers, one place for every test file (``from helpers import ...``).

- Samplers of rotations, quaternions and transforms: numpy ones for the reference tests
  (uniform plus the hard cases) and Hypothesis strategies for the property tests. Near-identity
  and near-pi rotations exercise the small-angle and antipodal branches of ``so3.exp``,
  ``so3.log`` and ``quat.from_matrix``; exactly pi about a general axis is included.
- Comparisons up to the double cover (``q`` and ``-q``) and the sign of a rotation vector at pi.
- The onboard camera's pose as MuJoCo itself computes it (``cam_xpos`` / ``cam_xmat``).
- Rendering helpers (one cone seen from a level drone, a scene's RGB image) and synthetic cone
  images painted by pixel-centre inclusion.
- The cone's extreme points written out by hand.
- Reading a Rerun 0.41 recording back (``rerun.chunk.RrdReader`` + pyarrow).
- The built-in scenario runs shared by the session fixture in ``conftest.py``.
- The pytest plugin's arguments for a pytest run of its own (``plugin_args``).

MuJoCo renders off-screen through EGL: ``conftest.py`` sets ``MUJOCO_GL`` before this module
(and with it MuJoCo) is imported.
"""

from __future__ import annotations

import dataclasses
import os
from collections import OrderedDict
from pathlib import Path

import numpy as np
import pyarrow as pa
from hypothesis import settings
from hypothesis import strategies as st
from rerun.chunk import RrdReader

from sim import names
from sim.config import CameraConfig, SceneConfig
from sim.render import Renderer
from sim.world import World
from vnav import quat, se3, so3
from vnav.cone import TRAFFIC_CONE
from vnav.detect import detect_cones
from vnav.metrics import horizontal_error

# ------------------------------------------------------------------------- numpy samplers

N_REFERENCE = 300
"""Samples per comparison with an independent implementation (MuJoCo, OpenCV)."""

REFERENCE_SEED = 20240516
"""Seed of the ``rng`` fixture (conftest.py) the reference tests draw from."""


def unit_vectors(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.standard_normal((n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def rotation_vectors(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) rotation vectors with angles in [0, pi]: uniform, tiny, near pi and exactly pi."""
    axes = unit_vectors(rng, n)
    k = n // 6
    angles = np.concatenate(
        [
            rng.uniform(0.0, np.pi, n - 5 * k),
            10.0 ** rng.uniform(-12, -3, k),  # near identity
            np.pi - 10.0 ** rng.uniform(-12, -3, k),  # near pi
            np.full(k, np.pi),  # exactly pi
            np.zeros(k),  # identity
            rng.uniform(0.0, 1e-7, k),
        ]
    )
    return axes * angles[:, None]


def quaternions(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 4) unit quaternions [x, y, z, w], both signs, including w = 0 and w = +-1."""
    q = rng.standard_normal((n, 4))
    q[: n // 8, 3] = 0.0  # rotations by pi
    q[n // 8 : n // 4, :3] *= 1e-9  # near identity
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def random_poses(rng: np.random.Generator, n: int, max_t_m: float = 10.0) -> np.ndarray:
    """(n, 4, 4) rigid transforms: rotations from ``rotation_vectors``, translations uniform
    in +-``max_t_m`` per axis."""
    return se3.make(so3.exp(rotation_vectors(rng, n)), rng.uniform(-max_t_m, max_t_m, (n, 3)))


# -------------------------------------------------------------------- Hypothesis strategies

PROPERTY_SETTINGS = settings(max_examples=150, deadline=None)
"""Hypothesis settings of the geometry properties."""

unit_float = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)


@st.composite
def unit_axes(draw) -> np.ndarray:
    v = np.array([draw(unit_float), draw(unit_float), draw(unit_float)])
    n = np.linalg.norm(v)
    if n < 1e-3:
        v, n = np.array([0.0, 0.0, 1.0]), 1.0
    return v / n


angles = st.one_of(
    st.floats(0.0, np.pi),
    st.floats(-15.0, -3.0).map(lambda e: 10.0**e),  # near identity
    st.floats(-15.0, -3.0).map(lambda e: np.pi - 10.0**e),  # near pi
    st.just(np.pi),
    st.just(0.0),
)


@st.composite
def rotvecs(draw) -> np.ndarray:
    return draw(unit_axes()) * draw(angles)


@st.composite
def rotations(draw) -> np.ndarray:
    return so3.exp(draw(rotvecs()))


@st.composite
def unit_quaternions(draw) -> np.ndarray:
    q = quat.from_rotvec(draw(rotvecs()))
    return -q if draw(st.booleans()) else q  # both signs


translations = st.lists(st.floats(-100.0, 100.0), min_size=3, max_size=3).map(np.array)


@st.composite
def transforms(draw) -> np.ndarray:
    return se3.make(draw(rotations()), draw(translations))


# ----------------------------------------------------------------------------- comparisons


def assert_same_rotvec(a: np.ndarray, b: np.ndarray, atol: float) -> None:
    """Equal rotation vectors; at an angle of pi, u pi and -u pi are the same rotation."""
    if np.linalg.norm(b) > np.pi - 1e-6 and np.dot(a, b) < 0:
        b = -b
    np.testing.assert_allclose(a, b, atol=atol)


def same_rotation_quat(a: np.ndarray, b: np.ndarray, atol: float) -> None:
    """a and b are the same rotation: equal up to the sign (q and -q)."""
    sign = np.where(np.sum(a * b, axis=-1) < 0.0, -1.0, 1.0)[..., None]
    np.testing.assert_allclose(a, sign * b, atol=atol)


# ----------------------------------------------------------------------------------- MuJoCo

R_GLC_TO_OPTICAL = np.diag([1.0, -1.0, -1.0])
"""MuJoCo's camera axes (OpenGL: x right, y up, looking along -z) to the optical frame."""


def mujoco_T_w_c(world: World) -> np.ndarray:
    """The onboard camera pose from MuJoCo's cam_xpos / cam_xmat, turned optical."""
    cam = world.model.camera(names.ONBOARD_CAMERA).id
    T = np.eye(4)
    T[:3, :3] = world.data.cam_xmat[cam].reshape(3, 3) @ R_GLC_TO_OPTICAL
    T[:3, 3] = world.data.cam_xpos[cam]
    return T


# ------------------------------------------------------------- SE(3) exp and log, stacked


def se3_exp_stack(xi: np.ndarray) -> np.ndarray:
    """``vnav.se3.exp`` of each row of ``xi`` (n, 6) ``[rho, phi]``: (n, 4, 4).

    For Monte Carlo draws by the thousand. B&F eq. 7 and 8 written out for stacks: the
    rotation ``so3.exp(phi)``, the translation ``J(phi) rho`` with SO(3)'s left Jacobian
    ``J = I + (1 - cos t) / t^2 phi^ + (t - sin t) / t^3 phi^2`` (its Taylor series below
    1e-6 rad, as vnav). ``test_uncertainty`` holds it equal to ``se3.exp`` row by row."""
    xi = np.asarray(xi, dtype=np.float64).reshape(-1, 6)
    rho, phi = xi[:, :3], xi[:, 3:]
    theta = np.linalg.norm(phi, axis=1)
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    a = np.where(small, 0.5, (1.0 - np.cos(t)) / t**2)
    b = np.where(small, 1.0 / 6.0, (t - np.sin(t)) / t**3)
    S = so3.skew(phi)
    J = np.eye(3) + a[:, None, None] * S + b[:, None, None] * (S @ S)
    return se3.make(so3.exp(phi), np.einsum("nij,nj->ni", J, rho))


def se3_log_stack(T: np.ndarray) -> np.ndarray:
    """``vnav.se3.log`` of each of ``T`` (n, 4, 4): (n, 6) ``[rho, phi]``, the
    rotation angle in [0, pi]: ``phi = so3.log(R)``, ``rho = J(phi)^-1 t`` with
    ``J^-1 = I - phi^ / 2 + (1 - (t / 2) / tan(t / 2)) / t^2 phi^2`` (Taylor below 1e-6 rad,
    as vnav). ``test_uncertainty`` holds it equal to ``se3.log`` one by one."""
    T = np.asarray(T, dtype=np.float64).reshape(-1, 4, 4)
    phi = so3.log(T[:, :3, :3])
    theta = np.linalg.norm(phi, axis=1)
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    c = np.where(small, 1.0 / 12.0, (1.0 - 0.5 * t / np.tan(0.5 * t)) / t**2)
    S = so3.skew(phi)
    J_inv = np.eye(3) - 0.5 * S + c[:, None, None] * (S @ S)
    return np.concatenate([np.einsum("nij,nj->ni", J_inv, T[:, :3, 3]), phi], axis=1)


# ------------------------------------------------------------------------------------ cones


def cone_corners_w(p0_w: np.ndarray) -> np.ndarray:
    """The cone's extreme points: the base plate's 8 corners and the apex, (9, 3), metres."""
    a, t = TRAFFIC_CONE.base_width_m / 2, TRAFFIC_CONE.base_thickness_m
    pts = [(sx * a, sy * a, z) for sx in (-1, 1) for sy in (-1, 1) for z in (0.0, t)]
    pts.append((0.0, 0.0, TRAFFIC_CONE.height_m))
    return np.array(pts) + p0_w


# -------------------------------------------------------------------------------- rendering


def render_scene(cones_w: tuple, T_w_b: np.ndarray) -> np.ndarray:
    """The onboard camera's RGB image of a scene with ``cones_w``, drone at ``T_w_b``."""
    world = World.from_config(SceneConfig(cones_w=cones_w))
    world.set_pose(T_w_b)
    with Renderer(world) as renderer:
        return renderer.render(depth=False).rgb


def render_one(cone_xy: tuple[float, float], height_m: float, pitch_deg: float, yaw: float = 0.0):
    """Render one cone from a level drone at (0, 0, height_m); return (world, frame, detections)."""
    world = World.from_config(
        SceneConfig(cones_w=((*cone_xy, 0.0),), camera=CameraConfig(pitch_down_deg=pitch_deg))
    )
    world.set_pose(se3.make(so3.rot_z(yaw), [0.0, 0.0, height_m]))
    with Renderer(world) as renderer:
        frame = renderer.render(depth=True)
    return world, frame, detect_cones(frame.rgb)


def render_one_view() -> dict:
    """The default scene's cone at (6, 1, 0) m seen from a level drone 4 m above the origin,
    yawed to face it: ``{"world", "frame" (rgb, depth, segmentation), "detection", "far_m"}``."""
    world = World.from_config(SceneConfig())
    T_w_b = se3.make(so3.from_rpy(0.0, 0.0, np.arctan2(1.0, 6.0)), [0.0, 0.0, 4.0])
    world.set_pose(T_w_b)
    with Renderer(world) as renderer:
        frame = renderer.render(depth=True, segmentation=True)
    far_m = 0.99 * world.model.vis.map.zfar * world.model.stat.extent
    (detection,) = detect_cones(frame.rgb)
    return {"world": world, "frame": frame, "detection": detection, "far_m": far_m}


def relative_error(world: World, p_w: np.ndarray) -> float:
    """Horizontal error of ``p_w`` from the world's first cone over the camera's range to it."""
    p0_w = world.cones_w[0]
    return float(horizontal_error(p0_w, p_w)[0] / np.linalg.norm(p0_w - world.T_w_c[:3, 3]))


# ----------------------------------------------------------------------- synthetic images

ORANGE = np.array([round(255 * c) for c in TRAFFIC_CONE.color_rgb], dtype=np.uint8)
BACKGROUND = np.array([90, 110, 80], dtype=np.uint8)


def synthetic_cone(
    image: np.ndarray, apex_uv: tuple[float, float], height_px: float, half_angle: float = 0.22
) -> None:
    """Paint an upright triangle (apex at ``apex_uv``, base ``height_px`` below) by pixel-centre
    inclusion, the rasterisation rule of OpenGL."""
    v, u = np.mgrid[0 : image.shape[0], 0 : image.shape[1]]
    t = (v - apex_uv[1]) / height_px
    inside = (t >= 0) & (t <= 1) & (np.abs(u - apex_uv[0]) <= half_angle * height_px * t)
    image[inside] = ORANGE


def blank() -> np.ndarray:
    """A 640 x 480 image of the background colour."""
    return np.tile(BACKGROUND, (480, 640, 1))


# ------------------------------------------------------------------------- Rerun recordings


_RECORDINGS: OrderedDict[tuple, list[tuple[str, pa.Table]]] = OrderedDict()
"""The last recordings read: (entity path, chunk as an Arrow table) in file order."""


def _chunks(path: Path) -> list[tuple[str, pa.Table]]:
    """Every chunk of the recording at ``path`` with its entity path, in file order; the file
    read once while it is unchanged (a test reads a recording's entities one by one, and each
    filtered read is a pass over the whole file, images included). Arrow tables are
    immutable: ``read_rows`` builds new rows from them at every call."""
    stat = os.stat(path)
    key = (os.path.realpath(path), stat.st_ino, stat.st_size, stat.st_mtime_ns)
    if key not in _RECORDINGS:
        _RECORDINGS[key] = [
            (chunk.entity_path, pa.Table.from_batches([chunk.to_record_batch()]))
            for chunk in RrdReader(str(path)).stream().to_chunks()
        ]
        while len(_RECORDINGS) > 16:  # the built-in runs' 10, and a few more
            _RECORDINGS.popitem(last=False)
    _RECORDINGS.move_to_end(key)
    return _RECORDINGS[key]


def entity_paths(path: Path) -> set[str]:
    """Every entity path the recording at ``path`` logs to (with a leading ``/``)."""
    return {entity_path for entity_path, _ in _chunks(path)}


def read_rows(path: Path, entity: str) -> list[dict]:
    """Every row logged to ``entity`` as a dict {column name: value}, in file order.

    ``entity`` is an entity path, or a subtree ``path/**`` (Rerun's entity path filter; any
    other filter expression is handed to Rerun's own). Columns are named like
    ``Transform3D:translation`` (each value a list of instances); timeline columns ``tick``
    and ``sim_time`` become ints (``sim_time`` in nanoseconds). Static rows have no timeline
    columns.
    """
    entity = "/" + entity.lstrip("/")
    base = entity.removesuffix("/**")
    if not base or any(c in base for c in "*+- "):  # ("/**" leaves out /__properties)
        reader = RrdReader(str(path)).stream().filter(content=entity).to_chunks()
        tables = [pa.Table.from_batches([chunk.to_record_batch()]) for chunk in reader]
    else:
        subtree = base != entity
        tables = [
            table
            for path_, table in _chunks(path)
            if path_ == base or (subtree and path_.startswith(base.rstrip("/") + "/"))
        ]
    rows: list[dict] = []
    for table in tables:
        columns = {}
        for name in table.column_names:
            column = table.column(name)
            if pa.types.is_timestamp(column.type) or pa.types.is_duration(column.type):
                column = column.cast(pa.int64())
            columns[name] = column.to_pylist()
        rows.extend({k: v[i] for k, v in columns.items()} for i in range(table.num_rows))
    return rows


def mat3x3(flat_column_major) -> np.ndarray:
    """Rerun stores 3x3 matrices column-major: back to a numpy (3, 3)."""
    return np.asarray(flat_column_major, dtype=np.float64).reshape(3, 3).T


# ------------------------------------------------------------------------ built-in scenarios

BUILTIN_TEST_RATE_HZ = 5.0
"""Built-in scenarios run in tests at 5 Hz instead of 10: the same flights, half the frames."""


@dataclasses.dataclass
class BuiltinRun:
    """One built-in scenario's run: its spec, records, judged checks, report and files."""

    spec: object
    result: object
    judged: list
    report: dict
    rrd: object
    json_path: object


# ------------------------------------------------------------------------ the pytest plugin

PYTEST_PLUGIN = "scenarios.grading.pytest_plugin"
"""vnav-sim's pytest plugin, registered by the ``pytest11`` entry point ``vnav``."""


def plugin_args() -> list[str]:
    """What a pytest run of its own (a subprocess, pytester) needs to load the plugin: nothing
    once the installed vnav-sim declares its entry point (pytest loads it; naming it again
    would register it twice), else ``-p`` and its module (an editable install made before the
    entry point existed)."""
    from importlib.metadata import entry_points

    installed = any(ep.value == PYTEST_PLUGIN for ep in entry_points(group="pytest11"))
    return [] if installed else ["-p", PYTEST_PLUGIN]
