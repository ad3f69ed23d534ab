"""vnav geometry core against SciPy: SE(3) on points, quaternions and rotation vectors to matrices
and back (``quat.from_matrix``, validated and with ``assume_valid``).

Same data for both, float64, best of several repeats (the least disturbed run). The point
transform is compared with SciPy's SE(3) type (``RigidTransform.apply``) and with its fastest
route, ``Rotation.apply(p) + t``. Targets: vnav at least as fast as SciPy on each operation
(ratio scipy/vnav >= 1.0), and the point transform within 3x of a plain copy of the same (N, 3)
array, the memory-bandwidth floor.
SciPy is imported here only, never by the library.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np

from vnav import quat, se3, so3


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``python -m benchmarks geometry``."""
    parser.add_argument("--n", type=int, default=1_000_000, help="points/rotations (1e6)")
    parser.add_argument("--repeats", type=int, default=20, help="repeats; the best one counts")
    parser.add_argument("--seed", type=int, default=0)


def _best_interleaved(fns: dict[str, Callable[[], object]], repeats: int) -> dict[str, float]:
    """Seconds of the fastest call of each function, the functions taking turns.

    Taking turns (rather than timing one function's repeats, then the next's) exposes every
    contender to the same background load; after one warm-up call each, the best of
    ``repeats`` is the least disturbed run.
    """
    for fn in fns.values():
        fn()
    best = dict.fromkeys(fns, np.inf)
    for _ in range(repeats):
        for name, fn in fns.items():
            start = time.perf_counter()
            fn()
            best[name] = min(best[name], time.perf_counter() - start)
    return best


def _quat_diff(a: np.ndarray, b: np.ndarray) -> float:
    """Largest difference of two quaternion arrays, each row up to its sign (q and -q are one
    rotation; SciPy does not canonicalise)."""
    return float(np.minimum(np.abs(a - b).max(axis=1), np.abs(a + b).max(axis=1)).max())


def run(args: argparse.Namespace) -> dict:
    """Time every operation, check vnav and SciPy agree, print the table unless ``--json``."""
    from scipy.spatial.transform import RigidTransform, Rotation

    n, repeats = args.n, args.repeats
    rng = np.random.default_rng(args.seed)
    p_b = rng.uniform(-10.0, 10.0, size=(n, 3))
    T_a_b = se3.make(so3.exp([0.3, -0.2, 1.1]), [1.0, -2.0, 0.5])
    rot = Rotation.from_matrix(T_a_b[:3, :3])
    rigid = RigidTransform.from_matrix(T_a_b)
    t_a_b = T_a_b[:3, 3]
    q = Rotation.random(n, random_state=args.seed).as_quat()  # xyzw, unit
    R = Rotation.from_quat(q).as_matrix()
    rotvec = Rotation.random(n, random_state=args.seed + 1).as_rotvec()

    # Same results first: a fast wrong answer is no answer.
    agree = {
        "se3_apply": np.abs(se3.apply(T_a_b, p_b) - rigid.apply(p_b)).max(),
        "se3_apply_vs_rotation": np.abs(se3.apply(T_a_b, p_b) - (rot.apply(p_b) + t_a_b)).max(),
        "quat_to_matrix": np.abs(quat.to_matrix(q) - Rotation.from_quat(q).as_matrix()).max(),
        "so3_exp": np.abs(so3.exp(rotvec) - Rotation.from_rotvec(rotvec).as_matrix()).max(),
        "quat_from_matrix": _quat_diff(quat.from_matrix(R), Rotation.from_matrix(R).as_quat()),
    }
    agree["quat_from_matrix_assume_valid"] = agree["quat_from_matrix"]

    cases = {
        "se3_apply": (
            lambda: se3.apply(T_a_b, p_b),
            lambda: rigid.apply(p_b),
            "se3.apply(T, p) vs RigidTransform.apply(p)",
        ),
        "se3_apply_vs_rotation": (
            lambda: se3.apply(T_a_b, p_b),
            lambda: rot.apply(p_b) + t_a_b,
            "se3.apply(T, p) vs Rotation.apply(p) + t",
        ),
        "quat_to_matrix": (
            lambda: quat.to_matrix(q),
            lambda: Rotation.from_quat(q).as_matrix(),
            "quat.to_matrix(q) vs from_quat(q).as_matrix()",
        ),
        "so3_exp": (
            lambda: so3.exp(rotvec),
            lambda: Rotation.from_rotvec(rotvec).as_matrix(),
            "so3.exp(v) vs from_rotvec(v).as_matrix()",
        ),
        "quat_from_matrix": (
            lambda: quat.from_matrix(R),
            lambda: Rotation.from_matrix(R).as_quat(),
            "quat.from_matrix(R) vs from_matrix(R).as_quat()",
        ),
        "quat_from_matrix_assume_valid": (
            lambda: quat.from_matrix(R, assume_valid=True),
            lambda: Rotation.from_matrix(R, assume_valid=True).as_quat(),
            "  the same, assume_valid=True on both",
        ),
    }
    fns: dict[str, Callable[[], object]] = {"copy": lambda: p_b.copy()}
    vnav_key = {name: name.split("_vs_")[0] for name in cases}  # one se3.apply timing for both
    for name, (vnav_fn, scipy_fn, _) in cases.items():
        fns[f"{vnav_key[name]}/vnav"] = vnav_fn
        fns[f"{name}/scipy"] = scipy_fn
    best = _best_interleaved(fns, repeats)
    figures: dict = {"n": n, "repeats": repeats, "copy_ms": best["copy"] * 1e3}
    for name in cases:
        vnav_s, scipy_s = best[f"{vnav_key[name]}/vnav"], best[f"{name}/scipy"]
        figures[name] = {
            "vnav_ms": vnav_s * 1e3,
            "scipy_ms": scipy_s * 1e3,
            "ratio_scipy_over_vnav": scipy_s / vnav_s,
            "max_abs_diff": float(agree[name]),
        }
    apply_over_copy = figures["se3_apply"]["vnav_ms"] / figures["copy_ms"]
    figures["apply_over_copy"] = apply_over_copy
    figures["targets_met"] = bool(
        all(figures[k]["ratio_scipy_over_vnav"] >= 1.0 for k in cases) and apply_over_copy <= 3.0
    )

    if not getattr(args, "json", False):
        print(f"vnav vs SciPy, n = {n:,}, float64, best of {repeats} (ms)")
        head = f"{'operation':<48} {'vnav':>8} {'scipy':>8} {'scipy/vnav':>10} {'max|diff|':>10}"
        print(head)
        print("-" * len(head))
        for name, (_, _, label) in cases.items():
            f = figures[name]
            print(
                f"{label:<48} {f['vnav_ms']:8.2f} {f['scipy_ms']:8.2f} "
                f"{f['ratio_scipy_over_vnav']:10.2f} {f['max_abs_diff']:10.1e}"
            )
        print(f"{'copy of the (N, 3) points (bandwidth floor)':<48} {figures['copy_ms']:8.2f}")
        print(f"se3.apply / copy: {apply_over_copy:.2f} (target <= 3)")
        print(
            "targets (scipy/vnav >= 1 on each, apply/copy <= 3): "
            + ("met" if figures["targets_met"] else "NOT met")
        )
    return figures
