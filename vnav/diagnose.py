"""The frame-bug doctor: which classic mistake of the frame chain explains a user's estimates.

Given, for N observations, the cone's point in the camera frame ``p_c``, the body pose at the
image's exposure ``T_w_b``, the declared mount ``T_b_c`` and a user's world estimates
``p_w_user``, ``diagnose`` recomputes what each mistake of the lecture's list (MIT 16.485
VNAV, lecture 1) would have produced and names the one that reproduces *every* estimate within
a tolerance while the correct chain ``p_w = T_w_b @ T_b_c @ p_c`` (chapter 7) does not. evo
and Kalibr say how large an error is; this says why.

The hypotheses are data: ``HYPOTHESES``, a tuple of ``Hypothesis`` (a name, the lecture
chapter, what the student did, the fix, and a function of the prepared observations
``Chain`` that returns the (N, 3) points that mistake gives). Adding a mistake is one entry
there, and ``predict`` gives the points of one of them by name (a navigating scenario flies on
a mistake's map with it). The forms are those a student writes:

- the Euler hypotheses rebuild ``R_w_b`` from the pose's roll, pitch, yaw as
  ``vnav.so3.to_rpy`` reads them (the angles a plug-in is handed, in degrees as
  ``rpy_w_b_deg``): ``Rx(roll) Ry(pitch) Rz(yaw)`` (order reversed, SciPy's
  ``from_euler("XYZ", rpy)``); ``Rz(roll) Ry(pitch) Rx(yaw)`` (roll and yaw swapped, an
  ``[r, p, y]`` array given to ``from_euler("ZYX", ...)``); ``so3.from_rpy(*rpy_deg)``
  (degrees taken for radians); ``so3.from_rpy(*np.radians(rpy_rad))`` (radians taken for
  degrees, e.g. ``from_euler(..., degrees=True)`` on radians);
- the quaternion hypotheses permute ``quat_w_b_xyzw`` (vnav's ``quat.from_matrix``; the sign
  of q does not matter): an xyzw array read by a wxyz reader (MuJoCo's, transforms3d's), i.e.
  ``R([y, z, w, x])`` in xyzw, and a wxyz array read by an xyzw reader, ``R([w, x, y, z])``;
- the stale pose uses ``T_w_b_newest``, the newest pose received when the image arrived, and
  is tried only when it is given.

Degenerate geometry. A mistake that changes nothing on the data cannot be seen in it: with an
identity mount rotation "mount rotation dropped" equals the correct chain, on a yaw-only flight
"Euler order reversed" does too, on a level flight heading along the world's x (an identity
body rotation) "body rotation dropped" and "rotation transposed" do, and with a zero mount
translation "mount inverted" equals "mount rotation transposed". The verdict is then:

- ``correct`` when the correct chain explains the estimates, whatever else also does (the
  estimates are right; ``candidates`` lists the mistakes this data could not exclude);
- ``ambiguous`` when two or more mistakes, not the correct chain, explain them: none is named
  (``mistake`` is None), ``candidates`` lists them all;
- ``mistake`` when exactly one does;
- ``unexplained`` when none does, never the nearest one forced on it;
- ``no estimates`` when every row of ``p_w_user`` is NaN.

A yaw-only flight keeps its other mistakes apart: there ``R_w_b.T`` is the pose with the yaw
negated, which is still "rotation transposed" and nothing else on the list.

Conventions: docs/CONVENTIONS.md ("The frame-bug doctor").
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from vnav import _validate as _v
from vnav import quat, se3, so3
from vnav._validate import FloatArray

__all__ = [
    "DEFAULT_TOLERANCE_M",
    "HYPOTHESES",
    "Chain",
    "Diagnosis",
    "Hypothesis",
    "Verdict",
    "diagnose",
    "hypothesis_names",
    "predict",
]

DEFAULT_TOLERANCE_M = 1e-6
"""Largest distance, metres, at which a hypothesis reproduces an estimate of a noise-free run."""

LECTURE = "MIT 16.485 VNAV, lecture 1"
CORRECT = "correct"


class Verdict(enum.StrEnum):
    """What the doctor concluded (a string: ``Verdict.MISTAKE == "mistake"``)."""

    CORRECT = "correct"
    """The correct chain explains every estimate (other hypotheses may too)."""
    MISTAKE = "mistake"
    """Exactly one mistake, and not the correct chain, explains every estimate."""
    AMBIGUOUS = "ambiguous"
    """Several mistakes, not the correct chain, explain every estimate."""
    UNEXPLAINED = "unexplained"
    """No hypothesis explains every estimate."""
    NO_ESTIMATES = "no estimates"
    """Every row of ``p_w_user`` is NaN."""


@dataclass(frozen=True)
class Chain:
    """The observations, validated and split once for every hypothesis.

    Attributes
    ----------
    p_c : ndarray, shape (N, 3)
        The point in the camera (optical) frame, metres.
    R_w_b, t_w_b : ndarray, shapes (N, 3, 3), (N, 3)
        The body pose at the exposure.
    R_b_c, t_b_c : ndarray, shapes (N, 3, 3), (N, 3)
        The declared mount, one per observation.
    rpy_w_b : ndarray, shape (N, 3)
        ``[roll, pitch, yaw]`` of ``R_w_b``, radians (``vnav.so3.to_rpy``, roll = 0 at gimbal
        lock).
    quat_w_b_xyzw : ndarray, shape (N, 4)
        ``R_w_b`` as a unit quaternion, scalar last (``vnav.quat.from_matrix``).
    T_w_b_newest : ndarray, shape (N, 4, 4), or None
        The newest pose received when each image arrived (a row of NaN: none had).
    """

    p_c: FloatArray
    R_w_b: FloatArray
    t_w_b: FloatArray
    R_b_c: FloatArray
    t_b_c: FloatArray
    rpy_w_b: FloatArray
    quat_w_b_xyzw: FloatArray
    T_w_b_newest: FloatArray | None


def _rot(R: FloatArray, p: FloatArray) -> FloatArray:
    """``R @ p`` row by row: (N, 3, 3) and (N, 3) to (N, 3)."""
    return np.einsum("nij,nj->ni", R, p)


def _transposed(R: FloatArray) -> FloatArray:
    return np.swapaxes(R, -1, -2)


def _p_b(c: Chain) -> FloatArray:
    """The point in the body frame, ``T_b_c @ p_c``."""
    return _rot(c.R_b_c, c.p_c) + c.t_b_c


def _with_body_rotation(c: Chain, R_w_b: FloatArray) -> FloatArray:
    """The correct chain with ``R_w_b`` replaced: ``R_w_b' (T_b_c p_c) + t_w_b``."""
    return _rot(R_w_b, _p_b(c)) + c.t_w_b


