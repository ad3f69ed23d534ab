"""The README runs: every shell command, the TOML example and the Python example in it.

Each fenced block of README.md is taken from the file itself, so a README that changes is
tested as it reads. Shell commands run in a temporary directory with the ``.venv/bin/`` of
this interpreter (``/tmp/`` paths are moved into that directory), except where a comment in
``_KIND`` says why a command is checked another way: ``./setup.sh`` needs root, apt-get and
the network and would rebuild the environment the tests run in; ``rerun FILE`` opens a window;
``rerun --serve-web FILE`` serves until stopped, so it is started, asked for its page, then
stopped; the walk-through of "Check your own frame chain" runs on a copy of ``examples/``.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import tomllib
import urllib.request
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from helpers import plugin_args

from scenarios import pipeline
from scenarios.cli import main
from scenarios.scenario import builtin
from scenarios.scenario.spec import from_dict

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
VENV_BIN = Path(sys.executable).parent
"""Where this interpreter's ``vnav-demo`` and ``rerun`` are: the README's ``.venv/bin``."""


def _blocks(language: str) -> list[str]:
    """The bodies of the README's fenced blocks in ``language``, in order."""
    return [
        body for lang, body in re.findall(r"```(\w+)\n(.*?)```", README, re.S) if lang == language
    ]


def _commands(block: str) -> list[str]:
    """The commands of a shell block, one per line, without their trailing comments."""
    return [c for line in block.splitlines() if (c := re.sub(r"\s+#.*$", "", line).strip())]


COMMANDS = [c for block in _blocks("bash") for c in _commands(block)]


def _kind(command: str) -> str:
    """How the test runs ``command``; a command of no known kind fails ``test_every_...``."""
    if command.startswith("./setup.sh && "):
        return "setup"  # set-up checked by its files; the command after && is run
    if re.fullmatch(r"\.venv/bin/rerun --serve-web \S+\.rrd", command):
        return "serve"  # started, asked for its page, stopped
    if re.fullmatch(r"\.venv/bin/rerun \S+\.rrd", command):
        return "viewer"  # opens a window: checked to name a file the README makes
    if "examples/" in command:
        return "example"  # the walk-through, run in order on a copy of examples/
    if command.startswith(".venv/bin/vnav-demo sweep "):
        return "sweep"  # run in order by test_sweep_commands_run, with the README's sweep file
    if command.startswith(".venv/bin/vnav-demo "):
        return "run"
    raise AssertionError(f"README command with no test: {command!r}")


def test_every_block_of_the_readme_is_tested() -> None:
    languages = {lang for lang, _ in re.findall(r"```(\w*)\n(.*?)```", README, re.S)}
    assert languages == {"bash", "toml", "python"}
    kinds = {_kind(c) for c in COMMANDS}
    assert kinds == {"setup", "serve", "viewer", "run", "sweep", "example"}
    assert len(_blocks("toml")) == 3  # a scenario, two sweeps: each has its test


def _shell(command: str, cwd: Path, timeout_s: float = 300.0) -> subprocess.CompletedProcess:
    """``command`` as a user would type it in ``cwd``, with this interpreter's ``.venv/bin``
    and ``/tmp/`` moved into ``cwd``."""
    command = command.replace(".venv/bin/", f"{VENV_BIN}/").replace(" /tmp/", f" {cwd}/tmp/")
    return subprocess.run(
        ["bash", "-c", command], cwd=cwd, capture_output=True, text=True, timeout=timeout_s
    )


# ------------------------------------------------------------------ on a new machine


def _new_machine_commands() -> list[str]:
    section = README.split("## On a new machine", 1)[1].split("\n## ", 1)[0]
    return [c for body in re.findall(r"```bash\n(.*?)```", section, re.S) for c in _commands(body)]


def test_a_new_machine_needs_two_commands_that_set_up_first() -> None:
    """One sets up and runs a scenario, one sets up and runs the tests."""
    first, second = _new_machine_commands()
    assert first == "./setup.sh && .venv/bin/vnav-demo run frame-problem"
    assert second == "./setup.sh && .venv/bin/python -m pytest"


