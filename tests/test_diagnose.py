"""The frame-bug doctor (``vnav.diagnose``) against mistakes written as a student writes them.

Each classic mistake is a user function of one observation, written independently of the
doctor: 4x4 products and ``np.linalg.inv``, and SciPy's ``Rotation`` for the Euler angles and
quaternions (the angles and quaternion it is handed come from SciPy too, as a plug-in's
``rpy_w_b_deg`` and ``quat_w_b_xyzw`` would). Its estimates over random, non-degenerate poses
and mounts must make the doctor name exactly that mistake. The degenerate cases follow the
module's docstring; the last tests use the simulator's own runs.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vnav import se3
from vnav.diagnose import (
    DEFAULT_TOLERANCE_M,
    HYPOTHESES,
    Diagnosis,
    Verdict,
    diagnose,
    hypothesis_names,
    predict,
)


@dataclass(frozen=True)
class Obs:
    """What a user function is given for one detection (a plug-in's observation)."""

    p_c: np.ndarray
    T_w_b: np.ndarray
    T_b_c: np.ndarray
    quat_w_b_xyzw: np.ndarray
    rpy_w_b_deg: np.ndarray
    T_w_b_newest: np.ndarray | None


def _h(p: np.ndarray) -> np.ndarray:
    return np.append(p, 1.0)


def _with_R(o: Obs, R_w_b: np.ndarray) -> np.ndarray:
    """The correct chain with the user's own ``R_w_b``."""
    return R_w_b @ (o.T_b_c @ _h(o.p_c))[:3] + o.T_w_b[:3, 3]


def _euler(seq: str, angles, degrees: bool) -> np.ndarray:
    return Rotation.from_euler(seq, angles, degrees=degrees).as_matrix()


def _rpy_rad(o: Obs) -> np.ndarray:
    return np.radians(o.rpy_w_b_deg)


def _quat(q_xyzw) -> np.ndarray:
    return Rotation.from_quat(q_xyzw).as_matrix()


USER: dict[str, Callable[[Obs], np.ndarray]] = {
    "correct": lambda o: (o.T_w_b @ o.T_b_c @ _h(o.p_c))[:3],
    "rotation transposed": lambda o: _with_R(o, o.T_w_b[:3, :3].T),
    "mount rotation transposed": lambda o: (
        o.T_w_b @ _h(o.T_b_c[:3, :3].T @ o.p_c + o.T_b_c[:3, 3])
    )[:3],
    "body pose inverted": lambda o: (np.linalg.inv(o.T_w_b) @ o.T_b_c @ _h(o.p_c))[:3],
    "mount inverted": lambda o: (o.T_w_b @ np.linalg.inv(o.T_b_c) @ _h(o.p_c))[:3],
    "composition order swapped": lambda o: (o.T_b_c @ o.T_w_b @ _h(o.p_c))[:3],
    "mount rotation dropped": lambda o: (o.T_w_b @ _h(o.p_c + o.T_b_c[:3, 3]))[:3],
    # Body axes taken for world axes: the body-frame point added to the drone's position.
    "body rotation dropped": lambda o: o.T_w_b[:3, 3] + (o.T_b_c @ _h(o.p_c))[:3],
    "body translation dropped": lambda o: o.T_w_b[:3, :3] @ (o.T_b_c @ _h(o.p_c))[:3],
    "mount translation dropped": lambda o: (o.T_w_b @ _h(o.T_b_c[:3, :3] @ o.p_c))[:3],
    "translations dropped": lambda o: o.T_w_b[:3, :3] @ o.T_b_c[:3, :3] @ o.p_c,
    "naive chain": lambda o: o.T_w_b[:3, 3] + o.p_c,
    # Intrinsic X-Y'-Z'': Rx(roll) Ry(pitch) Rz(yaw).
    "Euler order reversed": lambda o: _with_R(o, _euler("XYZ", o.rpy_w_b_deg, True)),
    # [roll, pitch, yaw] given where from_euler("ZYX") wants [yaw, pitch, roll].
    "roll and yaw swapped": lambda o: _with_R(o, _euler("ZYX", o.rpy_w_b_deg, True)),
    "degrees taken for radians": lambda o: _with_R(o, _euler("ZYX", o.rpy_w_b_deg[::-1], False)),
    "radians taken for degrees": lambda o: _with_R(o, _euler("ZYX", _rpy_rad(o)[::-1], True)),
    # `w, x, y, z = q` on an [x, y, z, w] array, then back to SciPy's [x, y, z, w].
    "quaternion read as wxyz": lambda o: _with_R(o, _quat(np.roll(o.quat_w_b_xyzw, -1))),
    # MuJoCo's [w, x, y, z] given to SciPy.
    "quaternion wxyz read as xyzw": lambda o: _with_R(o, _quat(np.roll(o.quat_w_b_xyzw, 1))),
    "pose at the wrong time": lambda o: (o.T_w_b_newest @ o.T_b_c @ _h(o.p_c))[:3],
}
"""One user function per hypothesis of the doctor (checked below: a new hypothesis needs one)."""

MISTAKES = [name for name in USER if name != "correct"]


def _random_pose(rng: np.random.Generator, *, t_scale_m: float = 5.0) -> np.ndarray:
    R = Rotation.random(random_state=rng).as_matrix()
    return se3.make(R, rng.normal(scale=t_scale_m, size=3))


def _scene(
    rng: np.random.Generator,
    n: int = 40,
    *,
    R_b_c: np.ndarray | None = None,
    t_b_c: np.ndarray | None = None,
    yaw_only: bool = False,
    per_row_mount: bool = False,
) -> dict:
    """Random observations: poses, a mount (or one per row), points 2-10 m ahead, newest poses."""
    if yaw_only:
        yaws = rng.uniform(-np.pi, np.pi, n)
        T_w_b = np.stack(
            [se3.make(Rotation.from_euler("z", y).as_matrix(), rng.normal(size=3)) for y in yaws]
        )
    else:
        T_w_b = np.stack([_random_pose(rng) for _ in range(n)])
    mounts = []
    for _ in range(n if per_row_mount else 1):
        R = Rotation.random(random_state=rng).as_matrix() if R_b_c is None else R_b_c
        t = rng.uniform(-0.3, 0.3, 3) if t_b_c is None else t_b_c
        mounts.append(se3.make(R, t))
    T_b_c = np.stack(mounts) if per_row_mount else mounts[0]
    p_c = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-2, 2, n), rng.uniform(2, 10, n)])
    T_w_b_newest = np.stack([_random_pose(rng) for _ in range(n)])
    return {"p_c": p_c, "T_w_b": T_w_b, "T_b_c": T_b_c, "T_w_b_newest": T_w_b_newest}


