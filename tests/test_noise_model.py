"""``vnav.noise_model``: the noise figures declared once. The scenario file's ``[noise]`` keys
are derived from the declaration, a key of an earlier version is refused with its new name, and
a run hands the one ``NoiseModel`` to the simulator and to the estimator alike."""

from __future__ import annotations

import dataclasses
import math

import pytest

from scenarios import pipeline
from scenarios.cli import main
from scenarios.judge import report
from scenarios.run import runner
from scenarios.scenario import builtin, schema, toml_out
from scenarios.scenario.spec import ScenarioError, from_dict
from vnav.noise_model import FIGURES, NOISELESS, SENSORS, Figure, NoiseModel


def test_noise_keys_are_the_declarations_fields_with_its_defaults_ranges_and_docs() -> None:
    fields = dataclasses.fields(NoiseModel)
    assert [k.name for k in schema.NOISE] == [f.name for f in fields] == list(FIGURES)
    for key, f in zip(schema.NOISE, fields, strict=True):
        figure = f.metadata["figure"]
        assert isinstance(figure, Figure) and figure is FIGURES[f.name]
        assert key.kind == "number"
        assert key.default == f.default == getattr(NOISELESS, f.name)
        assert (key.lo, key.hi, key.lo_open) == (figure.lo, figure.hi, False)
        assert key.doc == figure.line and key.doc.endswith(f", {figure.unit}")
        assert schema.comment(f"noise.{f.name}") == figure.line
        assert figure.sensor in SENSORS


def test_every_sensor_has_a_figure_and_every_name_says_its_unit() -> None:
    assert {f.sensor for f in FIGURES.values()} == set(SENSORS)
    suffixes = {"m": "_m", "deg": "_deg", "1/m": "_per_m2", "8-bit grey levels": "_grey"}
    for name, figure in FIGURES.items():
        assert name.endswith(suffixes[figure.unit]), name


@pytest.mark.parametrize("name", list(FIGURES))
def test_model_and_schema_accept_and_refuse_the_same_range(name: str) -> None:
    """The declared range, inclusive, is what both the dataclass and the file's key accept."""
    figure = FIGURES[name]
    for value in (figure.lo, figure.hi):
        assert getattr(NoiseModel(**{name: value}), name) == value
        assert schema.read({name: value}, schema.NOISE, "noise")[name] == value
    for value in (figure.lo - 1e-9, figure.hi * (1 + 1e-9)):
        with pytest.raises(ValueError, match=rf"NoiseModel\.{name} must be in"):
            NoiseModel(**{name: value})
        with pytest.raises(schema.SchemaError, match=rf"noise\.{name}: must be"):
            schema.read({name: value}, schema.NOISE, "noise")


def test_model_stores_floats_and_refuses_what_is_not_a_number() -> None:
    assert type(NoiseModel(intensity_std_grey=4).intensity_std_grey) is float
    for bad in (True, "1", None, math.inf, 10**400):
        with pytest.raises(ValueError, match=r"NoiseModel\.depth_std_m must be"):
            NoiseModel(depth_std_m=bad)


def test_noisy_says_which_sensors_carry_noise() -> None:
    noise = NoiseModel(attitude_std_deg=1.0, depth_std_per_m2=0.001)
    assert [s for s in SENSORS if noise.noisy(s)] == ["pose", "depth"]
    assert not any(NOISELESS.noisy(s) for s in SENSORS)
    with pytest.raises(ValueError, match="sensor must be one of"):
        noise.noisy("imu")


def test_degrees_convert_once() -> None:
    noise = NoiseModel(attitude_std_deg=1.0, extrinsic_std_deg=2.0)
    assert noise.attitude_std_rad == math.radians(1.0)
    assert noise.extrinsic_std_rad == math.radians(2.0)


def test_docstring_lists_every_figure() -> None:
    doc = NoiseModel.__doc__ or ""
    for name, figure in FIGURES.items():
        assert f"{name} : float" in doc and figure.doc in doc


# ------------------------------------------------------------------ the scenario file


