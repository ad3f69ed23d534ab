"""The documents a user reads agree with the declarations they describe."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from scenarios.scenario import toml_out
from vnav.methods import CONTRACT_DOMAIN, METHODS

ROOT = Path(__file__).resolve().parents[1]


def _table_rows(text: str, heading: str) -> list[list[str]]:
    """The cells of the markdown table whose header row starts with ``heading``."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(heading))
    rows = []
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        rows.append([cell.strip() for cell in line.strip("|").split("|")])
    return rows


@pytest.mark.parametrize("path", ["README.md", "docs/ACCURACY.md"])
def test_method_tables_state_vnav_methods(path):
    rows = _table_rows((ROOT / path).read_text(), "| method | depth from | accuracy promised")
    assert [r[0] for r in rows] == [f"`{m.name}`" for m in METHODS]
    assert [r[1] for r in rows] == [m.depth_from for m in METHODS]
    assert [r[2] for r in rows] == [m.promise for m in METHODS]


def test_readme_states_the_contract_domain():
    assert f"accuracy promised ({CONTRACT_DOMAIN.text})" in (ROOT / "README.md").read_text()


def test_accuracy_page_colours_are_the_recordings():
    rows = _table_rows((ROOT / "docs/ACCURACY.md").read_text(), "| method | depth from")
    assert [r[3] for r in rows] == [m.color_name for m in METHODS]


def _readme_scenario_block() -> str:
    """The README's scenario example (the other TOML block is a sweep file, with a grid)."""
    blocks = re.findall(r"```toml\n(.*?)```", (ROOT / "README.md").read_text(), flags=re.S)
    (block,) = [b for b in blocks if "[grid]" not in b]
    return block


def test_readme_example_is_the_schemas():
    assert _readme_scenario_block() == toml_out.example_toml()


def test_readme_example_is_a_valid_scenario():
    import tomllib

    from scenarios.scenario.spec import from_dict

    spec = from_dict(tomllib.loads(_readme_scenario_block()), where="README.md")
    assert spec.name == "my-scene" and spec.flight.mode == "kinematic"


def _repository_texts() -> list[Path]:
    skip = {".git", ".venv", "recordings", "sweeps", "node_modules"}
    return [
        p
        for p in ROOT.rglob("*")
        if p.suffix in {".py", ".md", ".sh", ".toml", ".yaml"}
        and p.is_file()
        and not skip & set(p.relative_to(ROOT).parts)
    ]


def test_no_text_cites_an_issue_or_a_path_outside_the_repository():
    """The lecture is cited by its name (MIT 16.485 VNAV, lecture 1); issues and the folders
    beside the repository are not there for a reader of it."""
    outside = re.compile(r"\.\./shared|shared[/]seed")
    issue = re.compile(r"\bthe issue\b|\bissue's\b|\bissue #?\d+", re.IGNORECASE)
    found = [
        f"{p.relative_to(ROOT)}:{n}: {line.strip()}"
        for p in _repository_texts()
        for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
        if outside.search(line) or issue.search(line)
    ]
    assert not found, found


def test_the_layer_table_lists_every_scenarios_sub_package_and_module():
    """docs/CONVENTIONS.md's layer table names each sub-package's modules, as on disk."""
    rows = _table_rows((ROOT / "docs/CONVENTIONS.md").read_text(), "| layer | purpose |")
    listed = {}
    for layer, _, modules, _ in rows:
        name = layer.strip("`").rstrip("/")
        listed[name] = sorted(re.findall(r"`(\w+)`", modules))
    packages = sorted(
        p.name for p in (ROOT / "scenarios").iterdir() if (p / "__init__.py").is_file()
    )
    for package in packages:
        assert package in listed, f"scenarios/{package}/ is missing from the layer table"
        on_disk = sorted(
            p.stem for p in (ROOT / "scenarios" / package).glob("*.py") if p.stem != "__init__"
        )
        assert set(on_disk) <= set(listed[package]), (package, on_disk, listed[package])


def test_the_calibration_mount_error_is_stated_as_its_true_angle():
    """The calibration built-in's mount error, stated in its description (what ``vnav-demo
    list`` prints) and in the README, is the angle of its rotation (SciPy, from the scenario's
    ``rpy_deg``, ``R = Rz(yaw) Ry(pitch) Rx(roll)``) and the length of its translation, at the
    rounding stated: not the largest angle, nor a rounded-up figure."""
    from scipy.spatial.transform import Rotation

    from scenarios.scenario import builtin

    error = builtin.REGISTRY["calibration"]()["camera"]["mount_error"]
    roll, pitch, yaw = error["rpy_deg"]
    angle_deg = float(
        np.degrees(Rotation.from_euler("ZYX", [yaw, pitch, roll], degrees=True).magnitude())
    )
    offset_mm = 1e3 * float(np.linalg.norm(error["position_m"]))
    readme = (ROOT / "README.md").read_text()
    description = builtin.REGISTRY["calibration"]()["description"]
    for where, text in (("README.md", " ".join(readme.split())), ("description", description)):
        stated = re.search(r"mounted (\d+\.(\d+)) deg and (\d+) mm off", text)
        assert stated, where
        assert stated[1] == f"{angle_deg:.{len(stated[2])}f}", where
        assert stated[3] == f"{offset_mm:.0f}", where
