"""Test-wide settings.

MuJoCo renders off-screen: choose EGL before anything imports mujoco (sim.gl does the same
when MUJOCO_GL is unset and there is no display). Under CI (CI=true) Hypothesis runs
derandomized, so a CI run is repeatable; locally it explores new examples each run.
"""

import os

from hypothesis import settings

os.environ.setdefault("MUJOCO_GL", "egl")

settings.register_profile("ci", derandomize=True, deadline=None)
if os.environ.get("CI"):
    settings.load_profile("ci")
