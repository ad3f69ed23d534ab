"""A run in the EuRoC MAV dataset's folder layout (ETH Zurich's ASL format), which VIO and
SLAM front ends and evo read.

``NAME.euroc/mav0/``::

    body.yaml                           what the body frame B is
    cam0/data.csv                       #timestamp [ns],filename: one row per image
    cam0/data/<t_ns>.png                the image the estimator saw (noise included), 8-bit RGB
    cam0/sensor.yaml                    T_BS (the true camera mount, optical frame in the
                                        body), rate_hz, resolution, pinhole intrinsics
                                        [fu, fv, cu, cv], radial-tangential distortion (none)
    depth0/data.csv, data/<t_ns>.png    planar z-depth, 16-bit PNG in millimetres (0: no return:
                                        the sky, beyond the far plane or 65.535 m); sensor.yaml
                                        as cam0's, with depth_scale
    imu0/data.csv                       a scenario with an [imu] only: every reading, stamped on
                                        the IMU's clock: angular rate w_RS_S (rad/s), then
                                        specific force a_RS_S (m/s^2), in the IMU frame S, noise
                                        and bias included
    imu0/sensor.yaml                    T_BS (the declared IMU mount, the one an estimator is
                                        told), rate_hz, Kalibr's four noise figures
    state_groundtruth_estimate0/data.csv   the body's true state at each image's stamp:
                                        p_RS_R, q_RS (w, x, y, z), v_RS_R, gyroscope and
                                        accelerometer biases
    state_groundtruth_estimate0/sensor.yaml

Frames (docs/CONVENTIONS.md, "Data out"): R is vnav's world (z up), S the state's sensor is
the body B itself (FLU; in the real dataset B is the IMU's frame, here it is vnav's body
frame, ``T_BS`` of the ground truth the identity), the camera's S its optical frame (RDF), so
``T_BS`` of cam0 is ``T_b_c``, and the IMU's S its own frame, so ``T_BS`` of imu0 is
``T_b_i``: the declared mount (``sim.config.ImuConfig.T_b_i_declared``), as a dataset's
sensor files carry the calibrated extrinsics, not the truth; the simulator's IMU sits at the
true mount, off it by the scenario's ``[imu.mount_error]`` (the comment says when).

Clocks: the camera's stamps are integer nanoseconds on the camera clock, the images' exposure
stamps, as in the TUM files (``scenarios.export.tum``); the ground truth is given at those same
stamps (the pose clock's ``stamp + camera_clock_offset_s``). The IMU's are on the **IMU's own
clock**, as it stamped them (``scenarios.run.records.ImuRecord.t_s``; Kalibr's
``t_imu = t_cam + timeshift_cam_imu``, the scenario's ``[imu] time_offset_s``), not converted
to the camera's: the real EuRoC rig is hardware-synchronised, this one is not, and the offset
is in the data for a camera-IMU calibration to find, as it would be in a real unsynchronised
rig's (imu0's comment gives it). The ground truth's biases are zero without an IMU, or with
one whose biases do not drift (both random walks zero: its biases stay zero); an IMU's
drifting biases are not kept by the run, so they are written ``nan`` (unknown), not zero.
The depth is millimetres (1000 per metre; TUM RGB-D's PNGs use 5000).

The velocity is the simulator's (``scenarios.run.records.TickRecord.v_w_b_mps``): MuJoCo's
free-joint velocity, or a keyframe flight's segment slope, not a difference of poses.

Images are encoded (``scenarios.export.png``) and written on a worker thread (deflate and file
writes release the GIL), overlapping the next tick's rendering, as the recording's JPEGs are,
and flushed to the disk by a ``scenarios.export.base.Flusher`` (several files at a time, off
the writer's thread). The depth in millimetres is made once for this export and the bag's
(``tick_depth_mm``).
"""

from __future__ import annotations

