"""The worked examples and quiz answers of MIT 16.485 VNAV lecture 1, computed with ``vnav``.

Each ``Example`` holds the lecture's own answer (as printed there, at its printed precision) and a
function that computes the same quantity with the library; ``vnav-demo lecture`` prints them side
by side (``table``). The tests (tests/test_lecture.py) state the lecture's numbers themselves
rather than reading them from here.
"""

from __future__ import annotations

import argparse
import textwrap
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from scenarios.commands.console import WIDTH, say
from vnav import frames, quat, se3, so3

__all__ = ["EXAMPLES", "Example", "Outcome", "command", "evaluate", "table"]


@dataclass(frozen=True)
class Example:
    """One worked example: the lecture's answer and how vnav computes it."""

    chapter: int
    what: str
    lecture: np.ndarray | float
    compute: Callable[[], np.ndarray | float]
    decimals: int  # the precision the lecture prints; agreement is judged at half its last digit


@dataclass(frozen=True)
class Outcome:
    """An example's result: vnav's value, its largest deviation from the lecture, agreement."""

    example: Example
    value: np.ndarray
    error: float
    agrees: bool


# The lecture's chapter 7 chain: body at world [5, 0, 0] yawed 90 deg; camera at body
# [0.3, 0, 0.2] with no rotation relative to the body.
def _T_w_r() -> np.ndarray:
    return se3.make(so3.rot_z(np.pi / 2), [5.0, 0.0, 0.0])


def _T_r_c() -> np.ndarray:
    return se3.make(np.eye(3), [0.3, 0.0, 0.2])


def _ch0_landmark() -> np.ndarray:
    # Camera at the body origin looking forward (optical z = body x); body yawed 90 deg
    # clockwise seen from above, i.e. -90 deg about the world's up axis.
    T_w_b = se3.make(so3.rot_z(-np.pi / 2), [0.0, 0.0, 0.0])
    T_b_c = se3.make(frames.R_FLU_RDF, [0.0, 0.0, 0.0])
    return se3.apply(T_w_b @ T_b_c, [0.0, 0.0, 3.0])


def _ch1_quiz() -> np.ndarray:
    T_w_1 = se3.make(np.eye(3), [1.0, 0.0, 0.0])
    T_w_2 = se3.make(np.eye(3), [4.0, 3.0, 0.0])
    return (se3.invert(T_w_1) @ T_w_2)[:3, 3]  # t_12 = p2 - p1 (frames share axes)


def _ch1_code() -> np.ndarray:
    p1_w = np.array([1.0, 2.0, 0.5])
    p2_w = np.array([3.0, 2.0, 0.5])
    return np.array([p2_w - p1_w, p1_w - p2_w])  # t12_w, t21_w


def _ch2_properties() -> np.ndarray:
    R = so3.rot_z(np.pi / 2)
    return np.array([float(so3.is_rotation(R)), np.linalg.det(R)])


def _ch3_composition() -> np.ndarray:
    R_w_r = so3.rot_z(np.radians(45))
    R_r_c = so3.rot_x(np.radians(-30))
    return R_w_r @ R_r_c


def _ch4_gimbal_lock() -> float:
    alpha, delta = 0.4, 1.1  # any roll alpha and any delta
    left = so3.from_rpy(alpha + delta, np.pi / 2, delta)  # Rz(d) Ry(pi/2) Rx(a + d)
    right = so3.from_rpy(alpha, np.pi / 2, 0.0)  # Rz(0) Ry(pi/2) Rx(a)
    return float(np.abs(left - right).max())


def _ch5_axis() -> np.ndarray:
    return np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)


def _ch5_angle_deg() -> float:
    R = so3.exp(np.radians(30) * _ch5_axis())
    return float(np.degrees(np.linalg.norm(so3.log(R))))


def _ch6_double_cover() -> float:
    q = quat.from_axis_angle([0.0, 0.0, 1.0], np.pi / 2)
    return float(np.abs(quat.to_matrix(q) - quat.to_matrix(-q)).max())


def _ch8_composer() -> np.ndarray:
    tree = frames.FrameTree()
    tree.add("world", "body", _T_w_r())
    tree.add("body", "camera", _T_r_c())
    return tree.lookup("world", "camera")[:3, 3]