def _estimates(name: str, scene: dict) -> np.ndarray:
    """``USER[name]`` over the scene's observations, each handed SciPy's rpy and quaternion."""
    n = len(scene["p_c"])
    T_b_c = np.broadcast_to(scene["T_b_c"], (n, 4, 4))
    out = np.empty((n, 3))
    for i in range(n):
        rotation = Rotation.from_matrix(scene["T_w_b"][i, :3, :3])
        o = Obs(
            p_c=scene["p_c"][i],
            T_w_b=scene["T_w_b"][i],
            T_b_c=T_b_c[i],
            quat_w_b_xyzw=rotation.as_quat(),
            rpy_w_b_deg=rotation.as_euler("ZYX", degrees=True)[::-1],
            T_w_b_newest=scene["T_w_b_newest"][i],
        )
        out[i] = USER[name](o)
    return out


def _diagnose(scene: dict, p_w_user: np.ndarray, **kwargs) -> Diagnosis:
    return diagnose(scene["p_c"], scene["T_w_b"], scene["T_b_c"], p_w_user, **kwargs)


def test_every_hypothesis_has_a_user_function():
    assert set(USER) == set(hypothesis_names())
    assert len(hypothesis_names()) == len(HYPOTHESES)
    assert all(h.chapter.startswith("chapter") for h in HYPOTHESES)


def test_the_correct_chain_is_named_correct(rng):
    scene = _scene(rng)
    d = _diagnose(scene, _estimates("correct", scene), T_w_b_newest=scene["T_w_b_newest"])
    assert d.verdict is Verdict.CORRECT and d.explained and d.mistake is None
    assert d.candidates == ("correct",)
    assert d.residual_m == d.correct_residual_m < 1e-9
    assert d.chapter == "chapter 7"


