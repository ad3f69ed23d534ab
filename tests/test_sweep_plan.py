"""scenarios.sweep.plan: sweep files expanded into grid points the scenario parser accepts."""

from __future__ import annotations

import dataclasses
import datetime as dt
import hashlib
import itertools
import json
import tomllib
from pathlib import Path

import pytest

from scenarios.scenario import builtin, spec, toml_out
from scenarios.sweep.plan import SweepError, draws_from_seed, load, plan
from vnav.methods import METHOD_NAMES


def test_grid_is_the_full_product_in_row_major_order():
    grid = {"camera.pitch_down_deg": [10.0, 30.0, 50.0], "noise.attitude_std_deg": [0.0, 0.5]}
    p = plan({"scenario": "approach", "seeds": 4, "grid": grid}, "s.toml")
    assert p.seeds == (1, 2, 3, 4)
    assert [tuple(pt.values.values()) for pt in p.points] == list(itertools.product(*grid.values()))
    assert p.episodes == [(i, s) for i in range(6) for s in (1, 2, 3, 4)]
    for pt in p.points:
        assert pt.spec.scene.camera.pitch_down_deg == pt.values["camera.pitch_down_deg"]
        assert pt.spec.noise.attitude_std_deg == pt.values["noise.attitude_std_deg"]
        assert pt.spec.name == f"approach-p{pt.index}"


def test_point_files_parse_back_to_the_same_scenario_exactly():
    """Floats in full: a value the sweep's rounding would change (toml_out's 6 digits)."""
    value = 33.690067525979785
    p = plan({"scenario": "orbit", "grid": {"camera.pitch_down_deg": [value]}}, "s.toml")
    (pt,) = p.points
    assert spec.from_dict(tomllib.loads(pt.scenario_toml)) == pt.spec
    assert pt.spec.scene.camera.pitch_down_deg == value
    base = {**builtin.REGISTRY["orbit"](), "name": pt.spec.name}
    base["camera"] = {**base["camera"], "pitch_down_deg": value}
    assert pt.spec == spec.from_dict(base)
    rounded = spec.from_dict(tomllib.loads(toml_out.dumps(base)))
    assert rounded.scene.camera.pitch_down_deg != value  # why exact=True is needed


def test_list_index_and_missing_tables():
    grid = {"flight.waypoints.2.position_w": [[-6.0, 0.0, 3.0]], "timing.image_latency_s": [0.05]}
    (pt,) = plan({"scenario": "approach", "grid": grid}, "s.toml").points
    assert pt.spec.flight.waypoints[2].position_w == (-6.0, 0.0, 3.0)
    assert pt.spec.timing.image_latency_s == 0.05


def test_seed_list_and_rank_by():
    p = plan({"scenario": "approach", "seeds": [7, 3], "rank_by": "ground_plane"}, "s.toml")
    assert p.seeds == (7, 3) and p.rank_by == "ground_plane" and len(p.points) == 1


def test_fingerprint_changes_with_what_runs():
    a = plan({"scenario": "approach", "seeds": 2}, "s.toml")
    assert a.fingerprint == plan({"scenario": "approach", "seeds": 2}, "t.toml").fingerprint
    assert a.fingerprint != plan({"scenario": "approach", "seeds": 3}, "s.toml").fingerprint
    grid = {"camera.pitch_down_deg": [20.0]}
    assert (
        a.fingerprint != plan({"scenario": "approach", "seeds": 2, "grid": grid}, "s").fingerprint
    )