def _scenario(noise: dict) -> dict:
    return {
        "name": "t",
        "cones": [{"position_w": [5.0, 0.0, 0.0]}],
        "flight": {
            "mode": "kinematic",
            "keyframes": [{"t": 0.0, "position_w": [0.0, 0.0, 3.0], "rpy_deg": [0.0, 0.0, 0.0]}],
        },
        "noise": noise,
    }


def test_the_scenario_holds_the_declaration() -> None:
    spec = from_dict(_scenario({"intensity_std_grey": 4.0, "attitude_std_deg": 1}))
    assert spec.noise == NoiseModel(intensity_std_grey=4.0, attitude_std_deg=1.0)
    assert from_dict(_scenario({})).noise == NOISELESS


def test_the_old_image_noise_key_is_refused_naming_the_new_one() -> None:
    with pytest.raises(ScenarioError) as info:
        from_dict(_scenario({"pixel_std_px": 4.0}), where="old.toml")
    message = str(info.value)
    assert message == (
        "old.toml: noise.pixel_std_px: renamed; write noise.intensity_std_grey "
        "(the same figure: 8-bit grey levels, not pixels)"
    )


def test_the_old_key_is_refused_even_beside_the_new_one() -> None:
    with pytest.raises(ScenarioError, match=r"renamed; write noise\.intensity_std_grey"):
        from_dict(_scenario({"pixel_std_px": 4.0, "intensity_std_grey": 4.0}))


def test_show_writes_the_new_key_with_its_unit(capsys) -> None:
    """``vnav-demo show uncertainty``: the image noise under its new name and unit."""
    assert main(["show", "uncertainty"]) == 0
    lines = capsys.readouterr().out.splitlines()
    line = "intensity_std_grey = 4.0  # noise on each image colour value, 8-bit grey levels"
    assert line in lines
    assert not any("pixel_std" in x for x in lines)


def test_readme_example_writes_every_figure_with_its_unit() -> None:
    text = toml_out.example_toml()
    for name, figure in FIGURES.items():
        assert f"{name} = 0.0  # {figure.line}" in text.splitlines()


# ------------------------------------------------------- one object for both sides of a run


def test_a_run_hands_the_same_model_to_the_simulator_and_the_estimator(monkeypatch) -> None:
    """Every noise draw of the simulator (``sim.noise``, as the runner calls it) and every
    estimate's covariance (the run's ``vnav.localize.Localizer``; the pose and mount
    covariances from ``vnav.sensor_noise``) receive the scenario's ``NoiseModel``
    itself, not a translation of it."""
    spec = dataclasses.replace(
        builtin.load("uncertainty"),
        duration_s=0.25,
        noise=NoiseModel(
            position_std_m=0.05,
            attitude_std_deg=1.0,
            intensity_std_grey=4.0,
            depth_std_m=0.005,
            depth_std_per_m2=0.0002,
            extrinsic_std_m=0.01,
            extrinsic_std_deg=0.5,
        ),
    )
    seen: dict[str, list[object]] = {}

    def spy(name: str, position: int) -> None:
        original = getattr(runner, name)

        def wrapped(*args, **kwargs):
            noise = kwargs["noise"] if "noise" in kwargs else args[position]
            seen.setdefault(name, []).append(noise)
            return original(*args, **kwargs)

        monkeypatch.setattr(runner, name, wrapped)

    spy("noisy_pose", 1)
    spy("noisy_rgb", 1)
    spy("noisy_depth", 1)
    spy("mount_error", 0)
    spy("mount_covariance", 0)
    spy("body_pose_covariance", 1)
    spy("Localizer", -1)  # keyword only: the estimator, told the noise once per run
    outcome = pipeline.run(spec, seed=3)
    assert set(seen) == {
        "noisy_pose",
        "noisy_rgb",
        "noisy_depth",
        "mount_error",
        "mount_covariance",
        "body_pose_covariance",
        "Localizer",
    }
    assert all(noise is spec.noise for calls in seen.values() for noise in calls)
    assert any(t.detections for t in outcome.result.ticks)
    # The report writes the declaration's fields, values as declared.
    assert outcome.report["report_version"] == report.REPORT_VERSION
    assert outcome.report["noise"] == dataclasses.asdict(spec.noise)
    assert list(outcome.report["noise"]) == list(FIGURES)
