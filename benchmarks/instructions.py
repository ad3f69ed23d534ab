"""Instructions per localised detection, counted by valgrind: a figure a busy machine cannot move.

Wall-clock benchmarks on a shared 2-core machine drift by 10% from one minute to the next, more
than the changes they are asked to judge. ``valgrind --tool=callgrind`` counts the instructions
a process executes, the same count for the same code and inputs whatever else runs beside it.
This benchmark renders the ``perception`` benchmark's frame once (natively), then runs
``vnav.localize.localize`` on it ``--calls`` times in a process under callgrind, and again with
no call; the difference over the calls is the count per call, start-up and imports cancelled.
With ``--against REV`` the same is counted for git revision REV (a temporary worktree) with
its own ``benchmarks.perception`` helpers, and the ratio now / REV is printed, with and without
covariances (``localize`` and ``localize_points`` of the ``perception`` benchmark).

Needs valgrind (``apt-get install valgrind``); a few minutes (Python runs ~50x slower under it).
"""

from __future__ import annotations

import argparse
import os
import pickle
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

_ROOT = Path(__file__).resolve().parents[1]

# Runs in the measured process, with the tree under test first on sys.path: its own noise and
# covariance helpers (their names and types changed between revisions), the frame from a file.
_INNER = r"""
import pickle, sys
root, frame_path, calls, with_cov = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4] == "1"
sys.path.insert(0, root)
import benchmarks.perception as perception
from vnav.detect import detect_cones
from vnav.localize import localize
with open(frame_path, "rb") as f:
    frame = pickle.load(f)
det = detect_cones(frame["rgb"])[0]
# Older revisions name it with a leading underscore.
noise_of = getattr(perception, "uncertainty_noise", None) or perception._uncertainty_noise
noise, cov_T_w_b = noise_of(frame["T_w_b"])
def call():
    return localize(det, frame["camera"], frame["T_w_b"], frame["T_b_c"], frame["depth"],
                    far_m=frame["far_m"], noise=noise, cov_T_w_b=cov_T_w_b,
                    with_covariance=with_cov)
call()  # first-use work (imports inside vnav, caches) outside the difference
for _ in range(calls):
    call()
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--calls", type=int, default=100, help="localize calls counted")
    parser.add_argument("--against", metavar="REV", help="also count git revision REV")


def _count(root: Path, frame_path: Path, calls: int, with_cov: bool) -> int:
    """Instructions of one process running ``calls`` localize calls with ``root``'s code."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    proc = subprocess.run(
        [
            "valgrind",
            "--tool=callgrind",
            "--callgrind-out-file=/dev/null",
            sys.executable,
            "-c",
            _INNER,
            str(root),
            str(frame_path),
            str(calls),
            "1" if with_cov else "0",
        ],
        capture_output=True,
        text=True,
        env=env,
        check=False,
    )
    found = re.search(r"Collected : (\d+)", proc.stderr)
    if proc.returncode != 0 or found is None:
        raise RuntimeError(f"valgrind run failed ({proc.returncode}): {proc.stderr[-500:]}")
    return int(found[1])


def _per_call(root: Path, frame_path: Path, calls: int, with_cov: bool) -> float:
    return (_count(root, frame_path, calls, with_cov) - _count(root, frame_path, 0, with_cov)) / (
        calls
    )


def run(args: argparse.Namespace) -> dict:
    if shutil.which("valgrind") is None:
        raise SystemExit("benchmarks instructions: valgrind is not installed (apt-get install)")
    from benchmarks.perception import benchmark_frame

    calls = getattr(args, "calls", 100)
    against = getattr(args, "against", None)
    with tempfile.TemporaryDirectory(prefix="vnav-bench-ins-") as tmp:
        f = benchmark_frame()
        world = f["world"]
        frame_path = Path(tmp) / "frame.pkl"
        with open(frame_path, "wb") as out:
            frame = {k: f[k] for k in ("rgb", "depth", "far_m")}
            frame |= {"camera": world.camera, "T_w_b": world.T_w_b, "T_b_c": world.T_b_c}
            pickle.dump(frame, out)
        trees = {"now": _ROOT}
        if against:
            rev = Path(tmp) / "rev"
            subprocess.run(
                ["git", "-C", str(_ROOT), "worktree", "add", "--detach", str(rev), against],
                check=True,
                capture_output=True,
            )
            trees[against] = rev
        try:
            figures: dict[str, object] = {"calls": calls}
            for label, root in trees.items():
                for name, with_cov in (("localize", True), ("localize_points", False)):
                    figures[f"{name}_instructions_{label}"] = _per_call(
                        root, frame_path, calls, with_cov
                    )
        finally:
            if against:
                subprocess.run(
                    ["git", "-C", str(_ROOT), "worktree", "remove", "--force", str(rev)],
                    check=False,
                    capture_output=True,
                )
    if against:
        for name in ("localize", "localize_points"):
            figures[f"{name}_ratio"] = (
                figures[f"{name}_instructions_now"] / figures[f"{name}_instructions_{against}"]
            )
    if not getattr(args, "json", False):
        print(f"instructions per call (valgrind callgrind, {calls} calls, start-up subtracted)")
        header = f"{'call':<18}{'now':>12}"
        if against:
            header += f"{against[:10]:>12}{'ratio':>8}"
        print(header)
        for name in ("localize", "localize_points"):
            line = f"{name:<18}{figures[f'{name}_instructions_now']:>12,.0f}"
            if against:
                line += f"{figures[f'{name}_instructions_{against}']:>12,.0f}"
                line += f"{figures[f'{name}_ratio']:>8.3f}"
            print(line)
    return figures