def test_scenario_file_relative_to_the_sweep_file(tmp_path):
    scenario = {**builtin.REGISTRY["frame-problem"](), "name": "mine"}
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "mine.toml").write_text(toml_out.dumps(scenario))
    (tmp_path / "sweep.toml").write_text('scenario = "sub/mine.toml"\nseeds = 2\n')
    p = load(tmp_path / "sweep.toml")
    assert p.points[0].spec == dataclasses.replace(
        spec.load_toml(tmp_path / "sub" / "mine.toml"), name="mine-p0"
    )


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"seeds": 2}, "scenario: required"),
        ({"scenario": "nope"}, "unknown built-in 'nope'"),
        ({"scenario": "approach", "seed": 2}, "seed: unknown key"),
        ({"scenario": "approach", "seeds": 0}, "seeds: must be in"),
        ({"scenario": "approach", "seeds": [1, 1]}, "distinct"),
        ({"scenario": "approach", "seeds": True}, "seeds"),
        ({"scenario": "approach", "rank_by": "best"}, "rank_by: must be one of"),
        ({"scenario": "approach", "grid": {"camera.pitch_down_deg": []}}, "non-empty list"),
        ({"scenario": "approach", "grid": {"name": ["x"]}}, "names each grid point"),
        (
            {"scenario": "approach", "grid": {"camera.pitch_down_deg": [10.0, 95.0]}},
            "grid point 1 (camera.pitch_down_deg = 95.0): camera: CameraConfig.pitch_down_deg must",
        ),
        (
            {"scenario": "approach", "grid": {"camera.tilt_deg": [1.0]}},
            "grid point 0 (camera.tilt_deg = 1.0): camera.tilt_deg: unknown key",
        ),
        (
            {"scenario": "uncertainty", "grid": {"noise.pixel_std_px": [8.0]}},
            "grid point 0 (noise.pixel_std_px = 8.0): noise.pixel_std_px: renamed; write "
            "noise.intensity_std_grey",
        ),
        (
            {"scenario": "approach", "grid": {"flight.waypoints.9.t": [1.0]}},
            "flight.waypoints is a list of 3",
        ),
        (
            {"scenario": "approach", "grid": {"camera_rate_hz.x": [1.0]}},
            "camera_rate_hz is a value, not a table",
        ),
        # Digits that are not ASCII: "²" (int() refuses it) and "١" (int() takes it as 1).
        ({"scenario": "approach", "grid": {"flight.waypoints.².t": [1.0]}}, "list of 3; index"),
        ({"scenario": "approach", "grid": {"flight.waypoints.١.t": [1.0]}}, "list of 3; index"),
        ({"scenario": "approach", "grid": {"camera..pitch_down_deg": [1.0]}}, "an empty part"),
        (
            {
                "scenario": "approach",
                "grid": {"noise": [{"attitude_std_deg": dt.date(2024, 1, 2)}]},
            },
            "grid.noise[0].attitude_std_deg: a TOML date is not a scenario value, got 2024-01-02",
        ),
        (
            {"scenario": "approach", "grid": {"flight.mode": [["orbit"]]}},
            'grid point 0 (flight.mode = ["orbit"]): flight.mode: must be',
        ),
        (
            {"scenario": "approach", "grid": {"checks.0.kind": [{"a": 1}]}},
            "checks[0].kind: must be one of ['max_error'",
        ),
    ],
)
def test_bad_sweeps_are_refused_naming_the_key(data, message):
    with pytest.raises(SweepError) as info:
        plan(data, "s.toml")
    assert message in str(info.value)
    assert str(info.value).startswith("s.toml: ")
    assert "\n" not in str(info.value)


def test_missing_sweep_file(tmp_path):
    with pytest.raises(SweepError, match="no such sweep file"):
        load(tmp_path / "none.toml")


def test_a_grid_of_more_points_than_plan_in_seconds_is_refused_before_planning(monkeypatch):
    """A 1,000 x 1,000 grid (one seed: the episode limit) is refused at once, naming the limit,
    before a single point is planned (each takes milliseconds: a million take an hour)."""
    from scenarios.sweep import plan as plan_module

    def planned(*args):
        raise AssertionError("a grid point was planned")

    monkeypatch.setattr(plan_module, "_point", planned)
    grid = {
        "camera.pitch_down_deg": [10.0 + 0.01 * i for i in range(1000)],
        "noise.attitude_std_deg": [0.001 * i for i in range(1000)],
    }
    with pytest.raises(SweepError) as info:
        plan({"scenario": "approach", "grid": grid}, "s.toml")
    message = str(info.value)
    assert f"1000000 grid points is more than {plan_module.MAX_POINTS}" in message
    assert "\n" not in message
    one_over = {
        "camera.pitch_down_deg": [10.0 + 0.01 * i for i in range(plan_module.MAX_POINTS + 1)]
    }
    with pytest.raises(SweepError, match="grid points is more than"):
        plan({"scenario": "approach", "grid": one_over}, "s.toml")


