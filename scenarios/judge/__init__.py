"""Judging a finished run: the checks' figures against their limits (``checks``), the camera
calibration recovered from a run (``calibration``), the JSON report (``report``) and the TUM
trajectories evo reads (``tum``). Needs neither MuJoCo nor Rerun."""