def test_setup_script_makes_the_venv_the_commands_use() -> None:
    """Not run here (it needs root, apt-get and the network, and would rebuild the venv these
    tests run in): it exists, is executable, and makes ``.venv`` with the test and sweep extras
    (the tests run sweeps on Ray)."""
    script = ROOT / "setup.sh"
    assert script.is_file() and os.access(script, os.X_OK)
    text = script.read_text()
    assert "-m venv .venv" in text and "pip install -q -e '.[test,sweep]'" in text
    # The tests the second command runs: pytest's configured test paths.
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert all((ROOT / p).is_dir() for p in pyproject["tool"]["pytest"]["ini_options"]["testpaths"])
    assert "vnav-demo" in pyproject["project"]["scripts"]


@pytest.fixture(scope="module")
def first_run(tmp_path_factory) -> Path:
    """The first command after its set-up, run where a user would: the directory it ran in."""
    cwd = tmp_path_factory.mktemp("readme-first")
    command = _new_machine_commands()[0].split(" && ", 1)[1]
    proc = _shell(command, cwd)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return cwd


def test_first_command_writes_what_the_readme_says(first_run: Path) -> None:
    said = re.search(r"written to\s+`(\S+\.rrd)` and `(\S+\.json)`", README)
    assert said, "the README says where the first command writes"
    rrd, report = (first_run / p for p in said.groups())
    assert rrd.is_file() and json.loads(report.read_text())["passed"] is True


# ------------------------------------------------------------------------- vnav-demo


def _stands_alone(command: str) -> bool:
    """Whether ``command`` reads and writes nothing of the directory it runs in: it writes only
    under its own ``--out /tmp/...`` or nothing at all (``list``, ``lecture``), which its test
    checks. Such commands run each in a directory of their own (the two test processes share
    them out); the others run in the README's order in one directory."""
    words = command.split()[1:]
    return words in (["list"], ["lecture"]) or re.search(r" --out /tmp/\S+", command) is not None


def test_vnav_demo_commands_run_in_order(tmp_path: Path) -> None:
    """Every ``vnav-demo`` command of the README that works in its directory, in the README's
    order, in one directory: each exits 0; ``show orbit > my-orbit.toml`` then
    ``run my-orbit.toml`` writes ``my-orbit`` files and leaves ``orbit``'s alone."""
    commands = [c for c in COMMANDS if _kind(c) == "run" and not _stands_alone(c)]
    assert len(commands) >= 4
    orbit_report = tmp_path / "recordings" / "orbit.json"
    before = None
    for command in commands:
        if "run my-orbit.toml" in command:
            before = orbit_report.read_text()  # written by `run --all`
        proc = _shell(command, tmp_path)
        assert proc.returncode == 0, f"{command}\n{proc.stdout}\n{proc.stderr}"
        assert proc.stderr == "", proc.stderr
    assert before is not None and orbit_report.read_text() == before
    name = tomllib.loads((tmp_path / "my-orbit.toml").read_text())["name"]
    assert name != "orbit"
    assert (tmp_path / "recordings" / f"{name}.rrd").is_file()
    assert json.loads((tmp_path / "recordings" / f"{name}.json").read_text())["passed"]
    for builtin_name in builtin.names():
        assert (tmp_path / "recordings" / f"{builtin_name}.rrd").is_file()


@pytest.mark.parametrize("command", [c for c in COMMANDS if _kind(c) == "run" and _stands_alone(c)])
def test_vnav_demo_command_on_its_own(command: str, tmp_path: Path) -> None:
    """The README's ``vnav-demo`` commands that write only under their ``--out /tmp/DIR`` or
    nothing, each in an empty directory: it exits 0 with nothing on stderr, and writes nothing
    but ``DIR`` (moved into the directory), there the report of every scenario it names."""
    proc = _shell(command, tmp_path)
    assert proc.returncode == 0, f"{command}\n{proc.stdout}\n{proc.stderr}"
    assert proc.stderr == "", proc.stderr
    out = re.search(r" --out /tmp/(\S+)", command)
    if out is None:
        assert list(tmp_path.iterdir()) == []
        return
    assert [p.name for p in tmp_path.iterdir()] == ["tmp"]
    assert [p.name for p in (tmp_path / "tmp").iterdir()] == [out[1].split("/")[0]]
    words = command.split()
    names = words[words.index("run") + 1 : next(i for i, w in enumerate(words) if w[:2] == "--")]
    assert names
    for name in names:
        assert json.loads((tmp_path / "tmp" / out[1] / f"{name}.json").read_text())["passed"]