def _correct(c: Chain) -> FloatArray:
    return _with_body_rotation(c, c.R_w_b)


def _rotation_transposed(c: Chain) -> FloatArray:
    return _with_body_rotation(c, _transposed(c.R_w_b))


def _mount_rotation_transposed(c: Chain) -> FloatArray:
    return _rot(c.R_w_b, _rot(_transposed(c.R_b_c), c.p_c) + c.t_b_c) + c.t_w_b


def _body_pose_inverted(c: Chain) -> FloatArray:
    # T_b_w @ T_b_c @ p_c, T_b_w = [[R^T, -R^T t], [0, 1]].
    return _rot(_transposed(c.R_w_b), _p_b(c) - c.t_w_b)


def _mount_inverted(c: Chain) -> FloatArray:
    # T_w_b @ T_c_b @ p_c, T_c_b = [[R_b_c^T, -R_b_c^T t_b_c], [0, 1]].
    return _rot(c.R_w_b, _rot(_transposed(c.R_b_c), c.p_c - c.t_b_c)) + c.t_w_b


def _order_swapped(c: Chain) -> FloatArray:
    # T_b_c @ T_w_b @ p_c.
    return _rot(c.R_b_c, _rot(c.R_w_b, c.p_c) + c.t_w_b) + c.t_b_c


def _mount_rotation_dropped(c: Chain) -> FloatArray:
    return _rot(c.R_w_b, c.p_c + c.t_b_c) + c.t_w_b


def _body_rotation_dropped(c: Chain) -> FloatArray:
    return c.t_w_b + _p_b(c)


def _body_translation_dropped(c: Chain) -> FloatArray:
    return _rot(c.R_w_b, _p_b(c))


