"""vnav's geometry core against SciPy and pytransform3d, side by side, quiet and under load.

Every batch operation of the geometry core, on the same float64 data for all contenders
(1e6 elements by default): ``so3.exp``, ``so3.log``, ``quat.to_matrix``,
``quat.from_matrix`` (validated, and with ``assume_valid=True``), ``quat.multiply`` and
``se3.apply``, with two floors for the point transform: a plain copy of the points, and the
cheapest pass that computes its output, ``np.negative`` of the points. vnav has no function
composing pose stacks (``T_a_b @ T_b_c`` is numpy's ``@``), so none is timed here.

Why two floors: a large copy (glibc's ``memcpy``) writes whole cache lines without reading
them first, while every kernel that computes its output (a numpy ufunc, OpenCV, BLAS) reads
each output line into the cache before writing it (read for ownership): 72 bytes of memory
traffic per point instead of 48. Once the arrays no longer fit in the cache, the copy is
therefore about 1.5x faster than anything that computes, whatever it computes; the one-pass
floor is what a transform can reach, the copy what memory alone allows.

How it is measured: the contenders take turns (each repeat calls every one once, so they all
meet the same background load), in two groups, the rotation stacks and the point sets (a
program transforming its points every frame does not flush them from the cache with 72 MB
of matrices in between), after one warm-up call each; the best of ``--repeats``
samples is the least disturbed run, the median the typical one. A sample of a fast call (the
point transforms, the copies) is the median of back-to-back calls lasting about 20 ms, so that
one lost scheduler time slice, or the first call's cold cache, does not pass for the call's
cost (``_time_interleaved``). The whole series runs twice: on the
machine as it is, then beside a busy neighbour, a child process spinning on one core, which
the benchmark starts and always stops (also on an error or Ctrl-C). Before any timing, each
peer's answer is compared with vnav's: a fast wrong answer is no answer.

Targets (the table says "met" or "NOT met" for each): vnav at least as fast as SciPy and as
pytransform3d on every operation, best and median, quiet and busy; ``se3.apply`` within 1.3x
the copy of its points (with and without ``out=``), and within 1.3x the one-pass floor;
every vnav median beside the busy neighbour within 2x of the quiet one. SciPy and
pytransform3d are benchmark-only dependencies (``pip install -e '.[bench]'``), never imported
by the library.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np

from vnav import quat, se3, so3

# Largest accepted difference between vnav's answer and a peer's. A wrong formula is off by
# 1e-3 or more; correct ones differ by their rounding, up to ~1e-11 where pytransform3d's
# log takes the axis from R - R^T close to pi (sin(theta) ~ 1e-5 there, the axis loses 5 digits).
_AGREE_ATOL = 1e-10
_PEERS = ("scipy", "pt3d")
_PEER_TITLE = {"scipy": "SciPy", "pt3d": "pytransform3d"}
_LABEL = 44  # width of the operation column
_APPLY_OVER_COPY = 1.3  # se3.apply at most this many copies of its points
_SAMPLE_S = 0.02  # a timing sample averages back-to-back calls of a fast function up to this
_BUSY_OVER_QUIET = 2.0  # a vnav median beside the busy neighbour, at most this many quiet ones
# The busy neighbour: spins until stopped, or until its parent is gone (reparented).
_SPIN = "import os\nparent = os.getppid()\nwhile os.getppid() == parent:\n    sum(range(10000))\n"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``python -m benchmarks geometry``."""
    parser.add_argument("--n", type=int, default=1_000_000, help="elements per batch (1e6)")
    parser.add_argument("--repeats", type=int, default=7, help="timed calls of each (N)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--n-large",
        type=int,
        default=10_000_000,
        help="points of the out-of-cache figure (1e7)",
    )


@dataclass
class Row:
    """One line of the table: a vnav call, its peers' equivalents (timing keys, None where a
    peer has none) and how far each peer's answer is from vnav's."""

    label: str
    vnav: str
    peers: dict[str, str | None]
    compare: Callable[[np.ndarray, np.ndarray], float]
    floor: str | None = None  # the copy this row is held to, for se3.apply
    one_pass: str | None = None  # the cheapest computing pass of the same memory traffic
    agree: dict[str, float] = field(default_factory=dict)