def _ch9_quiz() -> np.ndarray:
    T_w_c = _T_w_r() @ _T_r_c()
    return se3.invert(_T_w_r()) @ T_w_c  # T_r_c = (T_w_r)^-1 T_w_c


_RZ90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])

EXAMPLES: tuple[Example, ...] = (
    Example(
        0,
        "camera sees [0, 0, 3] (optical), drone yawed 90 deg clockwise: landmark from start",
        np.array([0.0, -3.0, 0.0]),
        _ch0_landmark,
        0,
    ),
    Example(
        1, "quiz: t12 for p1 = [1, 0, 0], p2 = [4, 3, 0]", np.array([3.0, 3.0, 0.0]), _ch1_quiz, 0
    ),
    Example(
        1,
        "code: t12_w and t21_w for p1 = [1, 2, 0.5], p2 = [3, 2, 0.5]",
        np.array([[2.0, 0.0, 0.0], [-2.0, 0.0, 0.0]]),
        _ch1_code,
        0,
    ),
    Example(2, "Rz(90 deg)", _RZ90, lambda: so3.rot_z(np.pi / 2), 4),
    Example(
        2,
        "Rz(90 deg)^T Rz(90 deg) = I",
        np.eye(3),
        lambda: so3.rot_z(np.pi / 2).T @ so3.rot_z(np.pi / 2),
        4,
    ),
    Example(2, "Rz(90 deg) in SO(3) (1 = yes), det", np.array([1.0, 1.0]), _ch2_properties, 4),
    Example(
        3,
        "Rz(90 deg) @ p_r, p_r = [1, 0, 0]",
        np.array([0.0, 1.0, 0.0]),
        lambda: so3.rot_z(np.pi / 2) @ [1.0, 0.0, 0.0],
        0,
    ),
    Example(
        3,
        "quiz: Rz(90 deg) @ p_body, p_body = [0, 2, 0]",
        np.array([-2.0, 0.0, 0.0]),
        lambda: so3.rot_z(np.pi / 2) @ [0.0, 2.0, 0.0],
        0,
    ),
    Example(
        3,
        "code: landmark 1 m ahead, body yawed 45 deg",
        np.array([0.707, 0.707, 0.0]),
        lambda: so3.rot_z(np.radians(45)) @ [1.0, 0.0, 0.0],
        3,
    ),
    Example(
        3,
        "code: R_w_c = Rz(45 deg) Rx(-30 deg) (not printed; worked by hand)",
        np.array([[0.707, -0.612, -0.354], [0.707, 0.612, 0.354], [0.0, -0.5, 0.866]]),
        _ch3_composition,
        3,
    ),
    Example(
        3,
        "code: R_w_r @ R_w_r^T = I (45 deg yaw)",
        np.eye(3),
        lambda: so3.rot_z(np.radians(45)) @ so3.rot_z(np.radians(45)).T,
        4,
    ),
    Example(4, "gimbal lock: max |Rz(d) Ry(90) Rx(a+d) - Ry(90) Rx(a)|", 0.0, _ch4_gimbal_lock, 12),
    Example(
        5,
        "Rodrigues: 90 deg about [0, 0, 1]",
        _RZ90,
        lambda: so3.exp(np.pi / 2 * np.array([0.0, 0.0, 1.0])),
        12,
    ),
    Example(
        5,
        "Rodrigues: 30 deg about [1, 1, 0]/sqrt(2)",
        np.array([[0.933, 0.067, 0.354], [0.067, 0.933, -0.354], [-0.354, 0.354, 0.866]]),
        lambda: so3.exp(np.radians(30) * _ch5_axis()),
        3,
    ),
    Example(5, "angle recovered from that matrix (deg)", 30.0, _ch5_angle_deg, 1),
    Example(
        6,
        "q for 90 deg about z, [x, y, z, w]",
        np.array([0.0, 0.0, 0.707, 0.707]),
        lambda: quat.from_axis_angle([0.0, 0.0, 1.0], np.pi / 2),
        3,
    ),
    Example(
        6,
        "R(q) for that q",
        _RZ90,
        lambda: quat.to_matrix(quat.from_axis_angle([0.0, 0.0, 1.0], np.pi / 2)),
        3,
    ),
    Example(6, "double cover: max |R(q) - R(-q)|", 0.0, _ch6_double_cover, 12),
    Example(
        7,
        "camera position in world, t_w_c",
        np.array([5.0, 0.3, 0.2]),
        lambda: (_T_w_r() @ _T_r_c())[:3, 3],
        3,
    ),
    Example(7, "T_w_r @ invert(T_w_r) = I", np.eye(4), lambda: _T_w_r() @ se3.invert(_T_w_r()), 3),
    Example(
        7,
        "code: landmark p_c = [0, 0, 3] in world (not printed; worked by hand)",
        np.array([5.0, 0.3, 3.2]),
        lambda: se3.apply(_T_w_r() @ _T_r_c(), [0.0, 0.0, 3.0]),
        3,
    ),
    Example(
        8,
        "transform composer: FrameTree world -> camera, translation",
        np.array([5.0, 0.3, 0.2]),
        _ch8_composer,
        3,
    ),
    Example(
        9,
        "quiz: T_r_c = invert(T_w_r) @ T_w_c",
        np.array([[1.0, 0, 0, 0.3], [0, 1.0, 0, 0], [0, 0, 1.0, 0.2], [0, 0, 0, 1.0]]),
        _ch9_quiz,
        3,
    ),
)