def _mount_translation_dropped(c: Chain) -> FloatArray:
    return _rot(c.R_w_b, _rot(c.R_b_c, c.p_c)) + c.t_w_b


def _translations_dropped(c: Chain) -> FloatArray:
    return _rot(c.R_w_b, _rot(c.R_b_c, c.p_c))


def _naive(c: Chain) -> FloatArray:
    return c.t_w_b + c.p_c


def _euler_reversed(c: Chain) -> FloatArray:
    roll, pitch, yaw = c.rpy_w_b.T
    return _with_body_rotation(c, so3.rot_x(roll) @ so3.rot_y(pitch) @ so3.rot_z(yaw))


def _roll_yaw_swapped(c: Chain) -> FloatArray:
    roll, pitch, yaw = c.rpy_w_b.T
    return _with_body_rotation(c, so3.from_rpy(yaw, pitch, roll))


def _degrees_as_radians(c: Chain) -> FloatArray:
    rpy_deg = np.degrees(c.rpy_w_b)
    return _with_body_rotation(c, so3.from_rpy(*rpy_deg.T))


def _radians_as_degrees(c: Chain) -> FloatArray:
    return _with_body_rotation(c, so3.from_rpy(*np.radians(c.rpy_w_b).T))


def _xyzw_read_as_wxyz(c: Chain) -> FloatArray:
    # A wxyz reader takes q[0] for w: the rotation of [q1, q2, q3, q0] in xyzw.
    return _with_body_rotation(c, quat.to_matrix(np.roll(c.quat_w_b_xyzw, -1, axis=-1)))


def _wxyz_read_as_xyzw(c: Chain) -> FloatArray:
    # q reordered to [w, x, y, z] (for MuJoCo), then given to an xyzw reader.
    return _with_body_rotation(c, quat.to_matrix(np.roll(c.quat_w_b_xyzw, 1, axis=-1)))


def _stale_pose(c: Chain) -> FloatArray | None:
    if c.T_w_b_newest is None:
        return None
    T = c.T_w_b_newest
    return _rot(T[:, :3, :3], _p_b(c)) + T[:, :3, 3]


@dataclass(frozen=True)
class Hypothesis:
    """One way of computing ``p_w``: the correct chain or a classic mistake.

    Attributes
    ----------
    name : str
        Short name, unique in ``HYPOTHESES``.
    chapter : str
        Where the lecture (MIT 16.485 VNAV, lecture 1) covers it, e.g. ``"chapter 7"``.
    what : str
        What the student did, as a formula.
    fix : str
        What to write instead.
    predict : callable
        ``predict(chain) -> ndarray (N, 3)``, the points this computation gives, or None when
        the observations cannot test it (no newest pose for the stale-pose hypothesis).
    """

    name: str
    chapter: str
    what: str
    fix: str
    predict: Callable[[Chain], FloatArray | None]


_FIX_CHAIN = "p_w = T_w_b @ T_b_c @ p_c"

