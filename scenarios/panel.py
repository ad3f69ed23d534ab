"""The state panel: the lecture's quantities at one camera tick, as text for the viewer.

At the time cursor the recording shows, as numbers (VNAV lecture 1):

- the poses ``T_w_b``, ``T_b_c`` and their composition ``T_w_c = T_w_b T_b_c`` (chapter 8),
  4x4, rounded (rotation to 3 decimals, translation to the centimetre);
- cone 0 as the camera sees it and through the chain ``p_c -> p_b = T_b_c p_c ->
  p_w = T_w_b p_b`` (chapter 0), next to the naive ``t_w_b + p_c``;
- the attitude ``R_w_b`` as roll, pitch, yaw (chapter 4) with the gimbal-lock flag, as a
  quaternion (chapter 6, x y z w) and as axis-angle (chapter 5, Rodrigues' formula).

All of it is the simulator's truth at that tick (the estimator's noisy pose is not shown).
"""

from __future__ import annotations

import math

import numpy as np

from scenarios.records import TickRecord
from vnav import quat
from vnav.estimators import naive

__all__ = ["state_text"]


def _number(x: float, decimals: int, width: int) -> str:
    # + 0.0 turns -0.0 into 0.0: a rounded "-0.000" would read as a sign error.
    return f"{round(float(x), decimals) + 0.0:{width}.{decimals}f}"


def _matrix_rows(T: np.ndarray) -> list[str]:
    """Four rows of a 4x4 pose: rotation to 3 decimals | translation to the centimetre."""
    return [
        " ".join(_number(T[i, j], 3, 6) for j in range(3)) + " |" + _number(T[i, 3], 2, 7)
        for i in range(4)
    ]


def _vector(p: np.ndarray, decimals: int = 2, width: int = 7) -> str:
    return "[" + " ".join(_number(x, decimals, width) for x in p) + "]"


def state_text(record: TickRecord, quat_xyzw: np.ndarray, cone0_w: np.ndarray) -> str:
    """Markdown for the state panel at one tick.

    Parameters
    ----------
    record : TickRecord
        The tick (its true ``T_w_b``, ``T_b_c``, attitude and gimbal-lock flag are shown).
    quat_xyzw : ndarray, shape (4,)
        The attitude as plotted: ``record.quat_xyzw`` with the sign that keeps the plotted
        quaternion continuous (``q`` and ``-q`` are the same rotation).
    cone0_w : ndarray, shape (3,)
        Cone 0's true base centre in the world, metres.
    """
    T_w_b, T_b_c = record.T_w_b, record.T_b_c
    T_w_c = T_w_b @ T_b_c
    names = ("T_w_b: body in world", "T_b_c: camera in body", "T_w_c = T_w_b T_b_c")
    blocks = [_matrix_rows(T) for T in (T_w_b, T_b_c, T_w_c)]
    lines = ["   ".join(f"{n:<29}" for n in names).rstrip()]
    lines += ["   ".join(rows[i] for rows in blocks) for i in range(4)]

    p = record.coordinates_of(cone0_w)
    lines += [
        "",
        f"cone 0  p_c               {_vector(p['camera'])}  camera: x right, y down, z fwd",
        f"        p_b = T_b_c p_c   {_vector(p['body'])}  body: x fwd, y left, z up",
        f"        p_w = T_w_b p_b   {_vector(p['world'])}  world: z up",
        f"naive   t_w_b + p_c       {_vector(naive(p['camera'], T_w_b[:3, 3]))}"
        "  wrong: p_c is not a world offset",
    ]

    roll, pitch, yaw = np.degrees(record.rpy_rad)
    axis, angle = quat.to_axis_angle(quat_xyzw, normalize=True)
    lock = "LOCKED: only yaw - roll is defined" if record.gimbal_locked else "no"
    flipped = quat_xyzw[3] < 0.0
    lines += [
        "",
        f"R_w_b   roll {_number(roll, 1, 6)}  pitch {_number(pitch, 1, 6)}  "
        f"yaw {_number(yaw, 1, 6)} deg    gimbal lock: {lock}",
        f"        quaternion xyzw {_vector(quat_xyzw, 3, 6)}"
        + ("  (w < 0: -q is the same rotation)" if flipped else ""),
        f"        axis-angle  axis {_vector(axis, 3, 6)}  angle "
        f"{_number(math.degrees(angle), 1, 6)} deg  (R = I + sin(a) K + (1 - cos(a)) K^2)",
    ]
    header = f"**tick {record.tick}, t = {record.t_s:.2f} s** (simulator truth)"
    return header + "\n\n```\n" + "\n".join(lines) + "\n```\n"