def evaluate(example: Example) -> Outcome:
    """Compute an example and compare it with the lecture's answer at the printed precision."""
    value = np.asarray(example.compute(), dtype=np.float64)
    expected = np.asarray(example.lecture, dtype=np.float64)
    error = float(np.abs(value - expected).max()) if value.shape == expected.shape else np.inf
    # A value printed with d decimals is the true one rounded: within half a unit of the last
    # digit (plus a little for the lecture's own rounding of intermediate values).
    tolerance = 0.5 * 10.0 ** (-example.decimals) + 1e-12
    return Outcome(example, value, error, bool(error <= tolerance))


def _number(v: float, decimals: int) -> str:
    """``v`` at ``decimals`` decimals (at most 4), trailing zeros dropped: 0.707, -1, 0."""
    text = f"{v:.{min(decimals, 4)}f}"
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def _format(x: np.ndarray, decimals: int) -> list[str]:
    """An array as text lines (one per matrix row), at ``decimals`` decimals."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 0:
        return [_number(float(x), decimals)]
    cells = [[_number(float(v), decimals) for v in row] for row in np.atleast_2d(x)]
    width = max(len(c) for row in cells for c in row)
    return ["[" + " ".join(c.rjust(width) for c in row) + "]" for row in cells]


def table(outcomes: list[Outcome], width: int = 80) -> str:
    """The outcomes as a plain-text table ``width`` columns wide: per example, its chapter and
    description (wrapped), then the lecture's value, vnav's, the largest |error| and whether
    they agree (matrices take one line per row)."""
    head = ("lecture", "vnav", "max |err|", "agree")
    rows = [
        (
            _format(np.asarray(o.example.lecture), o.example.decimals),
            _format(o.value, o.example.decimals),
            [f"{o.error:.1e}"],
            ["yes" if o.agrees else "NO"],
        )
        for o in outcomes
    ]
    widths = [
        max(len(head[i]), *(len(line) for r in rows for line in r[i])) for i in range(len(head))
    ]
    indent = " " * 4
    lines = [
        "ch  example",
        (indent + "  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True))).rstrip(),
        "--  " + "  ".join("-" * w for w in widths),
    ]
    for o, r in zip(outcomes, rows, strict=True):
        lines += textwrap.wrap(
            o.example.what,
            width,
            initial_indent=f"{o.example.chapter:<4}",
            subsequent_indent=indent,
        )
        for k in range(max(len(c) for c in r)):
            parts = [(c[k] if k < len(c) else "").ljust(w) for c, w in zip(r, widths, strict=True)]
            lines.append((indent + "  ".join(parts)).rstrip())
    n_ok = sum(o.agrees for o in outcomes)
    lines.append(f"{n_ok} of {len(outcomes)} worked examples agree with the lecture")
    return "\n".join(lines)


def command(args: argparse.Namespace) -> int:
    """``vnav-demo lecture``: print every example beside vnav's answer; exit status 1 if any
    disagrees."""
    outcomes = [evaluate(e) for e in EXAMPLES]
    say("MIT 16.485 VNAV lecture 1: every worked example and quiz, computed by vnav")
    say(table(outcomes, WIDTH))
    return 0 if all(o.agrees for o in outcomes) else 1