HYPOTHESES: tuple[Hypothesis, ...] = (
    Hypothesis(
        CORRECT,
        "chapter 7",
        "p_w = T_w_b @ T_b_c @ p_c",
        "nothing",
        _correct,
    ),
    Hypothesis(
        "rotation transposed",
        "chapters 2 and 3",
        "R_w_b.T used for R_w_b (R_b_w, the inverse rotation)",
        "p_w = R_w_b @ p_b + t_w_b: R_w_b's columns are the body axes in the world",
        _rotation_transposed,
    ),
    Hypothesis(
        "mount rotation transposed",
        "chapters 2 and 3",
        "R_b_c.T used for R_b_c",
        "p_b = R_b_c @ p_c + t_b_c: R_b_c's columns are the camera axes in the body",
        _mount_rotation_transposed,
    ),
    Hypothesis(
        "body pose inverted",
        "chapter 7",
        "T_b_w = invert(T_w_b) used for T_w_b",
        f"{_FIX_CHAIN}: T_w_b maps body coordinates into the world",
        _body_pose_inverted,
    ),
    Hypothesis(
        "mount inverted",
        "chapter 7",
        "T_c_b = invert(T_b_c) used for T_b_c",
        f"{_FIX_CHAIN}: T_b_c maps camera coordinates into the body",
        _mount_inverted,
    ),
    Hypothesis(
        "composition order swapped",
        "chapter 7",
        "p_w = T_b_c @ T_w_b @ p_c",
        f"{_FIX_CHAIN}: the inner letters cancel",
        _order_swapped,
    ),
    Hypothesis(
        "mount rotation dropped",
        "chapter 0",
        "camera axes taken for body axes: p_b = p_c + t_b_c",
        "p_b = R_b_c @ p_c + t_b_c: the camera's x right, y down, z forward are not the "
        "body's x forward, y left, z up",
        _mount_rotation_dropped,
    ),
    Hypothesis(
        "body rotation dropped",
        "chapter 0",
        "body axes taken for world axes: p_w = t_w_b + T_b_c @ p_c",
        f"{_FIX_CHAIN}: the body's x forward, y left turn with the drone; after a 90 deg yaw "
        "the cone 2 m in front is 2 m along the world's y, not its x",
        _body_rotation_dropped,
    ),
    Hypothesis(
        "body translation dropped",
        "chapter 7",
        "p_w = R_w_b @ (T_b_c @ p_c), without t_w_b",
        f"{_FIX_CHAIN}: a transform is [[R, t], [0, 1]], its translation included",
        _body_translation_dropped,
    ),
    Hypothesis(
        "mount translation dropped",
        "chapter 7",
        "p_b = R_b_c @ p_c, without t_b_c",
        f"{_FIX_CHAIN}: a transform is [[R, t], [0, 1]], its translation included",
        _mount_translation_dropped,
    ),
    Hypothesis(
        "translations dropped",
        "chapter 7",
        "p_w = R_w_b @ R_b_c @ p_c, rotations only",
        f"{_FIX_CHAIN}: a transform is [[R, t], [0, 1]], its translation included",
        _translations_dropped,
    ),
    Hypothesis(
        "naive chain",
        "chapter 0",
        "p_w = t_w_b + p_c: camera coordinates added to the drone's position",
        f"{_FIX_CHAIN}: p_c is in the camera's axes, not the world's",
        _naive,
    ),
    Hypothesis(
        "Euler order reversed",
        "chapter 4",
        "R_w_b = Rx(roll) @ Ry(pitch) @ Rz(yaw)",
        "R_w_b = Rz(yaw) @ Ry(pitch) @ Rx(roll) (so3.from_rpy; SciPy's from_euler('ZYX', "
        "[yaw, pitch, roll]))",
        _euler_reversed,
    ),
    Hypothesis(
        "roll and yaw swapped",
        "chapter 4",
        "R_w_b = Rz(roll) @ Ry(pitch) @ Rx(yaw): [roll, pitch, yaw] given where [yaw, pitch, "
        "roll] was expected",
        "R_w_b = Rz(yaw) @ Ry(pitch) @ Rx(roll): SciPy's from_euler('ZYX', ...) takes yaw first",
        _roll_yaw_swapped,
    ),
    Hypothesis(
        "degrees taken for radians",
        "chapter 4",
        "R_w_b = so3.from_rpy(*rpy_deg): angles in degrees given to a function of radians",
        "so3.from_rpy(*np.radians(rpy_deg))",
        _degrees_as_radians,
    ),
    Hypothesis(
        "radians taken for degrees",
        "chapter 4",
        "R_w_b = so3.from_rpy(*np.radians(rpy_rad)): angles already in radians converted again",
        "so3.from_rpy(*rpy_rad) (or from_euler(..., degrees=True) only on degrees)",
        _radians_as_degrees,
    ),
    Hypothesis(
        "quaternion read as wxyz",
        "chapter 6",
        "an [x, y, z, w] quaternion given to a reader of [w, x, y, z]",
        "vnav.quat.to_matrix(quat_xyzw), or quat.xyzw_to_wxyz before a wxyz reader (MuJoCo)",
        _xyzw_read_as_wxyz,
    ),
    Hypothesis(
        "quaternion wxyz read as xyzw",
        "chapter 6",
        "a quaternion reordered to [w, x, y, z], then given to a reader of [x, y, z, w]",
        "vnav and SciPy read [x, y, z, w]: reorder only for MuJoCo",
        _wxyz_read_as_xyzw,
    ),
    Hypothesis(
        "pose at the wrong time",
        "chapter 7 (its chain composes poses of one instant; stamps are beyond the lecture)",
        "the newest pose received used instead of the pose at the image's exposure",
        "look the pose up at the image's exposure stamp (every transform of a chain at one "
        "instant; docs/CONVENTIONS.md, 'Time and stamps')",
        _stale_pose,
    ),
)
"""Every computation the doctor tries, the correct chain first. Names are unique."""


