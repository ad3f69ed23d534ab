"""Scenario specifications: TOML keys, units and the start pose they imply."""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib

import numpy as np
import pytest

from scenarios.cli import main
from scenarios.scenario import builtin, schema
from scenarios.scenario.check_kinds import KINDS
from scenarios.scenario.spec import OrbitFlight, ScenarioError, from_dict, load_toml
from vnav import quat, so3


def _base(**flight) -> dict:
    return {"name": "t", "cones": [{"position_w": [0.0, 0.0, 0.0]}], "flight": flight}


def test_rpy_deg_keyframe_becomes_the_lecture_rotation():
    spec = from_dict(
        _base(
            mode="kinematic",
            keyframes=[
                {"t": 0.0, "position_w": [1.0, 2.0, 3.0], "rpy_deg": [10.0, 90.0, -30.0]},
            ],
        )
    )
    R = quat.to_matrix(spec.flight.keyframes[0].quat_xyzw)
    # R = Rz(yaw) Ry(pitch) Rx(roll), built independently from the elementary rotations.
    expected = so3.rot_z(math.radians(-30)) @ so3.rot_y(math.pi / 2) @ so3.rot_x(math.radians(10))
    assert np.allclose(R, expected, atol=1e-12)
    assert spec.scene.start_position_w == (1.0, 2.0, 3.0)


def test_orbit_mode_start_pose_and_duration():
    spec = from_dict(
        _base(
            mode="orbit",
            center_w=[2.0, 1.0, 0.0],
            radius_m=5.0,
            height_m=3.0,
            period_s=-10.0,
            turns=2.0,
            start_angle_deg=90.0,
            ramp_s=2.0,
        )
    )
    assert isinstance(spec.flight, OrbitFlight)
    assert np.allclose(spec.scene.start_position_w, [2.0, 6.0, 3.0])
    # Heading at the centre from the +y side: yaw = -90 deg.
    R = quat.to_matrix(spec.scene.start_quat_xyzw)
    assert np.allclose(R[:, 0], [0.0, -1.0, 0.0], atol=1e-12)
    assert spec.end_s == pytest.approx(1.0 + 2 * 10.0)


@pytest.mark.parametrize(
    ("flight", "message"),
    [
        (
            {"mode": "orbit", "radius_m": 5.0, "height_m": 3.0, "period_s": 10.0},
            r"flight\.center_w: missing",
        ),
        (
            {
                "mode": "orbit",
                "center_w": [0, 0, 0],
                "radius_m": -1.0,
                "height_m": 3.0,
                "period_s": 10.0,
            },
            r"flight\.radius_m: must be > 0",
        ),
        (
            {
                "mode": "orbit",
                "center_w": [0, 0, 0],
                "radius_m": 5.0,
                "height_m": 3.0,
                "period_s": 0.2,
            },
            r"flight\.period_s: must be at least 1 s",
        ),
        (
            {
                "mode": "orbit",
                "center_w": [0, 0, 0],
                "radius_m": 5.0,
                "height_m": 3.0,
                "period_s": 10.0,
                "speed": 3,
            },
            r"flight\.speed: unknown key",
        ),
        ({"mode": "controlled", "waypoints": []}, r"flight\.waypoints: must be a non-empty"),
    ],
)
def test_bad_flights_name_the_key(flight, message):
    with pytest.raises(ScenarioError, match=message):
        from_dict(_base(**flight), where="f.toml")


def _close(a, b, rel: float = 1e-5) -> bool:
    """Equal, floats within ``rel`` (``vnav-demo show`` rounds to 6 significant digits)."""
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        return type(a) is type(b) and _close(dataclasses.asdict(a), dataclasses.asdict(b), rel)
    if isinstance(a, dict):
        same_keys = isinstance(b, dict) and a.keys() == b.keys()
        return same_keys and all(_close(a[k], b[k], rel) for k in a)
    if isinstance(a, list | tuple):
        return len(a) == len(b) and all(_close(x, y, rel) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float):
        return math.isclose(a, b, rel_tol=rel, abs_tol=1e-12)
    return a == b


def _holds(a, b, rel: float = 1e-5) -> bool:
    """``a`` holds every key of ``b`` (tables within tables, list by list), each value
    ``_close`` to ``b``'s."""
    if isinstance(b, dict):
        return isinstance(a, dict) and all(k in a and _holds(a[k], b[k], rel) for k in b)
    if isinstance(b, list) and b and isinstance(b[0], dict):
        return len(a) == len(b) and all(_holds(x, y, rel) for x, y in zip(a, b, strict=True))
    return _close(a, b, rel)