@pytest.mark.parametrize("name", MISTAKES)
def test_each_mistake_is_named(rng, name):
    scene = _scene(rng)
    d = _diagnose(scene, _estimates(name, scene), T_w_b_newest=scene["T_w_b_newest"])
    assert d.verdict == "mistake", d.explain()
    assert d.mistake == name and d.candidates == (name,)
    assert d.residual_m < 1e-9
    assert d.correct_residual_m > 1e-2
    assert d.residuals_m[0] == (name, d.residual_m)
    text = d.explain()
    assert name in text and "MIT 16.485 VNAV, lecture 1" in text and d.chapter in text
    assert str(d) == text


@pytest.mark.parametrize(
    "name", ["mount inverted", "composition order swapped", "Euler order reversed"]
)
def test_a_mount_per_observation(rng, name):
    scene = _scene(rng, per_row_mount=True)
    d = _diagnose(scene, _estimates(name, scene))
    assert (d.verdict, d.mistake) == ("mistake", name) and d.residual_m < 1e-9


def test_observations_without_an_estimate_are_skipped(rng):
    scene = _scene(rng)
    p_w = _estimates("mount inverted", scene)
    p_w[::3] = np.nan
    p_w[1] += 100.0  # then made NaN: a skipped row is not read
    p_w[1] = np.nan
    d = _diagnose(scene, p_w)
    assert d.mistake == "mount inverted" and d.n_estimates == len(p_w) - len(p_w[::3]) - 1


def test_no_estimates_at_all(rng):
    scene = _scene(rng, n=5)
    d = _diagnose(scene, np.full((5, 3), np.nan))
    assert d.verdict == "no estimates" and not d.explained and d.mistake is None
    assert d.n_estimates == 0 and d.residuals_m == ()


@pytest.mark.parametrize("offset", ["random", "constant"])
def test_an_offset_is_unexplained_not_forced_on_the_nearest(rng, offset):
    scene = _scene(rng)
    p_w = _estimates("correct", scene)
    if offset == "random":
        p_w += rng.normal(scale=0.3, size=p_w.shape)
    else:
        p_w += [0.05, -0.02, 0.01]
    d = _diagnose(scene, p_w)
    assert d.verdict == "unexplained" and not d.explained
    assert d.mistake is None and d.residual_m is None and d.candidates == ()
    assert "Unexplained" in d.explain()


@pytest.mark.parametrize("name", ["rotation transposed", "naive chain", "quaternion read as wxyz"])
def test_noise_with_a_matching_tolerance_still_names_the_mistake(rng, name):
    scene = _scene(rng)
    noise_std_m = 1e-3
    p_w = _estimates(name, scene) + rng.normal(scale=noise_std_m, size=(len(scene["p_c"]), 3))
    # The largest of 40 noise vectors' norms (chi with 3 dof) stays well under 6 sigma.
    d = _diagnose(scene, p_w, tolerance_m=6 * noise_std_m)
    assert (d.verdict, d.mistake) == ("mistake", name), d.explain()
    assert 0 < d.residual_m <= 6 * noise_std_m
    # The same estimates against the exact default: the noise is above it, nothing is named.
    assert _diagnose(scene, p_w).verdict == "unexplained"


def test_noisy_correct_estimates_are_correct_within_their_tolerance(rng):
    scene = _scene(rng)
    p_w = _estimates("correct", scene) + rng.normal(scale=1e-3, size=(len(scene["p_c"]), 3))
    assert _diagnose(scene, p_w, tolerance_m=6e-3).verdict == "correct"


# ------------------------------------------------------------------ degenerate geometry


def test_identity_mount_rotation_cannot_show_a_dropped_mount_rotation(rng):
    scene = _scene(rng, R_b_c=np.eye(3))
    d = _diagnose(scene, _estimates("mount rotation dropped", scene))
    # The estimates are right: the correct chain is preferred, the mistake listed as possible.
    assert d.verdict == "correct" and d.mistake is None
    assert "mount rotation dropped" in d.candidates
    assert "cannot rule out" in d.message and "mount rotation dropped" in d.message