def hypothesis_names() -> tuple[str, ...]:
    """The names of ``HYPOTHESES``, in order."""
    return tuple(h.name for h in HYPOTHESES)


_BY_NAME = {h.name: h for h in HYPOTHESES}
assert len(_BY_NAME) == len(HYPOTHESES), "hypothesis names must be unique"


@dataclass(frozen=True)
class Diagnosis:
    """What the doctor found.

    Attributes
    ----------
    verdict : Verdict
        ``"correct"``, ``"mistake"``, ``"ambiguous"``, ``"unexplained"`` or
        ``"no estimates"`` (see the module's docstring).
    mistake : str or None
        The named mistake (a name of ``HYPOTHESES``) when the verdict is ``"mistake"``.
    explained : bool
        Whether some hypothesis (the correct chain included) reproduces every estimate.
    residual_m : float or None
        Largest distance, metres, of the named mistake (or, for ``"correct"``, the correct
        chain) from the estimates; None otherwise.
    correct_residual_m : float
        Largest distance of the correct chain from the estimates, metres (NaN without
        estimates).
    candidates : tuple of str
        Every hypothesis within the tolerance, in ``HYPOTHESES`` order.
    residuals_m : tuple of (str, float)
        Each tested hypothesis's largest distance from the estimates, metres, smallest first
        (inf where it gives no point for an estimate).
    tolerance_m : float
    n_estimates : int
        Observations with an estimate (rows of ``p_w_user`` not NaN).
    message : str
        One sentence for a student: what was found, the lecture chapter, the fix.
    """

    verdict: Verdict
    mistake: str | None
    explained: bool
    residual_m: float | None
    correct_residual_m: float
    candidates: tuple[str, ...]
    residuals_m: tuple[tuple[str, float], ...]
    tolerance_m: float
    n_estimates: int
    message: str

    @property
    def chapter(self) -> str | None:
        """The lecture chapter of the named mistake (or of the correct chain), or None."""
        name = self.mistake if self.verdict is Verdict.MISTAKE else None
        name = CORRECT if self.verdict is Verdict.CORRECT else name
        return None if name is None else _BY_NAME[name].chapter

    def explain(self) -> str:
        """The message, then each hypothesis's residual (smallest first), one per line."""
        lines = [self.message, f"residuals (tolerance {self.tolerance_m:.3g} m):"]
        width = max((len(n) for n, _ in self.residuals_m), default=0)
        for name, r in self.residuals_m:
            mark = " <" if name in self.candidates else ""
            lines.append(f"  {name.ljust(width)}  {r:.3g} m{mark}")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.explain()

    def to_dict(self) -> dict:
        """The diagnosis as plain JSON values (strict JSON: inf and NaN become None), with the
        chapter; ``residuals_m`` as a mapping in the same order, smallest first."""

        def number(x: float | None) -> float | None:
            return x if x is not None and np.isfinite(x) else None

        return {
            "verdict": str(self.verdict),
            "mistake": self.mistake,
            "chapter": self.chapter,
            "explained": self.explained,
            "residual_m": number(self.residual_m),
            "correct_residual_m": number(self.correct_residual_m),
            "candidates": list(self.candidates),
            "residuals_m": {name: number(r) for name, r in self.residuals_m},
            "tolerance_m": self.tolerance_m,
            "n_estimates": self.n_estimates,
            "message": self.message,
        }


# ------------------------------------------------------------------ validation