@pytest.mark.parametrize("name", builtin.names())
def test_show_prints_a_file_that_parses_to_the_same_scenario(tmp_path, capsys, name):
    """``vnav-demo show NAME`` output, parsed by tomllib (the independent reader) and by
    load_toml, gives the built-in's own dict (and the keys it leaves at their defaults) and
    spec back, but for its name (``my-NAME``, so running it does not overwrite the built-in's
    files) and floats rounded to 6 digits."""
    assert main(["show", name]) == 0
    text = capsys.readouterr().out
    assert all(len(line) <= 80 for line in text.splitlines())
    parsed = tomllib.loads(text)
    assert parsed["name"] == f"my-{name}" != name
    expected = {**builtin.REGISTRY[name](), "name": parsed["name"]}
    assert _holds(parsed, expected)
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    assert _close(load_toml(path), dataclasses.replace(builtin.load(name), name=f"my-{name}"))


def _keyed_lines(text: str) -> list[tuple[int, str]]:
    """(index, line) of every ``key = value`` line, outside multi-line strings and lists."""
    out, in_string = [], False
    for i, line in enumerate(text.splitlines()):
        if in_string:
            in_string = not line.endswith('"""')
            continue
        if re.match(r"^[a-z_]+ = ", line):
            out.append((i, line))
            in_string = line.endswith('"""\\')
    return out


@pytest.mark.parametrize("name", builtin.names())
def test_show_writes_every_key_of_the_schema_each_commented(capsys, name):
    """Every key of the schema (``scenarios.scenario.schema``) for the built-in, those at their
    defaults too (the file parses to the same scenario: the test above), an optional one
    without a value as a comment naming it; each check's keys that apply to its kind; the keys
    of the keyframes or waypoints named in their list's comment (or written, each commented,
    in ``[[flight.keyframes]]``). Every key written has its comment, after it or above it."""
    assert main(["show", name]) == 0
    text = capsys.readouterr().out
    parsed = tomllib.loads(text)
    commented = set(re.findall(r"^# ([a-z_]+): not set here", text, flags=re.M))

    def has_all(table: dict, keys, where: str) -> None:
        for key in keys:
            assert key.name in table or key.name in commented, f"{name}: {where}{key.name}"

    has_all(parsed, schema.TOP, "")
    has_all(parsed["camera"], schema.CAMERA, "camera.")
    has_all(parsed["camera"]["mount_error"], schema.MOUNT_ERROR, "camera.mount_error.")
    mode = parsed["flight"]["mode"]
    has_all(parsed["flight"], schema.FLIGHT_MODES[mode], "flight.")
    has_all(parsed["noise"], schema.NOISE, "noise.")
    has_all(parsed["timing"], schema.TIMING, "timing.")
    for cone in parsed["cones"]:
        assert set(cone) == {k.name for k in schema.CONE}
    for check in parsed["checks"]:
        kind = KINDS[check["kind"]]
        applies = {"kind", kind.limit_key, "name"} | ({"method"} if kind.uses_method else set())
        assert set(check) | (commented & {"name"}) >= applies, check
    entry_keys = schema.KEYFRAME if mode == "kinematic" else schema.WAYPOINT
    if mode in ("kinematic", "controlled"):  # the modes with a list of entries
        for k in entry_keys:  # in the list's comment, or written in each [[flight.keyframes]]
            assert re.search(rf"^(# .*\b{k.name}\b|{k.name} = )", text, re.M), k.name
    lines = text.splitlines()
    for i, line in _keyed_lines(text):
        assert "  # " in line or lines[i - 1].startswith("# "), line


def test_show_rounds_floats_and_explains_check_limits(capsys):
    assert main(["show", "orbit"]) == 0
    text = capsys.readouterr().out
    pitch_deg = builtin.REGISTRY["orbit"]()["camera"]["pitch_down_deg"]
    assert f"pitch_down_deg = {float(f'{pitch_deg:.6g}')!r}" in text
    assert repr(pitch_deg) not in text
    tracking = text.split('kind = "tracking_error"')[1]
    assert "method" not in tracking  # the kind does not use one
    assert "limit_m = 0.3  # at most, metres" in tracking
    assert "limit = 0.95  # at least, a fraction (0.95: 95%)" in text


def test_show_unknown_name_exit_2(capsys):
    assert main(["show", "nope"]) == 2
    assert "unknown scenario 'nope'; valid names: frame-problem" in capsys.readouterr().err