# ------------------------------------------------------------------------ recordings


def test_viewer_command_opens_the_file_the_first_command_writes(first_run: Path) -> None:
    """Not run (it opens a window); the file it names is the one the first command writes,
    and the viewer it calls starts."""
    for command in (c for c in COMMANDS if _kind(c) == "viewer"):
        assert (first_run / command.split()[-1]).is_file()
    version = subprocess.run(
        [VENV_BIN / "rerun", "--version"], capture_output=True, text=True, timeout=60
    )
    assert version.returncode == 0 and "rerun" in version.stdout.lower()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_serve_web_command_serves_the_recording_without_a_display(first_run: Path) -> None:
    """The README's no-display command, on free ports (the defaults it names are checked
    against ``rerun --help``), with no DISPLAY: its web viewer answers over HTTP."""
    (command,) = [c for c in COMMANDS if _kind(c) == "serve"]
    help_text = subprocess.run(
        [VENV_BIN / "rerun", "--help"], capture_output=True, text=True, timeout=60
    ).stdout
    web_default = re.search(r"--web-viewer-port.*?\[default: (\d+)\]", help_text, re.S)
    grpc_default = re.search(r"default port is (\d+)", help_text)
    assert f"http://localhost:{web_default[1]}" in README
    assert f"-L {grpc_default[1]}:localhost:{grpc_default[1]}" in README
    web, grpc = _free_port(), _free_port()
    args = command.replace(".venv/bin/", f"{VENV_BIN}/").split()
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    proc = subprocess.Popen(
        [*args, "--web-viewer-port", str(web), "--port", str(grpc)],
        cwd=first_run,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        deadline, status = time.monotonic() + 60.0, None
        while status is None and time.monotonic() < deadline:
            assert proc.poll() is None, f"rerun --serve-web exited with {proc.returncode}"
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=5) as response:
                    status, page = response.status, response.read().decode(errors="replace")
            except OSError:
                time.sleep(0.5)
        assert status == 200 and "rerun" in page.lower()
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=30)


def test_screenshot_script_renders_without_a_display() -> None:
    """Named by the README as the way to take pictures headless; not run here (it needs
    apt-get, Xvfb and minutes): it exists, starts a virtual display and has
    ``scripts/screenshot.py`` drive the real viewer on it (the viewer's own screenshot)."""
    assert "bash scripts/screenshots.sh" in README
    script = (ROOT / "scripts" / "screenshots.sh").read_text()
    assert "Xvfb" in script and 'DISPLAY="$display"' in script
    assert "scripts/screenshot.py" in script
    shot = (ROOT / "scripts" / "screenshot.py").read_text()
    assert "rerun_cli" in shot and "copy_screenshot_to_clipboard" in shot


# ------------------------------------------------------------ your own frame chain