# ------------------------------------------------------------------ a user's estimator
REFERENCE = """\
import numpy as np


def ref(obs):
    return (obs.T_w_b @ obs.T_b_c @ np.append(obs.p_c, 1.0))[:3]


def _private(obs):
    return None


NOT_CALLABLE = 3
"""


def test_an_estimator_file_is_found_beside_the_sweep_file(tmp_path, monkeypatch):
    """``estimator`` paths are relative to the sweep file, as its scenario file is, whatever
    the current directory: imported once, made absolute for workers, kept as the command's
    directory reaches it for the replay command, hashed from the file's bytes."""
    (tmp_path / "sweeps" / "est").mkdir(parents=True)
    source = tmp_path / "sweeps" / "est" / "mine.py"
    source.write_text(REFERENCE)
    (tmp_path / "sweeps" / "s.toml").write_text(
        'scenario = "approach"\nestimator = ["est/mine.py:ref", "vnav.plugin:reference_estimate"]\n'
    )
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    p = load("../sweeps/s.toml")
    mine, module = p.estimators
    assert mine.spec == "est/mine.py:ref"
    assert mine.shown == "../sweeps/est/mine.py:ref"
    assert mine.absolute == f"{source.resolve()}:ref"
    assert mine.sha256 == hashlib.sha256(source.read_bytes()).hexdigest()
    import vnav.plugin

    assert module.absolute == module.shown == module.spec == "vnav.plugin:reference_estimate"
    assert module.sha256 == hashlib.sha256(Path(vnav.plugin.__file__).read_bytes()).hexdigest()
    assert [m.name for m in p.user_methods] == ["user:ref", "user:reference_estimate"]
    assert [m.name for m in p.methods] == [*METHOD_NAMES, "user:ref", "user:reference_estimate"]
    # A worker imports it again itself, from the absolute path, wherever it runs.
    monkeypatch.chdir(tmp_path)
    assert mine.load().estimator.fn.__name__ == "ref"


def test_fingerprint_holds_the_estimators_and_their_files(tmp_path):
    """A sweep without an estimator keeps the fingerprint it always had (its scenarios and
    seeds); with one, the fingerprint changes with its spec and with its file's bytes."""
    (tmp_path / "mine.py").write_text(REFERENCE)
    base = {"scenario": "approach", "seeds": 2}
    plain = plan(base, "s.toml", base_dir=tmp_path)
    text = json.dumps([[pt.scenario_toml for pt in plain.points], [1, 2]])
    assert plain.fingerprint == hashlib.sha256(text.encode()).hexdigest()[:16]
    with_ref = plan({**base, "estimator": "mine.py:ref"}, "s.toml", base_dir=tmp_path)
    assert with_ref.fingerprint != plain.fingerprint
    as_list = plan({**base, "estimator": ["mine.py:ref"]}, "s.toml", base_dir=tmp_path)
    assert as_list.fingerprint == with_ref.fingerprint
    (tmp_path / "mine.py").write_text(REFERENCE + "\n# changed\n")
    changed = plan({**base, "estimator": "mine.py:ref"}, "s.toml", base_dir=tmp_path)
    assert changed.fingerprint not in (with_ref.fingerprint, plain.fingerprint)


def test_a_worker_refuses_an_estimator_file_changed_since_the_sweep_started(tmp_path):
    (tmp_path / "mine.py").write_text(REFERENCE)
    p = plan({"scenario": "approach", "estimator": "mine.py:ref"}, "s.toml", base_dir=tmp_path)
    (source,) = p.estimators
    assert source.load().name == "user:ref"
    (tmp_path / "mine.py").write_text(REFERENCE.replace("[:3]", "[:3] * 2.0"))
    with pytest.raises(ValueError, match=r"estimator mine.py:ref: its file changed since"):
        source.load()