def _inputs(n: int, seed: int) -> dict[str, np.ndarray]:
    """The same data for every contender: unit quaternions (both orders), their rotation
    matrices, rotation vectors, one pose, points (and homogeneous points for pytransform3d)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    q = Rotation.random(n, random_state=seed).as_quat()  # xyzw, unit
    q2 = Rotation.random(n, random_state=seed + 2).as_quat()
    p_b = rng.uniform(-10.0, 10.0, size=(n, 3))
    return {
        "q": q,
        "q2": q2,
        # pytransform3d orders quaternions w, x, y, z: reordered here, outside the timing.
        "q_wxyz": np.ascontiguousarray(q[:, [3, 0, 1, 2]]),
        "q2_wxyz": np.ascontiguousarray(q2[:, [3, 0, 1, 2]]),
        "R": Rotation.from_quat(q).as_matrix(),
        "rotvec": Rotation.random(n, random_state=seed + 1).as_rotvec(),
        "T_a_b": se3.make(so3.exp([0.3, -0.2, 1.1]), [1.0, -2.0, 0.5]),
        "p_b": p_b,
        "p_b_h": np.column_stack([p_b, np.ones(n)]),  # pytransform3d's homogeneous points
        "p_a_buf": np.empty_like(p_b),
    }


def _contenders(d: dict[str, np.ndarray]) -> dict[str, Callable[[], object]]:
    """Every timed call, by key ``<operation>/<who>``."""
    import pytransform3d.batch_rotations as pbr
    import pytransform3d.transformations as ptr
    from scipy.spatial.transform import RigidTransform, Rotation

    q, q2, R, v, T, p = d["q"], d["q2"], d["R"], d["rotvec"], d["T_a_b"], d["p_b"]
    rigid, rot, t_a_b = RigidTransform.from_matrix(T), Rotation.from_matrix(T[:3, :3]), T[:3, 3]
    buf = d["p_a_buf"]
    return {
        "exp/vnav": lambda: so3.exp(v),
        "exp/scipy": lambda: Rotation.from_rotvec(v).as_matrix(),
        "exp/pt3d": lambda: pbr.matrices_from_compact_axis_angles(v),
        "log/vnav": lambda: so3.log(R),
        "log/scipy": lambda: Rotation.from_matrix(R).as_rotvec(),
        "log/pt3d": lambda: pbr.axis_angles_from_matrices(R),
        "to_matrix/vnav": lambda: quat.to_matrix(q),
        "to_matrix/scipy": lambda: Rotation.from_quat(q).as_matrix(),
        "to_matrix/pt3d": lambda: pbr.matrices_from_quaternions(d["q_wxyz"]),
        "from_matrix/vnav": lambda: quat.from_matrix(R),
        "from_matrix/scipy": lambda: Rotation.from_matrix(R).as_quat(),
        "from_matrix_valid/vnav": lambda: quat.from_matrix(R, assume_valid=True),
        "from_matrix_valid/scipy": lambda: Rotation.from_matrix(R, assume_valid=True).as_quat(),
        "from_matrix/pt3d": lambda: pbr.quaternions_from_matrices(R),  # never checks R
        "multiply/vnav": lambda: quat.multiply(q, q2),
        "multiply/scipy": lambda: (Rotation.from_quat(q) * Rotation.from_quat(q2)).as_quat(),
        "multiply/pt3d": lambda: pbr.batch_concatenate_quaternions(d["q_wxyz"], d["q2_wxyz"]),
        "apply/vnav": lambda: se3.apply(T, p),
        "apply/scipy": lambda: rigid.apply(p),
        "apply_rotation/scipy": lambda: rot.apply(p) + t_a_b,
        "apply/pt3d": lambda: ptr.transform(T, d["p_b_h"]),
        "apply_out/vnav": lambda: se3.apply(T, p, out=buf),
        "copy/floor": lambda: p.copy(),
        "copy_out/floor": lambda: np.copyto(buf, p),
        "pass/floor": lambda: np.negative(p),
        "pass_out/floor": lambda: np.negative(p, out=buf),
    }


def _max_diff(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max())


def _quat_diff(a: np.ndarray, b: np.ndarray) -> float:
    """Largest difference of two quaternion arrays, each row up to its sign (q and -q are one
    rotation; SciPy and pytransform3d do not canonicalise)."""
    return float(np.minimum(np.abs(a - b).max(axis=1), np.abs(a + b).max(axis=1)).max())


def _rotvec_diff(a: np.ndarray, b: np.ndarray) -> float:
    """Largest difference of two rotation-vector arrays; at an angle of pi, v and -v are one
    rotation."""
    diff = np.abs(a - b).max(axis=1)
    at_pi = np.linalg.norm(a, axis=1) > np.pi - 1e-9
    diff[at_pi] = np.minimum(diff[at_pi], np.abs(a + b)[at_pi].max(axis=1))
    return float(diff.max())


# What each peer runs, printed under the tables.
_LEGEND = (
    "SciPy: Rotation.from_rotvec(v).as_matrix(), from_matrix(R).as_rotvec(), "
    "from_quat(q).as_matrix(), from_matrix(R).as_quat() (then with assume_valid=True), "
    "(from_quat(q) * from_quat(q2)).as_quat(), RigidTransform.apply(p)",
    "pytransform3d: batch_rotations.matrices_from_compact_axis_angles(v), "
    "axis_angles_from_matrices(R), matrices_from_quaternions(q_wxyz), "
    "quaternions_from_matrices(R) (it checks nothing: one timing for both rows), "
    "batch_concatenate_quaternions(q_wxyz, q2_wxyz), transformations.transform(T, p_h)",
    "vnav checks its input (rotations, unit norms) except with assume_valid=True",
)

# A peer's answer in vnav's form, where the forms differ.
_AS_VNAV: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "log/pt3d": lambda axis_angle: axis_angle[:, :3] * axis_angle[:, 3:],  # to theta u
    "from_matrix/pt3d": lambda q_wxyz: q_wxyz[:, [1, 2, 3, 0]],  # w x y z to x y z w
    "multiply/pt3d": lambda q_wxyz: q_wxyz[:, [1, 2, 3, 0]],
    "apply/pt3d": lambda p_h: p_h[:, :3],  # homogeneous to 3-vectors
}


def _rows() -> list[Row]:
    """The table's rows; ``compare`` measures how far a peer's answer is from vnav's."""

    def both(op: str) -> dict[str, str | None]:
        return {"scipy": f"{op}/scipy", "pt3d": f"{op}/pt3d"}

    fm_valid = {"scipy": "from_matrix_valid/scipy", "pt3d": "from_matrix/pt3d"}
    return [
        Row("so3.exp(rotvec)", "exp/vnav", both("exp"), _max_diff),
        Row("so3.log(R)", "log/vnav", both("log"), _rotvec_diff),
        Row("quat.to_matrix(q)", "to_matrix/vnav", both("to_matrix"), _max_diff),
        Row("quat.from_matrix(R)", "from_matrix/vnav", both("from_matrix"), _quat_diff),
        Row(
            "quat.from_matrix(R, assume_valid=True)", "from_matrix_valid/vnav", fm_valid, _quat_diff
        ),
        Row("quat.multiply(q, q2)", "multiply/vnav", both("multiply"), _quat_diff),
        Row("se3.apply(T, p)", "apply/vnav", both("apply"), _max_diff, "copy/floor", "pass/floor"),
        Row(
            "se3.apply(T, p) [SciPy: Rotation.apply + t]",
            "apply/vnav",
            {"scipy": "apply_rotation/scipy", "pt3d": None},
            _max_diff,
        ),
        Row(
            "se3.apply(T, p, out=buf)",
            "apply_out/vnav",
            {},
            _max_diff,
            "copy_out/floor",
            "pass_out/floor",
        ),
    ]