import logging
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from scenarios.export import png
from scenarios.export.base import (
    DEPTH_SCALE,
    ExportResult,
    Flusher,
    TickDepthMm,
    exporter_threads,
    queue_bound,
    stamp_ns,
    tick_depth_mm,
    write_flushed,
)
from scenarios.export.kalibr import yaml_float
from scenarios.run.records import RunResult, TickRecord
from vnav import quat
from vnav.camera import PinholeCamera

if TYPE_CHECKING:  # annotations only: importing sim.mesh loads MuJoCo before sim.gl
    from scenarios.scenario.spec import ScenarioSpec
    from sim.config import ImuConfig
    from sim.mesh import Scenery

__all__ = [
    "DEPTH_SCALE",
    "GROUNDTRUTH_HEADER",
    "IMU_HEADER",
    "EurocExporter",
]

logger = logging.getLogger(__name__)

RGB_FILTER = png.FILTER_NONE
"""The colour PNG's row filter: none. A rendered image comes out smaller than with the ``SUB``
filter (90 KB against 94 KB at 640x480), and is encoded faster (lossless either way)."""
DEPTH_FILTER = png.FILTER_SUB
"""The 16-bit depth PNG's row filter: ``SUB`` (each byte less the one two bytes left, the same
byte of the pixel before): a smooth depth's high bytes become zeros, and the image is less
than half the size of unfiltered (72 KB against 189 KB for the orbit built-in at 640x480)."""

GROUNDTRUTH_HEADER = (
    "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], "
    "q_RS_z [], v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], "
    "b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], "
    "b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]"
)
"""The EuRoC ground truth's header, column for column."""
IMAGES_HEADER = "#timestamp [ns],filename"
IMU_HEADER = (
    "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
    "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]"
)
"""The EuRoC IMU table's header: the angular rate first, then the specific force."""


def _write_file(path: Path, data: bytes) -> None:
    """Write ``data`` to a new file (an image; the caller hands it to the ``Flusher``)."""
    with open(path, "xb") as f:
        f.write(data)


def _write_images(
    rgb_path: Path,
    rgb: np.ndarray,
    depth_path: Path | None,
    depth_mm: TickDepthMm | None,
    flusher: Flusher,
) -> None:
    """Encode and write one tick's images (on the writer thread); flush them."""
    _write_file(rgb_path, png.encode_png(rgb, RGB_FILTER))
    flusher.submit(rgb_path)
    if depth_path is not None and depth_mm is not None:
        _write_file(depth_path, png.encode_png(depth_mm.get(), DEPTH_FILTER))
        flusher.submit(depth_path)


def _matrix_yaml(T: np.ndarray) -> str:
    """A 4x4 matrix as EuRoC writes ``T_BS``: ``cols``, ``rows``, ``data`` row-major."""
    rows = [", ".join(repr(float(v)) for v in row) for row in np.asarray(T, dtype=np.float64)]
    data = ",\n         ".join(rows)
    return f"  cols: 4\n  rows: 4\n  data: [{data}]\n"


def _camera_yaml(
    kind: str, comment: str, T_b_c: np.ndarray, rate_hz: float, camera: PinholeCamera, more: str
) -> str:
    return (
        "# General sensor definitions.\n"
        f"sensor_type: {kind}\n"
        f"comment: {_quoted(comment)}\n\n"
        "# Sensor extrinsics wrt. the body-frame.\n"
        f"T_BS:\n{_matrix_yaml(T_b_c)}\n"
        "# Camera specific definitions.\n"
        f"rate_hz: {rate_hz:g}\n"
        f"resolution: [{camera.width}, {camera.height}]\n"
        "camera_model: pinhole\n"
        f"intrinsics: [{float(camera.fx)!r}, {float(camera.fy)!r}, {float(camera.cx)!r}, "
        f"{float(camera.cy)!r}]"
        " #fu, fv, cu, cv\n"
        "distortion_model: radial-tangential\n"
        "distortion_coefficients: [0.0, 0.0, 0.0, 0.0]\n" + more
    )