def test_the_walk_through_finds_the_mistake_and_the_fix_passes(tmp_path: Path) -> None:
    """On a copy of ``examples/``: the run exits 1 and the doctor names the mistake the README
    names; ``pytest examples/`` fails naming it too; with the README's fix made, it passes
    (the plugin given with ``-p`` where the installed vnav-sim predates its entry point)."""
    shutil.copytree(ROOT / "examples", tmp_path / "examples", ignore=_no_cache)
    run, tests = [c for c in COMMANDS if _kind(c) == "example"]
    section = README.split("## Check your own frame chain", 1)[1].split("\n## ", 1)[0]
    said = " ".join(section.split())
    mistake = re.search(r"`(Mistake: [^(`]+ \([^)`]+\))`", said)[1]
    wrong, right = re.search(
        r"In `examples/my_chain.py`, `([^`]+)` becomes `([^`]+)`", said
    ).groups()
    tests += "".join(f" {a}" for a in plugin_args())

    proc = _shell(run, tmp_path)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert mistake in " ".join(proc.stdout.split())
    proc = _shell(tests, tmp_path)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert mistake in proc.stdout

    chain = tmp_path / "examples" / "my_chain.py"
    assert chain.read_text().count(wrong) == 1
    chain.write_text(chain.read_text().replace(wrong, right))
    proc = _shell(tests, tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert re.search(r"\b4 passed\b", proc.stdout), proc.stdout


def _no_cache(directory: str, names: list[str]) -> list[str]:
    return [n for n in names if n in ("__pycache__", ".pytest_cache")]


# ------------------------------------------------------------------ the TOML example


def _toml_block(kind: str) -> str:
    """The README's scenario example (``kind="scenario"``), or the sweep file it says to save
    as ``kind`` (``"my-sweep.toml"``: the text after the block says ``Saved as `NAME```)."""
    if kind == "scenario":
        (block,) = [b for b in _blocks("toml") if "[grid]" not in b]
        return block
    saved = re.findall(r"```toml\n(.*?)```\s+Saved as `(\S+\.toml)`", README, re.S)
    (block,) = [b for b, name in saved if name == kind and "[grid]" in b]
    return block


def test_toml_example_runs_and_passes_with_the_cone_well_inside_the_image(
    tmp_path: Path, monkeypatch
):
    block = _toml_block("scenario")
    spec = from_dict(tomllib.loads(block), where="README.md")
    path = tmp_path / "example.toml"
    path.write_text(block)
    outcomes = []  # the run the command makes, kept to look into its ticks
    run = pipeline.run

    def run_and_keep(*args, **kwargs):
        outcomes.append(run(*args, **kwargs))
        return outcomes[-1]

    monkeypatch.setattr(pipeline, "run", run_and_keep)
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    report = json.loads((tmp_path / "out" / f"{spec.name}.json").read_text())
    assert report["passed"]
    assert report["detections"] == report["matched_detections"] == report["camera_ticks"]
    # At every camera tick the cone is fully in view (its extreme points inside the image,
    # vnav.cone), and no detection touches the border.
    (outcome,) = outcomes
    assert outcome.result.spec == spec
    result = outcome.result
    assert all(t.cones_in_view == [0] for t in result.ticks)
    assert not any(d.detection.touches_border for t in result.ticks for d in t.detections)


# ------------------------------------------------------------------------- sweeps


def test_sweep_commands_run(tmp_path: Path) -> None:
    """The README's sweep file saved as it says, then its sweep commands in order: the first
    runs every episode on Ray (exit 1: the noisy points fail, as the README says; its first
    lines as the README quotes them), the second finds nothing left to run and writes the same
    tables. The episode count the README gives is the file's."""
    sweep_file = tomllib.loads(_toml_block("my-sweep.toml"))
    (tmp_path / "my-sweep.toml").write_text(_toml_block("my-sweep.toml"))
    commands = [c for c in COMMANDS if _kind(c) == "sweep" and " my-sweep.toml " in c]
    assert len(commands) == 2 and "--resume" in commands[1]
    outs, outs_stdout = [], []
    for command in commands:
        proc = _shell(command, tmp_path, timeout_s=600.0)
        assert proc.returncode == 1, f"{command}\n{proc.stdout}\n{proc.stderr}"
        assert proc.stderr == "", proc.stderr
        outs_stdout.append(proc.stdout)
        out = tmp_path / re.search(r"--out (\S+)", command)[1]
        outs.append((out / "results.parquet").read_bytes())
    assert "0 to run" in proc.stdout and outs[0] == outs[1]
    summary = json.loads((out / "summary.json").read_text())
    points = int(np.prod([len(values) for values in sweep_file["grid"].values()]))
    seeds, episodes = sweep_file["seeds"], sweep_file["seeds"] * points
    assert f"that is {points} grid points x {seeds} seeds = {episodes} episodes" in README
    quoted = re.search(r'sweep says so as it starts \(here "(.*?)"\)', README, re.S)[1]
    assert " ".join(quoted.split()) in outs_stdout[0]
    assert summary["complete"] and summary["episodes"]["done"] == episodes
    for point in summary["points"]:
        noisy = point["values"]["noise.attitude_std_deg"] > 0.0
        assert point["pass_rate"] == (0.0 if noisy else 1.0)
        median = point["methods"]["depth_image"]["median_m"]["median"]
        assert (0.12 < median < 0.2) if noisy else (median < 0.03)  # "about 2 cm to 17 cm"


def test_avoid_sweep_shows_what_the_readme_says(tmp_path: Path) -> None:
    """The README's sweep of a navigating flight, saved as it says and run by its command: it
    exits 1, prints each grid point's collision and goal counts as the README quotes them, and
    writes the rates' plot it names; summary.json's rates are those counts."""
    (tmp_path / "avoid-sweep.toml").write_text(_toml_block("avoid-sweep.toml"))
    (command,) = [c for c in COMMANDS if _kind(c) == "sweep" and " avoid-sweep.toml " in c]
    proc = _shell(command, tmp_path, timeout_s=600.0)
    assert proc.returncode == 1, f"{command}\n{proc.stdout}\n{proc.stderr}"
    assert proc.stderr == "", proc.stderr
    said = " ".join(README.split())
    quoted = re.search(r"prints, per grid point, `([^`]+)` for `depth_image` with the true", said)
    assert quoted and quoted[1] in " ".join(proc.stdout.split())
    out = tmp_path / re.search(r"--out (\S+)", command)[1]
    summary = json.loads((out / "summary.json").read_text())
    rates = {
        (p["values"]["flight.estimate"], p["values"]["noise.extrinsic_std_deg"]): (
            p["navigation"]["collided"],
            p["navigation"]["reached_goal"],
            p["navigation"]["flown"],
        )
        for p in summary["points"]
    }
    # "one of its 3 flights touches the cone"; "the naive map ... flies into it every time"
    assert rates == {
        ("depth_image", 0.0): (0, 3, 3),
        ("depth_image", 5.0): (1, 2, 3),
        ("naive", 0.0): (3, 0, 3),
        ("naive", 5.0): (3, 0, 3),
    }
    assert "one of its 3 flights touches the cone (seed 2:" in said
    touched = pq.read_table(out / "results.parquet").to_pylist()
    assert [r["seed"] for r in touched if r["point"] == 1 and r["nav__collided"]] == [2]
    for p in summary["points"]:
        collided, reached, flown = p["navigation"]["collided"], p["navigation"]["reached_goal"], 3
        assert (p["collision_rate"], p["goal_rate"]) == (collided / flown, reached / flown)
    plot = re.search(r"`plots/(navigation_vs_\S+\.png)` draws the two rates", said)[1]
    assert (out / "plots" / plot).read_bytes()[:4] == b"\x89PNG"


# --------------------------------------------------------------- the Python example


@pytest.mark.parametrize("index", range(len(_blocks("python"))))
def test_python_example_prints_what_its_comment_says(index, capsys) -> None:
    """Each Python block of the README (the library's first steps; the IMU's Allan deviation)
    runs and prints what the comment after its ``print`` says."""
    block = _blocks("python")[index]
    exec(compile(block, "README.md", "exec"), {})  # the README's own code
    printed = capsys.readouterr().out
    claimed = re.search(r"print\(.*\)\s*#\s*(\[[^\]]*\])", block)
    assert claimed, "the example's print says what it prints"

    def numbers(text: str) -> np.ndarray:
        return np.array([float(x) for x in re.findall(r"-?\d+\.?\d*(?:e-?\d+)?", text)])

    np.testing.assert_allclose(numbers(printed), numbers(claimed[1]), atol=1e-12)


# ------------------------------------------------------------------------ packaging


def test_dependencies_are_each_explained() -> None:
    """Every runtime dependency and every package of the test and sweep extras is named in the
    README's paragraph on what gets installed and why."""
    paragraph = README.split("What gets installed, and why:", 1)[1].split("\n\n", 1)[0].lower()
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = pyproject["optional-dependencies"]
    requirements = pyproject["dependencies"] + extras["test"] + extras["sweep"]
    called = {"opencv-python-headless": "opencv", "rerun-sdk": "rerun"}
    for requirement in requirements:
        name = re.match(r"[A-Za-z0-9_.-]+", requirement)[0].lower()
        assert called.get(name, name) in paragraph, name


def test_license_is_an_spdx_expression_for_a_setuptools_that_reads_it() -> None:
    """A TOML-table license makes setuptools print a deprecation warning on every install;
    an SPDX string needs setuptools 77 or newer."""
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert pyproject["project"]["license"] == "MIT"
    (setuptools,) = [r for r in pyproject["build-system"]["requires"] if "setuptools" in r]
    assert int(re.fullmatch(r"setuptools>=(\d+)(\.\d+)*", setuptools)[1]) >= 77