def _agreement(rows: list[Row], fns: dict[str, Callable[[], object]]) -> None:
    """Fill each row's ``agree``: the distance of every peer's answer from vnav's."""
    for row in rows:
        mine = fns[row.vnav]()
        for peer, key in row.peers.items():
            if key is not None:
                theirs = fns[key]()
                theirs = _AS_VNAV[key](theirs) if key in _AS_VNAV else theirs
                row.agree[peer] = row.compare(mine, theirs)


_POINT_OPS = ("apply", "apply_rotation", "apply_out", "copy", "copy_out", "pass", "pass_out")
"""Operations on point sets, timed as a group of their own (``run``)."""


def _out_of_cache(n: int, seed: int, repeats: int) -> dict[str, dict[str, float]]:
    """``se3.apply`` into a buffer, a copy and the one-pass floor on ``n`` points, far more
    than any cache holds (240 MB in, 240 MB out at 1e7): what memory alone allows, best and
    median in milliseconds. Not a target: it shows why the copy is out of reach once the
    points come from memory (the module's docstring)."""
    rng = np.random.default_rng(seed)
    p_b = rng.uniform(-10.0, 10.0, size=(n, 3))
    buf = np.empty_like(p_b)
    T_a_b = se3.make(so3.exp([0.3, -0.2, 1.1]), [1.0, -2.0, 0.5])
    fns = {
        "apply_out": lambda: se3.apply(T_a_b, p_b, out=buf),
        "copy_out": lambda: np.copyto(buf, p_b),
        "pass_out": lambda: np.negative(p_b, out=buf),
    }
    return _stats(_time_interleaved(fns, repeats))