class EurocExporter:
    """``NAME.euroc/`` (``scenarios.export.base.Exporter``; the layout in the module doc).

    Parameters
    ----------
    staging : Path
        An empty directory: ``NAME.euroc/`` is made in it.
    """

    name = "euroc"

    def __init__(self, staging: Path) -> None:
        self.staging = Path(staging)
        self._root: Path | None = None
        self._spec: ScenarioSpec | None = None
        self._camera: PinholeCamera | None = None
        self._seed = 0
        self._writer: ThreadPoolExecutor | None = None
        self._flusher: Flusher | None = None
        self._pending: deque[Future] = deque()
        self._images: list[int] = []
        self._depths: list[int] = []
        self._states: list[str] = []
        self._T_b_c_first: np.ndarray | None = None
        self._mount_moved = False
        self._biases_known = True

    def start(self, spec: ScenarioSpec, seed: int, camera: PinholeCamera, scenery: Scenery) -> None:
        self._spec, self._camera, self._seed = spec, camera, seed
        self._biases_known = _biases_stay_zero(spec)
        self._root = self.staging / f"{spec.name}.euroc"
        mav0 = self._root / "mav0"
        for sub in ("cam0/data", "depth0/data", "state_groundtruth_estimate0"):
            (mav0 / sub).mkdir(parents=True)
        self._writer = exporter_threads(1, "vnav-euroc")
        self._flusher = Flusher()

    def on_tick(self, record: TickRecord, rgb: np.ndarray, depth_m: np.ndarray | None) -> None:
        """Queue the tick's images for the writer thread (a tick waits for it beyond
        ``queue_bound``); keep its ground-truth row."""
        assert self._writer is not None and self._root is not None, "start() first"
        self._raise_done()
        t_ns = stamp_ns(record)
        mav0 = self._root / "mav0"
        depth_path, mm = None, None
        if depth_m is not None:
            depth_path = mav0 / "depth0" / "data" / f"{t_ns}.png"
            mm = tick_depth_mm(record, depth_m, self._spec.scene.zfar_m)
        self._pending.append(
            self._writer.submit(
                _write_images,
                mav0 / "cam0" / "data" / f"{t_ns}.png",
                rgb,
                depth_path,
                mm,
                self._flusher,
            )
        )
        self._images.append(t_ns)
        if depth_path is not None:
            self._depths.append(t_ns)
        self._states.append(_state_row(t_ns, record, self._biases_known))
        if self._T_b_c_first is None:
            self._T_b_c_first = record.T_b_c
        elif not np.array_equal(record.T_b_c, self._T_b_c_first):
            self._mount_moved = True
        while len(self._pending) > queue_bound(rgb, depth_m):
            self._pending.popleft().result()

    def _raise_done(self) -> None:
        """Raise a finished write's error now (a full disk stops the run early)."""
        while self._pending and self._pending[0].done():
            self._pending.popleft().result()

    def finish(self, result: RunResult) -> ExportResult:
        """Wait for the images, then write the tables and the sensors' descriptions."""
        assert self._writer is not None and self._root is not None, "start() first"
        try:
            while self._pending:
                self._pending.popleft().result()
            self._flusher.wait()
        finally:
            self._writer.shutdown(wait=True, cancel_futures=True)
            self._flusher.shutdown()
        mav0, spec = self._root / "mav0", self._spec
        about = f"vnav-sim scenario {spec.name}, seed {self._seed}"
        _write_text(
            mav0 / "body.yaml",
            "# Additional sensor information\n"
            "comment: "
            + _quoted(
                "The body frame B is vnav's body frame (FLU: x forward, y left, z up, at the "
                "drone's centre of mass), not an IMU's; every T_BS is relative to it."
            )
            + "\n",
        )
        self._write_cameras(mav0, about)
        imu = spec.scene.imu
        if imu is not None:
            _write_imu(mav0 / "imu0", about, imu, result)
        self._write_ground_truth(mav0 / "state_groundtruth_estimate0", about)
        return ExportResult("euroc", (self._root.name,), note="; ".join(self._notes()))

    def _write_cameras(self, mav0: Path, about: str) -> None:
        """``cam0/`` and ``depth0/``: the image tables and the sensors' descriptions (the
        depth folder removed when the run rendered no depth)."""
        spec, camera = self._spec, self._camera
        T_b_c = self._T_b_c_first if self._T_b_c_first is not None else np.eye(4)
        moved = (
            " The camera slides on the body in this flight: T_BS is its mount at the first image."
            if self._mount_moved
            else ""
        )
        _write_text(mav0 / "cam0" / "data.csv", _image_table(self._images))
        _write_text(
            mav0 / "cam0" / "sensor.yaml",
            _camera_yaml(
                "camera",
                f"{about}: the onboard camera (MuJoCo render, the scenario's image noise "
                f"included), 8-bit RGB PNG; T_BS is the true mount T_b_c, optical frame "
                f"(x right, y down, z forward) in the body.{moved}",
                T_b_c,
                spec.camera_rate_hz,
                camera,
                "",
            ),
        )
        if not self._depths:
            (mav0 / "depth0" / "data").rmdir()
            (mav0 / "depth0").rmdir()
            return
        _write_text(mav0 / "depth0" / "data.csv", _image_table(self._depths))
        _write_text(
            mav0 / "depth0" / "sensor.yaml",
            _camera_yaml(
                "depth",
                f"{about}: planar z-depth along the optical axis of cam0 (the same pixels "
                "and stamps, the scenario's depth noise included), 16-bit PNG, "
                "millimetres; 0 is no return (the sky, the far plane, beyond 65.535 m).",
                T_b_c,
                spec.camera_rate_hz,
                camera,
                f"depth_scale: {DEPTH_SCALE:g} # pixel value per metre\n",
            ),
        )

    def _write_ground_truth(self, state: Path, about: str) -> None:
        """``state_groundtruth_estimate0/``: the body's true state at each image's stamp."""
        imu = self._spec.scene.imu
        _write_text(state / "data.csv", GROUNDTRUTH_HEADER + "\n" + "".join(self._states))
        _write_text(
            state / "sensor.yaml",
            "# Additional sensor information\n"
            "sensor_type: ground-truth\n"
            "comment: "
            + _quoted(
                f"{about}: the simulator's true body state at each image's stamp (camera "
                "clock); p and v in the world (z up), q the body's attitude (w, x, y, z); "
                + _biases_comment(imu, self._biases_known)
            )
            + "\n\n"
            "# Sensor extrinsics wrt. the body-frame.\n"
            f"T_BS:\n{_matrix_yaml(np.eye(4))}",
        )

    def _notes(self) -> list[str]:
        """What the export leaves out or does differently from EuRoC, in words."""
        imu = self._spec.scene.imu
        notes = []
        if imu is None:
            notes.append("no IMU (imu0/): the scenario has no [imu]")
        else:
            notes.append(
                "imu0/ is stamped on the IMU's clock (t_imu = t_cam + "
                f"{imu.time_offset_s:g} s), not the camera's"
            )
            if not self._biases_known:
                notes.append("the ground truth's biases are nan: the run keeps no IMU biases")
        if self._mount_moved:
            notes.append("the camera slides in this flight: cam0's T_BS is its first mount")
        if self._images and self._images[0] < 0:
            notes.append("the camera clock starts before zero: the first stamps are negative")
        return notes

    def abort(self) -> None:
        """Stop the writer (the staging directory is its owner's to remove)."""
        if self._writer is not None:
            self._writer.shutdown(wait=True, cancel_futures=True)
        if self._flusher is not None:
            self._flusher.shutdown()
        self._pending.clear()