def test_zero_mount_translation_makes_inversion_and_transposition_ambiguous(rng):
    scene = _scene(rng, t_b_c=np.zeros(3))
    d = _diagnose(scene, _estimates("mount inverted", scene))
    assert d.verdict == "ambiguous" and d.explained and d.mistake is None
    assert set(d.candidates) == {"mount inverted", "mount rotation transposed"}
    assert d.residual_m is None and d.correct_residual_m > 1e-2
    assert "mount inverted" in d.message and "mount rotation transposed" in d.message


def test_yaw_only_flight(rng):
    scene = _scene(rng, yaw_only=True)
    # R_w_b.T is the yaw negated: still "rotation transposed", and nothing else.
    d = _diagnose(scene, _estimates("rotation transposed", scene))
    assert (d.verdict, d.mistake) == ("mistake", "rotation transposed")
    assert d.candidates == ("rotation transposed",)
    # One elementary rotation: the Euler order does not matter, the estimates are right.
    d = _diagnose(scene, _estimates("Euler order reversed", scene))
    assert d.verdict == "correct" and "Euler order reversed" in d.candidates


def test_level_unyawed_flight_cannot_show_a_dropped_body_rotation(rng):
    """An identity body rotation: "body rotation dropped" (and "rotation transposed") give the
    right points; yawed 90 deg, the lecture's case, the mistake is named."""
    scene = _scene(rng)
    scene["T_w_b"][:, :3, :3] = np.eye(3)
    d = _diagnose(scene, _estimates("body rotation dropped", scene))
    assert d.verdict == "correct" and "body rotation dropped" in d.candidates
    scene["T_w_b"][:, :3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    d = _diagnose(scene, _estimates("body rotation dropped", scene))
    assert (d.verdict, d.mistake) == ("mistake", "body rotation dropped"), d.explain()
    assert d.chapter == "chapter 0"


def test_the_lectures_cone_after_a_90_deg_yaw_lands_off_to_the_side():
    """MIT 16.485 VNAV, lecture 1: a cone 2 m in front and 1 m to the left of the drone; the
    drone yawed 90 deg (facing world +y). The body numbers taken as world numbers put it 2 m
    along world x, i.e. 2 m to the drone's right and 1 m behind it in the body frame."""
    T_w_b = se3.make(Rotation.from_euler("z", 90, degrees=True).as_matrix(), [5.0, 3.0, 1.0])
    T_b_c = np.eye(4)  # camera axes = body axes, so p_c is the body-frame point
    p_b = np.array([2.0, 1.0, 0.0])
    truth = predict("correct", [p_b], [T_w_b], T_b_c)[0]
    wrong = predict("body rotation dropped", [p_b], [T_w_b], T_b_c)[0]
    assert np.allclose(truth, [5.0 - 1.0, 3.0 + 2.0, 1.0])  # left of a +y heading is -x
    assert np.allclose(wrong, [5.0 + 2.0, 3.0 + 1.0, 1.0])
    assert np.allclose(se3.apply(se3.invert(T_w_b), wrong), [1.0, -2.0, 0.0])


def test_predict_gives_each_users_points(rng):
    scene = _scene(rng, n=12)
    for name in hypothesis_names():
        got = predict(name, scene["p_c"], scene["T_w_b"], scene["T_b_c"], scene["T_w_b_newest"])
        assert got.shape == (12, 3)
        assert np.allclose(got, _estimates(name, scene), atol=1e-9), name


def test_predict_refuses_what_it_cannot_compute(rng):
    scene = _scene(rng, n=3)
    args = (scene["p_c"], scene["T_w_b"], scene["T_b_c"])
    with pytest.raises(ValueError, match=r"name must be one of .*body rotation dropped"):
        predict("body-rotation-dropped", *args)
    with pytest.raises(ValueError, match="T_w_b_newest"):
        predict("pose at the wrong time", *args)
    with pytest.raises(ValueError, match="T_w_b"):
        predict("correct", scene["p_c"], scene["T_w_b"][:2], scene["T_b_c"])
    assert predict("correct", np.zeros((0, 3)), np.zeros((0, 4, 4)), np.eye(4)).shape == (0, 3)


@pytest.mark.filterwarnings("ignore:Gimbal lock detected")
@pytest.mark.parametrize("name", ["Euler order reversed", "roll and yaw swapped"])
def test_gimbal_lock_uses_the_angles_with_roll_zero(rng, name):
    """At pitch = 90 deg only yaw - roll is defined: SciPy, like vnav.so3.to_rpy, hands out
    roll = 0, and the doctor rebuilds the Euler mistakes from those angles."""
    scene = _scene(rng)
    for i in range(len(scene["p_c"])):
        R = Rotation.from_euler("ZYX", [rng.uniform(-3, 3), np.pi / 2, rng.uniform(-3, 3)])
        scene["T_w_b"][i, :3, :3] = R.as_matrix()
    d = _diagnose(scene, _estimates(name, scene))
    assert (d.verdict, d.mistake) == ("mistake", name), d.explain()
    assert d.residual_m < 1e-9


def test_the_stale_pose_is_tried_only_with_newest_poses(rng):
    scene = _scene(rng)
    p_w = _estimates("pose at the wrong time", scene)
    d = _diagnose(scene, p_w)
    assert d.verdict == "unexplained"
    assert "pose at the wrong time" not in dict(d.residuals_m)
    # A row where no pose had arrived (NaN) while the user gave an estimate: not explained.
    newest = scene["T_w_b_newest"].copy()
    newest[0] = np.nan
    d = _diagnose(scene, p_w, T_w_b_newest=newest)
    assert d.verdict == "unexplained"
    assert dict(d.residuals_m)["pose at the wrong time"] == np.inf
    p_w[0] = np.nan  # ... unless it gave none there either
    d = _diagnose(scene, p_w, T_w_b_newest=newest)
    assert d.mistake == "pose at the wrong time"


def test_the_diagnosis_as_strict_json(rng):
    scene = _scene(rng)
    newest = scene["T_w_b_newest"].copy()
    newest[0] = np.nan  # an infinite residual
    d = _diagnose(scene, _estimates("naive chain", scene), T_w_b_newest=newest)
    loaded = json.loads(json.dumps(d.to_dict(), allow_nan=False))
    assert loaded["verdict"] == "mistake" and loaded["mistake"] == "naive chain"
    assert loaded["chapter"] == "chapter 0" and loaded["message"] == d.message
    assert list(loaded["residuals_m"]) == [name for name, _ in d.residuals_m]
    assert loaded["residuals_m"]["pose at the wrong time"] is None
    assert loaded["residual_m"] == d.residual_m


# ------------------------------------------------------------------ bad input


def _bad(scene: dict, **change) -> dict:
    args = {
        "p_c": scene["p_c"],
        "T_w_b": scene["T_w_b"],
        "T_b_c": scene["T_b_c"],
        "p_w_user": scene["p_c"],
    }
    args.update(change)
    return args


@pytest.mark.parametrize(
    ("argument", "value"),
    [
        ("p_c", lambda s: s["p_c"][:, :2]),
        ("p_c", lambda s: np.where(np.arange(4)[:, None] == 1, np.nan, s["p_c"])),
        ("p_c", lambda s: np.zeros((0, 3))),
        ("p_c", lambda s: "not numbers"),
        ("T_w_b", lambda s: s["T_w_b"][:3]),
        ("T_w_b", lambda s: s["T_w_b"] * 2.0),
        ("T_b_c", lambda s: np.eye(3)),
        ("T_b_c", lambda s: np.diag([1.0, 1.0, -1.0, 1.0])),
        ("p_w_user", lambda s: s["p_c"][:3]),
        ("p_w_user", lambda s: np.where(np.arange(3) == 0, np.nan, s["p_c"])),
        ("p_w_user", lambda s: np.full((4, 3), np.inf)),
        ("T_w_b_newest", lambda s: s["T_w_b"][:, :3, :3]),
        ("T_w_b_newest", lambda s: s["T_w_b"] * 2.0),
        ("tolerance_m", lambda s: -1.0),
        ("tolerance_m", lambda s: 0.0),
        ("tolerance_m", lambda s: float("nan")),
        ("tolerance_m", lambda s: True),
    ],
)
def test_bad_input_raises_naming_the_argument(rng, argument, value):
    scene = _scene(rng, n=4)
    args = _bad(scene, **{argument: value(scene)})
    with pytest.raises(ValueError, match=argument):
        diagnose(
            args["p_c"],
            args["T_w_b"],
            args["T_b_c"],
            args["p_w_user"],
            T_w_b_newest=args.get("T_w_b_newest"),
            tolerance_m=args.get("tolerance_m", DEFAULT_TOLERANCE_M),
        )


# ------------------------------------------------------------------ speed


def test_a_30_s_flight_takes_well_under_a_second(rng):
    """About 900 observations (30 s at 30 Hz), every hypothesis tried."""
    scene = _scene(rng, n=900)
    p_w = _estimates("composition order swapped", scene)
    diagnose(scene["p_c"][:5], scene["T_w_b"][:5], scene["T_b_c"], p_w[:5])  # imports, caches
    start = time.perf_counter()
    d = _diagnose(scene, p_w, T_w_b_newest=scene["T_w_b_newest"])
    elapsed_s = time.perf_counter() - start
    assert d.mistake == "composition order swapped"
    assert elapsed_s < 1.0, f"{elapsed_s:.3f} s"


# ------------------------------------------------------------------ the simulator's runs


def _run_scene(run) -> tuple[dict, dict[str, np.ndarray]]:
    """A built-in run's observations, as a plug-in would see them: ``p_c`` is the
    ``depth_image`` estimate in the camera frame with the estimator's own pose and mount, the
    newest pose received when the image arrived (the exposure pose where none is recorded).
    Also the run's own estimates (``depth_image``, ``naive``) of the same detections."""
    rows: list[tuple] = []
    own: dict[str, list] = {"depth_image": [], "naive": []}
    for tick in run.result.ticks:
        newest = tick.timing.T_w_b_latest if tick.timing is not None else None
        for d in tick.detections:
            p_w = d.estimates_w.get("depth_image")
            if p_w is None:
                continue
            p_c = se3.apply(se3.invert(tick.T_w_b_est @ tick.T_b_c_est), p_w)
            T_w_b_newest = tick.T_w_b_est if newest is None else newest
            rows.append((p_c, tick.T_w_b_est, tick.T_b_c_est, T_w_b_newest))
            own["depth_image"].append(p_w)
            own["naive"].append(d.estimates_w["naive"])
    assert len(rows) >= 5, "the run should have depth_image estimates"
    p_c, T_w_b, T_b_c, T_w_b_newest = (np.array(column) for column in zip(*rows, strict=True))
    scene = {"p_c": p_c, "T_w_b": T_w_b, "T_b_c": T_b_c, "T_w_b_newest": T_w_b_newest}
    return scene, {k: np.array(v) for k, v in own.items()}


@pytest.mark.parametrize("scenario", ["frame-problem", "transform-composer"])
def test_builtin_runs_estimates_are_diagnosed(builtin_runs, scenario):
    """The run's own estimates: ``depth_image`` is the correct chain, ``naive`` (built from it,
    vnav.estimators.naive) the naive chain; three mistakes applied to the run's observations are
    named."""
    scene, own = _run_scene(builtin_runs[scenario])
    d = _diagnose(scene, own["depth_image"])
    assert d.verdict == "correct" and d.residual_m < 1e-9, d.explain()
    d = _diagnose(scene, own["naive"])
    assert (d.verdict, d.mistake) == ("mistake", "naive chain"), d.explain()
    assert d.residual_m < 1e-9
    for name in ("rotation transposed", "mount inverted", "composition order swapped"):
        d = _diagnose(scene, _estimates(name, scene))
        assert (d.verdict, d.mistake) == ("mistake", name), d.explain()
        assert d.residual_m < 1e-9


def test_builtin_latency_run_names_the_stale_pose(builtin_runs):
    """The latency built-in's newest poses (50 ms late, through a fast yaw): a user chain fed
    them is named "pose at the wrong time"; without them the doctor cannot say."""
    scene, _ = _run_scene(builtin_runs["latency"])
    stale = ~np.all(scene["T_w_b_newest"] == scene["T_w_b"], axis=(1, 2))
    assert stale.sum() >= 5
    p_w = _estimates("pose at the wrong time", scene)
    d = _diagnose(scene, p_w, T_w_b_newest=scene["T_w_b_newest"])
    assert (d.verdict, d.mistake) == ("mistake", "pose at the wrong time"), d.explain()
    assert d.residual_m < 1e-9 < d.correct_residual_m
    assert _diagnose(scene, p_w).verdict == "unexplained"
