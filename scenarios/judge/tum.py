"""Camera trajectories in the TUM format, for evo (MichaelGrupp/evo) and the like.

One pose per line, ``t x y z qx qy qz qw``: the stamp in seconds, the camera's position in the
world and its orientation as a unit quaternion, scalar last (the TUM RGB-D benchmark's format,
which ``evo_ape tum A.tum B.tum`` reads). Here the pose is ``T_w_c`` (the optical frame in the
world) and the stamp the image's exposure stamp on the camera clock.

- ``NAME.truth.tum``: the true camera pose at every camera tick;
- ``NAME.pnp.tum``: the camera pose from PnP on the cones the image shows
  (``vnav.multiview.camera_pose_from_cones``, the estimator's pose as the guess that matches
  them), on ticks with at least 4 cones seen whole.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scenarios.run.records import RunResult
from vnav import quat
from vnav.camera import PinholeCamera
from vnav.multiview import camera_pose_from_cones

__all__ = ["output_paths", "pnp_trajectory", "truth_trajectory", "tum_files", "tum_text"]


def _stamp(tick) -> float:
    return tick.t_s if tick.timing is None else tick.timing.stamp_cam_s


def truth_trajectory(result: RunResult) -> tuple[np.ndarray, np.ndarray]:
    """``(stamps_s (N,), T_w_c (N, 4, 4))``: the true camera pose at every tick."""
    stamps = np.array([_stamp(t) for t in result.ticks])
    T = np.array([t.T_w_b @ t.T_b_c for t in result.ticks]).reshape(-1, 4, 4)
    return stamps, T


def pnp_trajectory(result: RunResult, camera: PinholeCamera) -> tuple[np.ndarray, np.ndarray]:
    """``(stamps_s (K,), T_w_c (K, 4, 4))``: PnP on each tick with 4 or more whole cones."""
    stamps, poses = [], []
    cones_w = result.cones_w
    for t in result.ticks:
        detections = [d.detection for d in t.detections if not d.detection.touches_border]
        if len(detections) < 4:
            continue
        try:
            fit, _ = camera_pose_from_cones(
                camera, cones_w, detections, T_w_c_guess=t.T_w_b_est @ t.T_b_c_est
            )
        except ValueError:
            continue
        stamps.append(_stamp(t))
        poses.append(fit.T_w_c)
    return np.array(stamps), np.array(poses).reshape(-1, 4, 4)


def tum_text(stamps_s: np.ndarray, T_w_c: np.ndarray) -> str:
    """The TUM lines of a trajectory (an empty string for none)."""
    q = quat.from_matrix(T_w_c[:, :3, :3]) if len(T_w_c) else np.zeros((0, 4))
    return "".join(
        f"{t:.9f} {p[0]:.9f} {p[1]:.9f} {p[2]:.9f} {x:.9f} {y:.9f} {z:.9f} {w:.9f}\n"
        for t, p, (x, y, z, w) in zip(stamps_s, T_w_c[:, :3, 3], q, strict=True)
    )


def output_paths(name: str, out_dir: Path) -> tuple[Path, Path]:
    """Where a scenario's TUM files go: ``NAME.truth.tum`` and ``NAME.pnp.tum`` in
    ``out_dir``."""
    return Path(out_dir) / f"{name}.truth.tum", Path(out_dir) / f"{name}.pnp.tum"


def tum_files(result: RunResult, camera: PinholeCamera, out_dir: Path) -> dict[Path, str]:
    """The text of ``NAME.truth.tum`` and ``NAME.pnp.tum`` by their paths in ``out_dir``
    (``output_paths``), for the caller to write."""
    truth, pnp = output_paths(result.spec.name, out_dir)
    return {
        truth: tum_text(*truth_trajectory(result)),
        pnp: tum_text(*pnp_trajectory(result, camera)),
    }