def _quoted(text: str) -> str:
    """A YAML single-quoted string (a plain one cannot hold ``: ``)."""
    return "'" + text.replace("'", "''") + "'"


def _write_text(path: Path, text: str) -> None:
    write_flushed(path, text.encode("utf-8"))


def _image_table(stamps_ns: list[int]) -> str:
    return IMAGES_HEADER + "\n" + "".join(f"{t},{t}.png\n" for t in stamps_ns)


def _state_row(t_ns: int, record: TickRecord, biases_known: bool = True) -> str:
    """One ground-truth row: the body's position, attitude (w first), velocity, and the
    biases: zero where they are known to be (``_biases_stay_zero``), ``nan`` otherwise."""
    p = record.T_w_b[:3, 3]
    x, y, z, w = quat.from_matrix(record.T_w_b[:3, :3])
    v = record.v_w_b_mps if record.v_w_b_mps is not None else np.full(3, np.nan)
    values = [*p, w, x, y, z, *v, *([0.0 if biases_known else np.nan] * 6)]
    return f"{t_ns}," + ",".join(f"{float(u):.9f}" for u in values) + "\n"


def _biases_stay_zero(spec: ScenarioSpec) -> bool:
    """Whether the ground truth's biases are known to be zero: no IMU, or one whose biases
    do not drift (``vnav.imu.ImuNoiseProcess`` starts them at zero)."""
    imu = spec.scene.imu
    return imu is None or not (imu.accelerometer_random_walk or imu.gyroscope_random_walk)


