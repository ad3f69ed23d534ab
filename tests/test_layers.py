"""The layering reads from the imports: evaluating, judging and reporting a run need neither
MuJoCo nor Rerun, the simulator loop needs no Rerun, and vnav needs neither."""

from __future__ import annotations

import subprocess
import sys

import pytest


@pytest.mark.parametrize(
    ("module", "absent"),
    [
        ("vnav.localize", ("mujoco", "rerun")),
        ("vnav.methods", ("mujoco", "rerun", "cv2")),
        ("scenarios.records", ("mujoco", "rerun")),
        ("scenarios.evaluate", ("mujoco", "rerun")),
        ("scenarios.checks", ("mujoco", "rerun")),
        ("scenarios.report", ("mujoco", "rerun")),
        ("scenarios.spec", ("mujoco", "rerun")),
        ("scenarios.runner", ("rerun",)),
        ("sim.mesh", ("rerun",)),
        ("scenarios.panel", ("mujoco", "rerun")),
        ("scenarios.plots", ("mujoco", "rerun", "matplotlib")),
        ("scenarios.viewer", ("mujoco",)),
        # A sweep's plan, tables, summary and plots need no simulator; the command loads Ray
        # only when it runs, so that without it the command can say how to install it.
        ("scenarios.sweep.plan", ("mujoco", "rerun", "ray", "pyarrow")),
        ("scenarios.sweep.store", ("mujoco", "rerun", "ray")),
        ("scenarios.sweep.summary", ("mujoco", "rerun", "ray", "pyarrow")),
        ("scenarios.sweep.plots", ("mujoco", "rerun", "ray", "pyarrow")),
        ("scenarios.sweep.command", ("ray",)),
    ],
)
def test_module_does_not_load(module, absent):
    code = f"import sys, {module}; print(','.join(m for m in {absent!r} if m in sys.modules))"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.strip()
    assert out == "", f"{module} loads {out}"