def _points(x: ArrayLike, name: str, n: int | None, *, nan_rows: bool) -> FloatArray:
    a = _v.check_shape(_v.as_float(x, name), name, (3,), batched=True)
    if a.ndim != 2:
        raise ValueError(f"{name} must have shape (N, 3); got shape {a.shape}")
    if n is not None and a.shape[0] != n:
        raise ValueError(f"{name} must have shape ({n}, 3), one row per p_c; got shape {a.shape}")
    if not nan_rows:
        return _v.check_finite(a, name)
    nan = np.isnan(a)
    partial = nan.any(axis=1) & ~nan.all(axis=1)
    if partial.any():
        raise ValueError(
            f"{name} row {int(np.argmax(partial))} is partly NaN; a row is an estimate (finite) "
            "or none (all NaN)"
        )
    if np.isinf(a).any():
        raise ValueError(f"{name} must hold no inf; got {int(np.isinf(a).sum())} inf entries")
    return a


def _poses(T: ArrayLike, name: str, n: int, *, single: bool, nan_rows: bool = False) -> FloatArray:
    a = _v.as_float(T, name)
    if single and a.shape == (4, 4):
        a = np.broadcast_to(se3.check_pose(a, name), (n, 4, 4))
        return a
    if a.shape != (n, 4, 4):
        expected = f"(4, 4) or ({n}, 4, 4)" if single else f"({n}, 4, 4)"
        raise ValueError(f"{name} must have shape {expected}, one per p_c; got shape {a.shape}")
    if nan_rows:
        missing = np.isnan(a).all(axis=(1, 2))
        if missing.any():
            out = np.full_like(a, np.nan)
            if (~missing).any():
                out[~missing] = se3.check_transform(a[~missing], name)
            return out
    return se3.check_transform(a, name)


def _tolerance(tolerance_m: object) -> float:
    tol = _v.tolerance(tolerance_m, "tolerance_m")
    if tol == 0.0:
        raise ValueError("tolerance_m must be > 0 (rounding alone differs from 0); got 0.0")
    return tol


def _chain(
    p_c: FloatArray, T_w_b: FloatArray, T_b_c: FloatArray, newest: FloatArray | None
) -> Chain:
    """The validated observations split for the hypotheses (every row used)."""
    R_w_b = T_w_b[:, :3, :3]
    return Chain(
        p_c=p_c,
        R_w_b=R_w_b,
        t_w_b=T_w_b[:, :3, 3],
        R_b_c=T_b_c[:, :3, :3],
        t_b_c=T_b_c[:, :3, 3],
        rpy_w_b=so3.to_rpy(R_w_b, warn=False),
        quat_w_b_xyzw=quat.from_matrix(R_w_b, assume_valid=True),
        T_w_b_newest=newest,
    )


def predict(
    name: str,
    p_c: ArrayLike,
    T_w_b: ArrayLike,
    T_b_c: ArrayLike,
    T_w_b_newest: ArrayLike | None = None,
) -> FloatArray:
    """The world points hypothesis ``name`` computes from the observations: what a student
    who makes that mistake gets (``"correct"``: the lecture's chain).

    Parameters
    ----------
    name : str
        A name of ``HYPOTHESES`` (``hypothesis_names()``), e.g. ``"body rotation dropped"``.
    p_c : array_like, shape (N, 3)
        The point in the camera (optical) frame, metres.
    T_w_b : array_like, shape (N, 4, 4)
        The body pose at each image's exposure.
    T_b_c : array_like, shape (4, 4) or (N, 4, 4)
        The declared camera mount.
    T_w_b_newest : array_like, shape (N, 4, 4), optional
        The newest pose received when each image arrived; needed by "pose at the wrong time"
        only (a row of NaN gives a row of NaN there).

    Returns
    -------
    ndarray, shape (N, 3)
        The world points, metres.

    Raises
    ------
    ValueError
        ``name`` not a hypothesis (the message lists them), "pose at the wrong time" without
        ``T_w_b_newest``, or an argument of the wrong shape, not finite or not rigid (as for
        ``diagnose``).
    """
    if not isinstance(name, str) or name not in _BY_NAME:
        raise ValueError(f"name must be one of {list(_BY_NAME)}; got {name!r}")
    p_c = _points(p_c, "p_c", None, nan_rows=False)
    n = p_c.shape[0]
    T_w_b = _poses(T_w_b, "T_w_b", n, single=False)
    T_b_c = _poses(T_b_c, "T_b_c", n, single=True)
    newest = None
    if T_w_b_newest is not None:
        newest = _poses(T_w_b_newest, "T_w_b_newest", n, single=False, nan_rows=True)
    if n == 0:
        return np.zeros((0, 3))
    predicted = _BY_NAME[name].predict(_chain(p_c, T_w_b, T_b_c, newest))
    if predicted is None:
        raise ValueError(f"{name!r} needs T_w_b_newest, the newest pose at each image's arrival")
    return predicted


