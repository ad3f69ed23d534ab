"""``python -m benchmarks pipeline --imu``: a scenario with the ``imu`` built-in's ``[imu]`` and
without, side by side, per camera tick, and the ratio against the target."""

from __future__ import annotations

import dataclasses
import re

import pytest

from benchmarks import pipeline
from benchmarks.__main__ import main
from scenarios.scenario import builtin


def test_the_two_sides_differ_by_the_imu_builtins_imu_table_alone():
    specs = pipeline._imu_specs("orbit", 0.6)
    assert specs["plain"].scene.imu is None
    assert specs["imu"].scene.imu == builtin.load("imu").scene.imu
    assert specs["imu"].end_s == specs["plain"].end_s == pytest.approx(0.6)
    with_imu = dataclasses.replace(
        specs["imu"], scene=dataclasses.replace(specs["imu"].scene, imu=None)
    )
    assert with_imu == specs["plain"]


def test_a_tiny_flight_prints_each_stage_and_the_ratio_line(capsys):
    assert main(["pipeline", "--imu", "--duration", "0.6", "--rounds", "1"]) == 0
    out = capsys.readouterr().out
    for stage in ("physics", "render", "detect", "localize", "log"):
        assert re.search(rf"^  {stage} +[\d.]+ +[\d.]+ +[-+][\d.]+$", out, re.M), stage
    cpu = re.search(r"^  tick, CPU +([\d.]+) +([\d.]+)$", out, re.M)
    ratio = re.search(
        r"^ratio with / without, a tick's CPU: ([\d.]+) \(target <= 1\.05\)", out, re.M
    )
    assert cpu and ratio, out
    # The ratio is that of the two ticks' CPU printed above it (to their printed digits).
    without_ms, with_ms = float(cpu[1]), float(cpu[2])
    assert float(ratio[1]) == pytest.approx(with_ms / without_ms, abs=2e-3 + 0.01 / without_ms)
    assert "where the IMU's time goes" in out and "imu_consistent" in out


def test_a_scenario_with_its_own_imu_is_refused_on_one_line(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["pipeline", "--imu", "--scenario", "imu"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "has an [imu] already" in err
