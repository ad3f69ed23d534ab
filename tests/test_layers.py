"""The layering reads from the imports.

Across the project: ``vnav`` <- ``sim`` <- ``scenarios`` <- ``benchmarks``, nothing points back
up. Inside ``scenarios``, each sub-package has one purpose and imports only the ones below it:
the scenario format, running, judging, recording, the pipeline, sweeps, the commands, the
command line. No module imports another module's private names, and no import circle exists.
At run time: evaluating, judging and reporting a run need neither MuJoCo nor Rerun, the
simulator loop needs no Rerun, and vnav needs neither.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

PROJECT_LAYERS = ("vnav", "sim", "scenarios", "benchmarks")
"""Top-level packages, lowest first: each may import only itself and those before it."""

SCENARIOS_LAYERS = (
    "scenarios.scenario",
    "scenarios.run",
    "scenarios.judge",
    "scenarios.record",
    "scenarios.export",
    "scenarios.pipeline",
    "scenarios.grading",
    "scenarios.sweep",
    "scenarios.commands",
    "scenarios.cli",
    "scenarios.__main__",
)
"""``scenarios``' sub-packages and top modules, lowest first (docs/CONVENTIONS.md, Layers)."""


def _modules() -> dict[str, Path]:
    found = {}
    for top in PROJECT_LAYERS:
        for path in sorted((ROOT / top).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            found[name] = path
    return found


MODULES = _modules()


def _imports(path: Path) -> list[tuple[str, list[str], int]]:
    """``(module, imported names, line)`` of every import in the file, at any depth (an import
    inside a function is still a dependency)."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out += [(a.name, [], node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.append((node.module, [a.name for a in node.names], node.lineno))
    return out


def _project_deps(name: str) -> list[tuple[str, int]]:
    """The project modules ``name`` imports (``from pkg import module`` names the module)."""
    deps = []
    for module, names, line in _imports(MODULES[name]):
        if module.split(".")[0] not in PROJECT_LAYERS:
            continue
        subs = [f"{module}.{n}" for n in names if f"{module}.{n}" in MODULES]
        deps += [(d, line) for d in subs] or [(module, line)]
    return deps


def _layer(name: str, layers: tuple[str, ...]) -> int | None:
    return next((i for i, p in enumerate(layers) if name == p or name.startswith(p + ".")), None)


def test_the_layer_tables_name_every_package_and_sub_package():
    for name in MODULES:
        assert _layer(name, PROJECT_LAYERS) is not None, name
        if name.startswith("scenarios.") and name.count(".") >= 1:
            assert _layer(name, SCENARIOS_LAYERS) is not None, f"{name} is in no layer"


@pytest.mark.parametrize("name", sorted(MODULES))
def test_imports_point_down(name):
    bad = []
    for dep, line in _project_deps(name):
        if _layer(dep, PROJECT_LAYERS) > _layer(name, PROJECT_LAYERS):
            bad.append(f"line {line}: {dep}")
        mine, theirs = _layer(name, SCENARIOS_LAYERS), _layer(dep, SCENARIOS_LAYERS)
        if mine is not None and theirs is not None and theirs > mine:
            bad.append(f"line {line}: {dep} (a higher layer of scenarios)")
    assert not bad, f"{name} imports upwards: {bad}"


@pytest.mark.parametrize("name", sorted(MODULES))
def test_no_module_imports_another_modules_private_names(name):
    bad = [
        f"line {line}: from {module} import {n}"
        for module, names, line in _imports(MODULES[name])
        if module.split(".")[0] in PROJECT_LAYERS
        for n in names
        if n.startswith("_") and f"{module}.{n}" not in MODULES  # a private module is shared
    ]
    assert not bad, f"{name}: {bad}"


def test_no_import_circle():
    graph = {n: {d for d, _ in _project_deps(n) if d in MODULES and d != n} for n in MODULES}
    # A package's __init__ is imported with its modules; an edge from a module to its own
    # package is no circle of code.
    for n, deps in graph.items():
        graph[n] = {d for d in deps if not n.startswith(d + ".")}
    state: dict[str, int] = {}
    path: list[str] = []

    def visit(n: str) -> None:
        state[n] = 1
        path.append(n)
        for d in sorted(graph[n]):
            assert state.get(d) != 1, "import circle: " + " -> ".join([*path[path.index(d) :], d])
            if d not in state:
                visit(d)
        path.pop()
        state[n] = 2

    for n in sorted(graph):
        if n not in state:
            visit(n)


@pytest.mark.parametrize(
    ("module", "absent"),
    [
        ("vnav.localize", ("mujoco", "rerun")),
        ("vnav.methods", ("mujoco", "rerun", "cv2")),
        # Replanned at every camera tick: pure geometry, numpy only.
        ("vnav.obstacle_map", ("mujoco", "rerun", "cv2", "scipy")),
        ("vnav.navigate", ("mujoco", "rerun", "cv2", "scipy")),
        # The IMU's chain, noise and Allan deviation: numpy only (MuJoCo's sensors are sim's).
        ("vnav.imu", ("mujoco", "rerun", "cv2", "scipy")),
        # Camera-IMU calibration: numpy and OpenCV; SciPy is its tests' oracle only.
        ("vnav.imu_calibration", ("mujoco", "rerun", "scipy")),
        ("scenarios.judge.imu_calibration", ("mujoco", "rerun", "scipy")),
        ("scenarios.scenario.spec", ("mujoco", "rerun")),
        ("scenarios.scenario.builtin", ("mujoco", "rerun")),
        ("scenarios.run.records", ("mujoco", "rerun")),
        ("scenarios.run.evaluate", ("mujoco", "rerun")),
        ("scenarios.run.runner", ("rerun",)),
        ("scenarios.judge.checks", ("mujoco", "rerun")),
        ("scenarios.judge.report", ("mujoco", "rerun")),
        ("scenarios.judge.calibration", ("mujoco", "rerun")),
        ("sim.mesh", ("rerun",)),
        ("scenarios.record.panel", ("mujoco", "rerun")),
        ("scenarios.record.plots", ("mujoco", "rerun", "matplotlib")),
        ("scenarios.record.viewer", ("mujoco",)),
        ("scenarios.record.reader", ("mujoco",)),
        # A sweep's plan, tables, summary and plots need no simulator; the command loads Ray
        # only when it runs, so that without it the command can say how to install it.
        ("scenarios.sweep.plan", ("mujoco", "rerun", "ray", "pyarrow")),
        ("scenarios.sweep.store", ("mujoco", "rerun", "ray")),
        ("scenarios.sweep.summary", ("mujoco", "rerun", "ray", "pyarrow")),
        ("scenarios.sweep.plots", ("mujoco", "rerun", "ray", "pyarrow")),
        ("scenarios.commands.sweep", ("ray",)),
        # The command line loads a verb's module only when the verb runs.
        ("scenarios.cli", ("mujoco", "rerun", "ray", "cv2")),
        ("scenarios.commands.list", ("mujoco", "rerun", "ray")),
        # Loaded by every pytest session once vnav-sim is installed (its pytest11 entry point).
        ("scenarios.grading.pytest_plugin", ("mujoco", "rerun", "ray", "cv2", "numpy")),
    ],
)
def test_module_does_not_load(module, absent):
    code = f"import sys, {module}; print(','.join(m for m in {absent!r} if m in sys.modules))"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.strip()
    assert out == "", f"{module} loads {out}"
