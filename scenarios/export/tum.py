"""Camera trajectories in the TUM format, for evo (MichaelGrupp/evo) and the like.

One pose per line, ``t x y z qx qy qz qw``: the stamp in seconds, the camera's position in the
world and its orientation as a unit quaternion, scalar last (the TUM RGB-D benchmark's format,
which ``evo_ape tum A.tum B.tum`` reads). Here the pose is ``T_w_c`` (the optical frame in the
world) and the stamp the image's exposure stamp on the camera clock.

- ``NAME.truth.tum``: the true camera pose at every camera tick;
- ``NAME.pnp.tum``: the camera pose from PnP on the cones the image shows
  (``vnav.multiview.camera_pose_from_cones``, the estimator's pose as the guess that matches
  them), on ticks with at least 4 cones seen whole. A run with no such tick has no PnP
  trajectory: the file is not written (nor left from an earlier run), and the export's note
  says why.

The report gets the PnP trajectory's absolute position error against the truth, the
statistics ``evo_ape tum NAME.truth.tum NAME.pnp.tum`` prints (no alignment, the translation
part, metres): ``rmse``, ``mean``, ``median``, ``std``, ``min``, ``max``, ``sse``.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from scenarios.export.base import ExportResult, write_flushed
from scenarios.run.records import RunResult, TickRecord
from vnav import quat
from vnav.camera import PinholeCamera
from vnav.metrics import error_stats, position_error
from vnav.multiview import camera_pose_from_cones

if TYPE_CHECKING:  # annotations only: importing sim.mesh loads MuJoCo before sim.gl
    from scenarios.scenario.spec import ScenarioSpec
    from sim.mesh import Scenery

__all__ = [
    "PNP_MIN_CONES",
    "TumExporter",
    "ape_statistics",
    "pnp_trajectory",
    "truth_trajectory",
    "tum_text",
]

PNP_MIN_CONES = 4
"""PnP on the cones needs this many seen whole (their apexes and base points)."""


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
        if len(detections) < PNP_MIN_CONES:
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


def ape_statistics(
    truth: tuple[np.ndarray, np.ndarray], estimate: tuple[np.ndarray, np.ndarray]
) -> dict[str, float | int]:
    """The absolute position error of ``estimate`` against ``truth``, as ``evo_ape`` gives it
    with neither alignment nor scale correction (its default: the translation part, metres):
    ``rmse``, ``mean``, ``median``, ``std`` (population), ``min``, ``max``, ``sse``, and
    ``count``, the poses compared.

    Parameters
    ----------
    truth, estimate : tuple of (ndarray, shape (N,), ndarray, shape (N, 4, 4))
        Stamps (seconds) and poses; each estimate's stamp is one of the truth's.

    Raises
    ------
    ValueError
        If ``estimate`` is empty or a stamp of it is not in ``truth``.
    """
    (t_ref, T_ref), (t_est, T_est) = truth, estimate
    if len(t_est) == 0:
        raise ValueError("no estimated pose to compare")
    index = {float(t): i for i, t in enumerate(t_ref)}
    try:
        ref = T_ref[[index[float(t)] for t in t_est]]
    except KeyError as exc:
        raise ValueError(f"estimate stamp {exc.args[0]} is not a truth stamp") from None
    e = position_error(ref[:, :3, 3], T_est[:, :3, 3])
    # evo's statistics are vnav.metrics' and the sum of squares.
    return {**error_stats(e), "sse": float(np.sum(e**2))}


class TumExporter:
    """``NAME.truth.tum`` and ``NAME.pnp.tum`` (``scenarios.export.base.Exporter``): made
    from the finished run; PnP's file only if it found a pose.

    Parameters
    ----------
    staging : Path
        An empty directory: the files are written there under their final names.
    """

    name = "tum"

    def __init__(self, staging: Path) -> None:
        self.staging = Path(staging)
        self._camera: PinholeCamera | None = None

    def start(self, spec: ScenarioSpec, seed: int, camera: PinholeCamera, scenery: Scenery) -> None:
        self._camera = camera

    def on_tick(self, record: TickRecord, rgb: np.ndarray, depth_m: np.ndarray | None) -> None:
        pass  # made from the whole run: PnP needs the estimator's pose of each tick

    def finish(self, result: RunResult) -> ExportResult:
        """Write the trajectories that have a pose; the PnP file's absence is explained."""
        assert self._camera is not None, "start() first"
        name = result.spec.name
        truth_name, pnp_name = f"{name}.truth.tum", f"{name}.pnp.tum"
        truth = truth_trajectory(result)
        pnp = pnp_trajectory(result, self._camera)
        write_flushed(self.staging / truth_name, tum_text(*truth).encode("utf-8"))
        if len(pnp[0]):
            write_flushed(self.staging / pnp_name, tum_text(*pnp).encode("utf-8"))
            return ExportResult(
                "tum", (truth_name, pnp_name), figures={"pnp_ape_m": ape_statistics(truth, pnp)}
            )
        return ExportResult("tum", (truth_name,), (pnp_name,), note=_why_no_pnp(result))

    def abort(self) -> None:
        pass  # nothing but the staging directory, which its owner removes


def _why_no_pnp(result: RunResult) -> str:
    """Why PnP gave no pose in the whole run: one sentence."""
    whole = [sum(not d.detection.touches_border for d in t.detections) for t in result.ticks]
    most = max(whole, default=0)
    pnp = f"{result.spec.name}.pnp.tum not written"
    if most < PNP_MIN_CONES:
        return (
            f"{pnp}: PnP needs {PNP_MIN_CONES} cones seen whole in one image; this run saw at "
            f"most {most}"
        )
    n = sum(w >= PNP_MIN_CONES for w in whole)
    return f"{pnp}: PnP found no pose on the {n} images with {PNP_MIN_CONES} cones or more"