def _time_interleaved(fns: dict[str, Callable[[], object]], repeats: int) -> dict[str, np.ndarray]:
    """Seconds per call of each function, ``repeats`` samples each, the functions taking turns
    in a shuffled order (so that every contender meets the same background load).

    A sample is the median of k back-to-back calls, k set by a timed call after the warm-up
    so that a sample lasts about ``_SAMPLE_S`` (k = 1 for every call that long): the steady
    cost of a call. One scheduler time slice lost would otherwise triple a 1.5 ms call; and
    the first call after another contender pays for the cache and memory that contender left
    (measured: 15 to 20 ms for the first ``cv2.transform`` of 1e6 points after
    pytransform3d's transform, which allocates and frees 64 MB, then 1.8 ms per call), which
    is the interleaving's cost, not the call's. A stall that hits every call still shows in
    full.
    """
    calls = {}
    for name, fn in fns.items():
        fn()  # warm-up: imports, first-touch of memory
        start = time.perf_counter()
        fn()
        calls[name] = max(1, round(_SAMPLE_S / (time.perf_counter() - start)))
    seconds = {name: np.empty(repeats) for name in fns}
    # A new order each repeat (seeded): no contender always follows the same one, whose
    # leftovers in the cache and memory it would otherwise always inherit.
    order = np.random.default_rng(0)
    for i in range(repeats):
        for name in order.permutation(list(fns)):
            fn = fns[name]
            each = np.empty(calls[name])
            for j in range(calls[name]):
                start = time.perf_counter()
                fn()
                each[j] = time.perf_counter() - start
            seconds[name][i] = np.median(each)
    return seconds


@contextlib.contextmanager
def _busy_neighbour() -> Iterator[subprocess.Popen]:
    """A child process spinning on one core while the block runs; stopped on the way out,
    whatever the way (an error, Ctrl-C), and it also stops by itself if this process dies."""
    proc = subprocess.Popen(
        [sys.executable, "-c", _SPIN], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL
    )
    try:
        time.sleep(0.5)  # running, and seen by the scheduler, before the first timing
        yield proc
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _stats(seconds: dict[str, np.ndarray]) -> dict[str, dict[str, float]]:
    """Best and median of each contender, in milliseconds."""
    return {
        key: {"best_ms": float(s.min() * 1e3), "median_ms": float(np.median(s) * 1e3)}
        for key, s in seconds.items()
    }


def _comparisons(rows: list[Row], ms: dict) -> list[dict]:
    """Every (row, peer, condition, statistic) comparison: the peer's time over vnav's (>= 1
    is the target) and whether the two answers agree."""
    out = []
    for row in rows:
        for peer, key in row.peers.items():
            if key is None:
                continue
            for cond, stats in ms.items():
                for stat in ("best_ms", "median_ms"):
                    ratio = stats[key][stat] / stats[row.vnav][stat]
                    agree = row.agree[peer] <= _AGREE_ATOL
                    out.append(
                        {
                            "row": row.label,
                            "peer": peer,
                            "condition": cond,
                            "stat": stat,
                            "ratio": ratio,
                            "agree": agree,
                            "met": bool(ratio >= 1.0 and agree),
                        }
                    )
    return out