# ------------------------------------------------------------------ the doctor


def diagnose(
    p_c: ArrayLike,
    T_w_b: ArrayLike,
    T_b_c: ArrayLike,
    p_w_user: ArrayLike,
    *,
    T_w_b_newest: ArrayLike | None = None,
    tolerance_m: float = DEFAULT_TOLERANCE_M,
) -> Diagnosis:
    """Name the classic frame mistake that explains a user's estimates, if one does.

    Each hypothesis of ``HYPOTHESES`` is recomputed from the observations; its residual is the
    largest distance from the user's estimates. A hypothesis explains them when its residual
    is at most ``tolerance_m``. The verdicts (correct, mistake, ambiguous, unexplained, no
    estimates) and the degenerate cases are described in the module's docstring.

    Parameters
    ----------
    p_c : array_like, shape (N, 3)
        The point in the camera (optical) frame, metres, per observation.
    T_w_b : array_like, shape (N, 4, 4)
        The body pose at each image's exposure.
    T_b_c : array_like, shape (4, 4) or (N, 4, 4)
        The declared camera mount (one, or one per observation).
    p_w_user : array_like, shape (N, 3)
        The user's world estimates, metres; a row of NaN is no estimate and is skipped.
    T_w_b_newest : array_like, shape (N, 4, 4), optional
        The newest pose received when each image arrived (runs with latency); a row of NaN
        where none had. Without it the stale-pose hypothesis is not tried.
    tolerance_m : float
        Largest distance at which a hypothesis reproduces an estimate, metres (> 0). The
        default suits exact data; with noise, pass a bound on its effect.

    Returns
    -------
    Diagnosis

    Raises
    ------
    ValueError
        Naming the argument: a wrong shape, NaN or inf (other than whole NaN rows in
        ``p_w_user`` and ``T_w_b_newest``), a pose that is not rigid, a tolerance that is not
        a finite number > 0.
    """
    tol = _tolerance(tolerance_m)
    p_c, T_w_b, T_b_c, p_w_user, newest = _diagnose_inputs(
        p_c, T_w_b, T_b_c, p_w_user, T_w_b_newest
    )
    has = ~np.isnan(p_w_user[:, 0])
    n_est = int(has.sum())
    if n_est == 0:
        return _no_estimates(tol)
    # Only the observations with an estimate are tested (and paid for).
    chain = _chain(p_c[has], T_w_b[has], T_b_c[has], None if newest is None else newest[has])
    return _verdict(_residuals(chain, p_w_user[has]), tol, n_est)