def _biases_comment(imu: ImuConfig | None, known: bool) -> str:
    if imu is None:
        return "biases zero (the scenario has no IMU)."
    if known:
        return "biases zero (the IMU's do not drift: both random walks are zero)."
    return (
        "biases nan: unknown (the IMU's biases drift from zero and the run does not keep "
        "them); imu0's readings carry them."
    )


def _write_imu(imu0: Path, about: str, imu: ImuConfig, result: RunResult) -> None:
    """``imu0/data.csv`` (every reading on the IMU's clock, rad/s then m/s^2, in full) and
    ``imu0/sensor.yaml`` (the declared mount, the rate, Kalibr's noise figures)."""
    imu0.mkdir()
    record = result.imu
    rows = []
    if record is not None:
        for t_s, gyro_i, accel_i in zip(record.t_s, record.gyro_i, record.accel_i, strict=True):
            values = ",".join(repr(float(v)) for v in (*gyro_i, *accel_i))
            rows.append(f"{round(float(t_s) * 1e9)},{values}\n")
    _write_text(imu0 / "data.csv", IMU_HEADER + "\n" + "".join(rows))
    mount = (
        "T_BS is the declared mount T_b_i (the IMU frame in the body), the one an estimator is "
        "told; the simulator's IMU sits at the true mount, off it by the scenario's "
        "[imu.mount_error]."
        if not imu.mount_error.is_zero
        else "T_BS is the mount T_b_i (the IMU frame in the body), declared and true alike."
    )
    comment = (
        f"{about}: the IMU (MuJoCo's accelerometer and gyro at the IMU's site, Kalibr's noise "
        "model with the figures below, bias included), angular rate w (rad/s) and specific "
        "force a (m/s^2) in the IMU frame; stamps on the IMU's clock, t_imu = t_cam + "
        f"{imu.time_offset_s!r} s (Kalibr's timeshift_cam_imu), not synchronised with cam0's. "
        + mount
    )
    _write_text(
        imu0 / "sensor.yaml",
        "# General sensor definitions.\n"
        "sensor_type: imu\n"
        f"comment: {_quoted(comment)}\n\n"
        "# Sensor extrinsics wrt. the body-frame.\n"
        f"T_BS:\n{_matrix_yaml(imu.T_b_i_declared)}"
        f"rate_hz: {imu.rate_hz:g}\n\n"
        "# inertial sensor noise model parameters (static)\n"
        f"gyroscope_noise_density: {yaml_float(imu.gyroscope_noise_density)}"
        '  # [ rad / s / sqrt(Hz) ]   ( gyro "white noise" )\n'
        f"gyroscope_random_walk: {yaml_float(imu.gyroscope_random_walk)}"
        "  # [ rad / s^2 / sqrt(Hz) ] ( gyro bias diffusion )\n"
        f"accelerometer_noise_density: {yaml_float(imu.accelerometer_noise_density)}"
        '  # [ m / s^2 / sqrt(Hz) ]   ( accel "white noise" )\n'
        f"accelerometer_random_walk: {yaml_float(imu.accelerometer_random_walk)}"
        "  # [ m / s^3 / sqrt(Hz) ]   ( accel bias diffusion )\n",
    )