def _targets(rows: list[Row], ms: dict) -> dict:
    """The four targets, each with its figures and whether it is met."""
    comparisons = _comparisons(rows, ms)
    quiet, busy = ms["quiet"], ms["busy"]

    def over(floor: str) -> dict[str, dict[str, float]]:
        return {
            row.label: {
                stat: quiet[row.vnav][stat] / quiet[getattr(row, floor)][stat]
                for stat in quiet[row.vnav]
            }
            for row in rows
            if getattr(row, floor)
        }

    floors, one_pass = over("floor"), over("one_pass")
    steady = {
        key: busy[key]["median_ms"] / quiet[key]["median_ms"]
        for key in dict.fromkeys(row.vnav for row in rows)
    }
    return {
        "ahead_of_peers": {
            "met": all(c["met"] for c in comparisons),
            "not_met": [c for c in comparisons if not c["met"]],
            "count": len(comparisons),
        },
        "apply_over_copy": {
            "figures": floors,
            "met": all(r <= _APPLY_OVER_COPY for f in floors.values() for r in f.values()),
        },
        "apply_over_one_pass": {
            "figures": one_pass,
            "met": all(r <= _APPLY_OVER_COPY for f in one_pass.values() for r in f.values()),
        },
        "busy_over_quiet_median": {
            "figures": steady,
            "met": all(r <= _BUSY_OVER_QUIET for r in steady.values()),
        },
    }


def _cell(stats: dict | None) -> str:
    return "-" if stats is None else f"{stats['best_ms']:.2f} / {stats['median_ms']:.2f}"


def _ratio(mine: dict, theirs: dict | None) -> str:
    if theirs is None:
        return ""
    return (
        f"{theirs['best_ms'] / mine['best_ms']:.2f} / {theirs['median_ms'] / mine['median_ms']:.2f}"
    )


def _print_condition(title: str, rows: list[Row], ms: dict, floors: dict[str, str]) -> None:
    """One table: every row's best / median for vnav and each peer, the peer/vnav ratios,
    and how far each peer's answer is from vnav's."""
    print(title)
    head = f"{'operation':<{_LABEL}} {'vnav':>15}"
    for peer in _PEERS:
        head += f" {_PEER_TITLE[peer]:>15} {'x vnav':>11}"
    print(head + f" {'max|diff| S, P':>17}")
    print("-" * (len(head) + 18))
    for row in rows:
        line = f"{row.label:<{_LABEL}} {_cell(ms[row.vnav]):>15}"
        for peer in _PEERS:
            key = row.peers.get(peer)
            theirs = ms[key] if key else None
            line += f" {_cell(theirs):>15} {_ratio(ms[row.vnav], theirs):>11}"
        agree = " ".join(f"{row.agree[p]:.0e}" if p in row.agree else "-" for p in _PEERS)
        print(line + f" {agree:>17}")
    for key, label in floors.items():
        print(f"{label:<{_LABEL}} {_cell(ms[key]):>15}")
    print()


_FLOORS = {
    "copy/floor": "copy of the points, p.copy()",
    "copy_out/floor": "copy into a buffer, np.copyto(buf, p)",
    "pass/floor": "one pass, np.negative(p)",
    "pass_out/floor": "one pass into a buffer, np.negative(p, out=buf)",
}
"""The floors' timing keys and their labels, under each table."""


def _verdict(met: bool) -> str:
    """A target's verdict, as the tables print it."""
    return "met" if met else "NOT met"


def _print_tables(figures: dict, rows: list[Row]) -> None:
    """What was measured and how, the quiet and the busy table, and what each peer runs."""
    n, repeats = figures["n"], figures["repeats"]
    print(
        f"vnav vs SciPy {figures['versions']['scipy']} vs pytransform3d "
        f"{figures['versions']['pt3d']}: n = {n:,}, float64, best / median of {repeats} "
        f"interleaved samples (ms per call; a sample is the median of back-to-back calls over "
        f"{_SAMPLE_S * 1e3:.0f} ms); 'x vnav' = peer time / vnav time (>= 1: vnav ahead)"
    )
    for cond, title in (("quiet", "quiet"), ("busy", "beside a busy neighbour process")):
        load = figures["load_1min"][cond]
        title = f"{title} (1-min load average {load:.2f} before it started)"
        _print_condition(title, rows, figures["ms"][cond], _FLOORS)
    print("\n".join(_LEGEND) + "\n")