def _diagnose_inputs(
    p_c: ArrayLike,
    T_w_b: ArrayLike,
    T_b_c: ArrayLike,
    p_w_user: ArrayLike,
    T_w_b_newest: ArrayLike | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """``diagnose``'s observations, checked and shaped: one row (or pose) per observation.

    Parameters
    ----------
    p_c, T_w_b, T_b_c, p_w_user, T_w_b_newest
        As ``diagnose`` takes them.

    Returns
    -------
    p_c : np.ndarray, shape (N, 3)
    T_w_b : np.ndarray, shape (N, 4, 4)
    T_b_c : np.ndarray, shape (N, 4, 4)
    p_w_user : np.ndarray, shape (N, 3)
        Rows of NaN where the user gave no estimate.
    newest : np.ndarray, shape (N, 4, 4), or None
        Without ``T_w_b_newest``, None.

    Raises
    ------
    ValueError
        As ``diagnose`` says, and if ``p_c`` holds no observation.
    """
    p_c = _points(p_c, "p_c", None, nan_rows=False)
    n = p_c.shape[0]
    if n == 0:
        raise ValueError("p_c must hold at least one observation; got shape (0, 3)")
    T_w_b = _poses(T_w_b, "T_w_b", n, single=False)
    T_b_c = _poses(T_b_c, "T_b_c", n, single=True)
    p_w_user = _points(p_w_user, "p_w_user", n, nan_rows=True)
    newest = None
    if T_w_b_newest is not None:
        newest = _poses(T_w_b_newest, "T_w_b_newest", n, single=False, nan_rows=True)
    return p_c, T_w_b, T_b_c, p_w_user, newest


def _residuals(chain: Chain, user: np.ndarray) -> dict[str, float]:
    """Each hypothesis's residual: its largest distance from the user's estimates.

    Parameters
    ----------
    chain : Chain
        The observations with an estimate.
    user : np.ndarray, shape (M, 3)
        The user's estimates of those, metres.

    Returns
    -------
    dict of str to float
        Metres, by hypothesis name (``inf`` where a prediction is NaN); a hypothesis that
        cannot be tried (no newest pose) is left out.
    """
    residuals: dict[str, float] = {}
    for h in HYPOTHESES:
        predicted = h.predict(chain)
        if predicted is None:
            continue
        d = np.linalg.norm(predicted - user, axis=1)
        residuals[h.name] = float(np.max(np.where(np.isnan(d), np.inf, d)))
    return residuals


def _no_estimates(tol: float) -> Diagnosis:
    return Diagnosis(
        verdict=Verdict.NO_ESTIMATES,
        mistake=None,
        explained=False,
        residual_m=None,
        correct_residual_m=float("nan"),
        candidates=(),
        residuals_m=(),
        tolerance_m=tol,
        n_estimates=0,
        message="No estimates to diagnose: every row of p_w_user is NaN.",
    )


def _verdict(residuals: dict[str, float], tol: float, n_est: int) -> Diagnosis:
    candidates = tuple(name for name, r in residuals.items() if r <= tol)
    ranked = tuple(sorted(residuals.items(), key=lambda item: item[1]))
    r_correct = residuals[CORRECT]
    others = [c for c in candidates if c != CORRECT]
    mistake = None
    residual: float | None = None
    if CORRECT in candidates:
        verdict, residual = Verdict.CORRECT, r_correct
        message = (
            f"Correct: the lecture's chain {_FIX_CHAIN} ({LECTURE}, chapter 7) reproduces all "
            f"{n_est} estimates within {r_correct:.3g} m."
        )
        if others:
            message += (
                f" This data cannot rule out {_join(others)}, which give the same points here "
                "(e.g. an identity mount rotation or a yaw-only flight); a more general pose "
                "or mount would tell."
            )
    elif len(others) == 1:
        mistake = others[0]
        verdict, residual = Verdict.MISTAKE, residuals[mistake]
        h = _BY_NAME[mistake]
        message = (
            f"Mistake: {mistake} ({LECTURE}, {h.chapter}): {h.what}. It reproduces all "
            f"{n_est} estimates within {residual:.3g} m, while the correct chain misses by up "
            f"to {r_correct:.3g} m. Fix: {h.fix}."
        )
    elif others:
        verdict = Verdict.AMBIGUOUS
        parts = "; ".join(f"{c} ({LECTURE}, {_BY_NAME[c].chapter})" for c in others)
        message = (
            f"Ambiguous: {len(others)} mistakes reproduce all {n_est} estimates within "
            f"{tol:.3g} m and this data cannot tell them apart: {parts}. The correct chain "
            f"misses by up to {r_correct:.3g} m."
        )
    else:
        verdict = Verdict.UNEXPLAINED
        nearest = next(name for name, _ in ranked if name != CORRECT)
        message = (
            f"Unexplained: no mistake of the lecture's list ({LECTURE}) reproduces the "
            f"estimates within {tol:.3g} m. The correct chain misses by up to {r_correct:.3g} m, "
            f"the nearest mistake ({nearest}) by {residuals[nearest]:.3g} m; look for another "
            "error (an offset, a wrong point, noise above the tolerance)."
        )
    return Diagnosis(
        verdict=verdict,
        mistake=mistake,
        explained=bool(candidates),
        residual_m=residual,
        correct_residual_m=r_correct,
        candidates=candidates,
        residuals_m=ranked,
        tolerance_m=tol,
        n_estimates=n_est,
        message=message,
    )


def _join(names: list[str]) -> str:
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]
