"""``vnav-demo calibrate FILE.rrd [--out calib.yaml]``: the camera mount and clock offset
from a recording (``scenarios.record.reader``, ``vnav.calibration``), printed with their
standard errors and, where the recording holds the truth, their errors; written as YAML."""

from __future__ import annotations

import argparse
from pathlib import Path

from scenarios.commands.console import error, say
from scenarios.judge.calibration import Truth, errors_against
from scenarios.record.outputs import OutputError, write_atomic
from scenarios.record.reader import RecordingError, calibration_inputs
from vnav import se3
from vnav.calibration import CalibrationError, CalibrationResult

__all__ = ["command", "to_yaml", "write_yaml"]


def to_yaml(result: CalibrationResult) -> str:
    """The result as YAML: ``T_b_c`` (4x4, rows), ``time_offset_s``, ``reprojection_rms_px``,
    ``frames_used`` (written by hand: four keys need no library)."""
    rows = ",\n  ".join(
        "[" + ", ".join(f"{v:.9f}" for v in row) + "]" for row in se3.check_pose(result.T_b_c)
    )
    return (
        f"T_b_c: [\n  {rows}]\n"
        f"time_offset_s: {result.time_offset_s:.9f}\n"
        f"reprojection_rms_px: {result.reprojection_rms_px:.6f}\n"
        f"frames_used: {result.frames_used}\n"
    )


def write_yaml(result: CalibrationResult, path: str | Path) -> None:
    """Write ``to_yaml`` to ``path`` completely or not at all
    (``scenarios.record.outputs.write_atomic``).

    Raises
    ------
    scenarios.record.outputs.OutputError
        If the file cannot be written; ``path`` is then as it was.
    """
    text = to_yaml(result)
    write_atomic(Path(path), lambda tmp: tmp.write_text(text, encoding="utf-8"))


def command(args: argparse.Namespace) -> int:
    """``vnav-demo calibrate FILE.rrd [--out calib.yaml]``: exit status 0, or 2 with one line
    on stderr for a file that is not a usable recording, an output path that cannot be
    written, or a flight that does not determine the answer."""
    recording, out = args.recording, args.out
    out_path = None if out is None else Path(out)
    if out_path is not None and not out_path.parent.is_dir():
        error(f"--out {out}: no such directory {str(out_path.parent)!r}")
        return 2
    try:
        inputs = calibration_inputs(recording)
        solved = inputs.solve()
    except (RecordingError, CalibrationError) as exc:
        error(f"cannot calibrate: {exc}")
        return 2
    except ValueError as exc:  # what vnav refuses in the recording's numbers
        error(f"cannot calibrate: {recording}: {exc}")
        return 2
    say(_table(solved, inputs.truth))
    if out_path is not None:
        try:
            write_yaml(solved, out_path)
        except OutputError as exc:
            error(f"--out {out}: cannot write: {exc.strerror}")
            return 2
        say(f"wrote {out_path}")
    return 0


def _table(result: CalibrationResult, truth: Truth | None) -> str:
    """The answer, its standard errors and, with the truth, its errors, in 80 columns."""
    lines = ["camera mount T_b_c (optical frame in the body):"]
    lines += ["  " + " ".join(f"{v:9.5f}" for v in row) for row in result.T_b_c]
    lines.append(f"clock offset: t_pose = t_cam + {1e3 * result.time_offset_s:.3f} ms")
    lines.append(
        f"reprojection RMS {result.reprojection_rms_px:.3f} px over "
        f"{result.observations_used} apexes in {result.frames_used} images"
    )
    lines.append(
        f"standard errors: rotation {result.std_rotation_deg:.4f} deg, translation "
        f"{1e3 * result.std_translation_m:.2f} mm, offset {1e3 * result.std_offset_s:.3f} ms"
    )
    if truth is not None:
        e = errors_against(result, truth)
        lines.append(
            f"against the truth: rotation {e['rotation_deg']:.4f} deg, translation "
            f"{e['translation_mm']:.2f} mm, offset {e['time_offset_ms']:.3f} ms"
        )
    return "\n".join(lines)