def _print_targets(figures: dict) -> None:
    """Every target, met or not (each comparison not met named), and the out-of-cache
    figure."""
    t = figures["targets"]
    ahead = t["ahead_of_peers"]
    print(
        f"vnav >= SciPy and >= pytransform3d (best and median, quiet and busy, answers within "
        f"{_AGREE_ATOL:g}): {_verdict(ahead['met'])} "
        f"({ahead['count'] - len(ahead['not_met'])} of {ahead['count']} comparisons)"
    )
    for c in ahead["not_met"]:
        why = f"ratio {c['ratio']:.2f}" if c["agree"] else "answers differ"
        print(
            f"  NOT met: {c['row']} vs {_PEER_TITLE[c['peer']]}, {c['condition']} "
            f"{c['stat'][:-3]}: {why}"
        )
    for label, f in t["apply_over_copy"]["figures"].items():
        print(f"{label} / copy: best {f['best_ms']:.2f}, median {f['median_ms']:.2f}")
    print(f"se3.apply <= {_APPLY_OVER_COPY}x copy: {_verdict(t['apply_over_copy']['met'])}")
    for label, f in t["apply_over_one_pass"]["figures"].items():
        print(f"{label} / one pass: best {f['best_ms']:.2f}, median {f['median_ms']:.2f}")
    print(f"se3.apply <= {_APPLY_OVER_COPY}x one pass: {_verdict(t['apply_over_one_pass']['met'])}")
    steady = t["busy_over_quiet_median"]["figures"]
    print(
        "busy median / quiet median: "
        + ", ".join(f"{k.split('/')[0]} {v:.2f}" for k, v in steady.items())
    )
    print(
        f"busy median <= {_BUSY_OVER_QUIET:g}x quiet median: "
        f"{_verdict(t['busy_over_quiet_median']['met'])}"
    )
    big = figures["out_of_cache"]
    print(
        f"out of cache, {figures['n_large']:,} points: se3.apply(out=) "
        f"{big['apply_out']['best_ms']:.1f} ms, copy {big['copy_out']['best_ms']:.1f} ms "
        f"(x{big['apply_out']['best_ms'] / big['copy_out']['best_ms']:.2f}), one pass "
        f"{big['pass_out']['best_ms']:.1f} ms "
        f"(x{big['apply_out']['best_ms'] / big['pass_out']['best_ms']:.2f}); a copy writes "
        "without reading its destination first, a computing pass cannot (not a target)"
    )
    print(f"all targets: {_verdict(figures['targets_met'])}")


def _print(figures: dict, rows: list[Row]) -> None:
    """The two tables, the steadiness figures and every target, met or not."""
    _print_tables(figures, rows)
    _print_targets(figures)


def run(args: argparse.Namespace) -> dict:
    """Time every contender quiet and beside a busy process; print the tables unless
    ``--json``; return the figures."""
    import pytransform3d
    import scipy

    data = _inputs(args.n, args.seed)
    fns = _contenders(data)
    rows = _rows()
    _agreement(rows, fns)
    figures: dict = {
        "n": args.n,
        "n_large": args.n_large,
        "repeats": args.repeats,
        "versions": {"scipy": scipy.__version__, "pt3d": pytransform3d.__version__},
        "load_1min": {},
        "ms": {},
    }
    # Two groups, each interleaved within itself: the rotation stacks (72 MB of matrices each)
    # would otherwise flush the point sets from the cache between samples of the point
    # transforms, which a program transforming its points every frame does not see.
    points = {k: f for k, f in fns.items() if k.split("/")[0] in _POINT_OPS}
    rotations = {k: f for k, f in fns.items() if k not in points}
    for cond in ("quiet", "busy"):
        figures["load_1min"][cond] = os.getloadavg()[0]  # the machine's, before the neighbour
        with _busy_neighbour() if cond == "busy" else contextlib.nullcontext():
            seconds = _time_interleaved(rotations, args.repeats)
            seconds |= _time_interleaved(points, args.repeats)
            figures["ms"][cond] = _stats(seconds)
    figures["out_of_cache"] = _out_of_cache(args.n_large, args.seed, args.repeats)
    figures["agree"] = {row.label: row.agree for row in rows}
    figures["targets"] = _targets(rows, figures["ms"])
    figures["targets_met"] = all(t["met"] for t in figures["targets"].values())
    if not getattr(args, "json", False):
        _print(figures, rows)
    return figures
