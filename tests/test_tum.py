"""``vnav-demo run --export tum``: camera trajectories in the TUM format evo reads, checked
against the recording written beside them (the simulator's truth, read back)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from helpers import read_rows

from scenarios.cli import main
from vnav import quat, so3


def _read_tum(path) -> np.ndarray:
    """(N, 8): ``t x y z qx qy qz qw`` per line."""
    rows = [list(map(float, line.split())) for line in path.read_text().splitlines()]
    assert all(len(r) == 8 for r in rows)
    return np.array(rows).reshape(-1, 8)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    out = tmp_path_factory.mktemp("tum")
    status = main(
        ["run", "calibration", "--duration", "3", "--export", "tum", "--out", str(out), "--quiet"]
    )
    assert status in (0, 1)  # 3 s is short for the calibration checks; the files are the point
    return out


def test_truth_trajectory_is_the_recorded_camera(exported):
    """One line per camera tick; each pose is ``T_w_b`` (``world/body``, every tick) times the
    true mount (``world/body/camera``, static) as the recording holds them (float32)."""
    truth = _read_tum(exported / "calibration.truth.tum")
    report = json.loads((exported / "calibration.json").read_text())
    assert len(truth) == report["camera_ticks"]
    rrd = exported / "calibration.rrd"
    body = [r for r in read_rows(rrd, "world/body") if "tick" in r]
    mount = next(r for r in read_rows(rrd, "world/body/camera") if r.get("Transform3D:translation"))
    R_b_c = quat.to_matrix(np.array(mount["Transform3D:quaternion"][0]), normalize=True)
    t_b_c = np.array(mount["Transform3D:translation"][0])
    for line, row in zip(truth, body, strict=True):
        R_w_b = quat.to_matrix(np.array(row["Transform3D:quaternion"][0]), normalize=True)
        t_w_b = np.array(row["Transform3D:translation"][0])
        np.testing.assert_allclose(line[1:4], t_w_b + R_w_b @ t_b_c, atol=1e-5)
        R = quat.to_matrix(line[4:], normalize=True)
        assert np.linalg.norm(line[4:]) == pytest.approx(1.0, abs=1e-8)
        assert (
            math.degrees(np.linalg.norm(so3.log(so3.nearest_rotation(R.T @ R_w_b @ R_b_c)))) < 1e-3
        )
    assert np.all(np.diff(truth[:, 0]) > 0)


def test_pnp_trajectory_follows_the_truth(exported):
    """PnP on the cones, where 4 or more are seen whole: within 1 deg and 10 cm of the true
    camera pose of the same stamp (apexes 0.3-0.5 px off, cones 7-14 m away, all apexes at one
    height: a plane seen at a slant)."""
    truth = {round(r[0], 6): r for r in _read_tum(exported / "calibration.truth.tum")}
    pnp = _read_tum(exported / "calibration.pnp.tum")
    assert len(pnp) >= 0.8 * len(truth)
    for line in pnp:
        t = truth[round(line[0], 6)]
        assert np.linalg.norm(line[1:4] - t[1:4]) < 0.1
        R_err = quat.to_matrix(line[4:], normalize=True).T @ quat.to_matrix(t[4:], normalize=True)
        assert math.degrees(np.linalg.norm(so3.log(so3.nearest_rotation(R_err)))) < 1.0