@pytest.mark.parametrize(
    ("estimator", "message"),
    [
        ("absent.py:ref", "absent.py does not import: no such file"),
        ("mine.py:nothing", "has no attribute 'nothing'"),
        ("mine.py:NOT_CALLABLE", "is not callable"),
        ("mine.py", "expected package.module:function"),
        ("no_such_module_here:f", "does not import"),
        ("mine.py:_private", "user:_private: no plain column name"),
        (["mine.py:ref", "mine.py:ref"], "is user:ref, as another one is"),
        (3, "estimator: must be a spec"),
        ([3], "estimator: must be a spec"),
    ],
)
def test_a_bad_estimator_is_refused_naming_the_key(tmp_path, estimator, message):
    (tmp_path / "mine.py").write_text(REFERENCE)
    with pytest.raises(SweepError) as info:
        plan({"scenario": "approach", "estimator": estimator}, "s.toml", base_dir=tmp_path)
    assert str(info.value).startswith("s.toml: estimator: ")
    assert message in str(info.value) and "\n" not in str(info.value)


def test_rank_by_may_name_a_users_function(tmp_path):
    (tmp_path / "mine.py").write_text(REFERENCE)
    data = {"scenario": "approach", "estimator": "mine.py:ref", "rank_by": "user:ref"}
    assert plan(data, "s.toml", base_dir=tmp_path).rank_by == "user:ref"


def test_a_grid_over_imu_keys_sets_the_scenes_imu():
    """``imu.*`` keys sweep as any other: each point's IMU has its values, the rest of the
    built-in's ``[imu]`` (mount, its error, the clock offset) as declared; a point whose IMU
    draws noise draws from its seed, one with a perfect IMU (and no other noise) does not."""
    grid = {"imu.rate_hz": [100.0, 200.0], "imu.gyroscope_noise_density": [1e-3, 0.0]}
    zero = {f"imu.{k}": [0.0] for k in builtin.IMU_NOISE if k != "gyroscope_noise_density"}
    p = plan({"scenario": "imu", "seeds": 2, "grid": {**grid, **zero}}, "s.toml")
    assert [tuple(pt.values.values())[:2] for pt in p.points] == list(
        itertools.product(*grid.values())
    )
    declared = builtin.load("imu").scene.imu
    for pt in p.points:
        imu = pt.spec.scene.imu
        assert imu.rate_hz == pt.values["imu.rate_hz"]
        assert imu.gyroscope_noise_density == pt.values["imu.gyroscope_noise_density"]
        assert imu.accelerometer_noise_density == 0.0
        assert (imu.T_b_i == declared.T_b_i).all() and imu.time_offset_s == declared.time_offset_s
        assert draws_from_seed(pt.spec) == (imu.gyroscope_noise_density > 0.0)


def test_a_grid_can_give_a_scenario_an_imu_and_bad_values_name_the_point():
    """``imu.*`` on a built-in without ``[imu]`` makes the table (a controlled flight carries
    it); on a kinematic flight, or above the physics rate, the point is refused by name."""
    (pt,) = plan({"scenario": "approach", "grid": {"imu.rate_hz": [50.0]}}, "s.toml").points
    assert pt.spec.scene.imu.rate_hz == 50.0 and pt.spec.scene.imu.noise.is_zero
    assert "[imu]" in pt.scenario_toml
    with pytest.raises(SweepError, match=r"grid point 0 \(imu.rate_hz = 50.0\).*needs a flight"):
        plan({"scenario": "yaw-sweep", "grid": {"imu.rate_hz": [50.0]}}, "s.toml")
    with pytest.raises(SweepError, match=r"grid point 1 .*imu.rate_hz: must be at most the phys"):
        plan({"scenario": "imu", "grid": {"imu.rate_hz": [200.0, 400.0]}}, "s.toml")
