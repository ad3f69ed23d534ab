"""vnav-demo sweep, end to end: serial and on a local Ray instance (1 and 2 workers), the same
rows bit for bit; --resume after an interruption; the tables against summary.json; the worst
seed replayed by vnav-demo run; bad input.

The sweep: frame-problem cut to 2 s, two grid points (attitude noise 0 and 1 deg) x 3 seeds,
so that seeds give different numbers where there is noise.
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from scenarios.sweep import engine as engines
from scenarios.sweep.rows import row_columns
from vnav import metrics
from vnav.methods import METHOD_NAMES

SWEEP = """\
scenario = "frame-problem"
seeds = 3
[grid]
"noise.attitude_std_deg" = [0.0, 1.0]
"duration_s" = [2.0]
"""


def sweep_cli(*args: str, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "scenarios", "sweep", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


# Session-scoped (one per test process, never torn down midway): under pytest-xdist this
# module's tests are spread over both processes, between other modules' tests.
@pytest.fixture(scope="session")
def work(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("sweep")
    (root / "small.toml").write_text(SWEEP)
    return root


@pytest.fixture(scope="session")
def serial(work) -> Path:
    proc = sweep_cli("small.toml", "--out", "serial", "--workers", "0", cwd=work)
    assert proc.returncode == 1, proc.stderr  # the noisy point fails frame-problem's checks
    return work / "serial"


def rows(out: Path) -> list[dict]:
    """results.parquet without the one machine-dependent column."""
    return pq.read_table(out / "results.parquet").drop(["wall_s"]).to_pylist()


def same(a, b) -> bool:
    """Equal, NaN equal to NaN (Arrow's and Python's == say NaN != NaN)."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


def assert_same_rows(a: list[dict], b: list[dict]) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        assert x.keys() == y.keys()
        different = [k for k in x if not same(x[k], y[k])]
        assert not different, (x["point"], x["seed"], different)


def test_serial_rows(serial):
    table = pq.read_table(serial / "results.parquet")
    assert table.column_names == [
        "point",
        "seed",
        "noise.attitude_std_deg",
        "duration_s",
        *row_columns(),
    ]
    got = rows(serial)
    assert [(r["point"], r["seed"]) for r in got] == [(p, s) for p in (0, 1) for s in (1, 2, 3)]
    noiseless = [r["depth_image.median_m"] for r in got if r["point"] == 0]
    noisy = [r["depth_image.median_m"] for r in got if r["point"] == 1]
    assert len(set(noiseless)) == 1  # no noise: the seed changes nothing
    assert len(set(noisy)) == 3  # 1 deg of attitude noise: each seed its own
    assert all(r["status"] == "passed" for r in got if r["point"] == 0)
    assert all(r["status"] == "failed" and r["failed_checks"] for r in got if r["point"] == 1)


@pytest.mark.parametrize("workers", ["1", "2"])
def test_ray_workers_give_the_serial_rows(work, serial, workers):
    out = f"ray{workers}"
    proc = sweep_cli("small.toml", "--out", out, "--workers", workers, cwd=work)
    assert proc.returncode == 1, proc.stderr
    assert f"({workers} local workers)" in proc.stdout
    assert_same_rows(rows(work / out), rows(serial))
    assert_same_rows(
        pq.read_table(work / out / "estimates.parquet").to_pylist(),
        pq.read_table(serial / "estimates.parquet").to_pylist(),
    )


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def ray_cluster():
    """A Ray cluster of 2 CPUs started as a user would (``ray start --head``), stopped after."""
    port, client_port = _free_port(), _free_port()
    env = {**os.environ, "RAY_AUTH_MODE": "disabled"}  # no token to hand to the sweep
    command = [str(Path(sys.executable).parent / "ray"), "start", "--head", "--block"]
    command += ["--num-cpus", "2", "--port", str(port)]
    command += ["--ray-client-server-port", str(client_port)]
    command += ["--include-dashboard", "false", "--disable-usage-stats"]
    # `ray start` records its address for `--address auto` and leaves the record behind.
    record = Path("/tmp/ray/ray_current_cluster")
    recorded = record.read_bytes() if record.exists() else None
    head = subprocess.Popen(
        command,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 120
        for p in (port, client_port):
            while True:
                try:
                    socket.create_connection(("127.0.0.1", p), timeout=1).close()
                    break
                except OSError:
                    assert time.monotonic() < deadline and head.poll() is None, "ray start failed"
                    time.sleep(0.2)
        yield f"127.0.0.1:{port}", f"ray://127.0.0.1:{client_port}", env
    finally:
        head.terminate()
        head.wait(timeout=120)
        if recorded is None:
            record.unlink(missing_ok=True)
        else:
            record.write_bytes(recorded)


def test_an_existing_cluster_gives_the_serial_rows(work, serial, ray_cluster):
    """--address joins a cluster, as host:port (its GCS), ray://host:port (Ray Client) or
    auto (the cluster `ray start` recorded), and nothing else changes; asking for more workers
    than the cluster has CPUs is refused."""
    address, client_address, env = ray_cluster
    sweep = [sys.executable, "-m", "scenarios", "sweep", "small.toml", "--workers", "2"]
    for out, given in (("cluster", address), ("client", client_address), ("auto", "auto")):
        proc = subprocess.run(
            [*sweep, "--address", given, "--out", out],
            cwd=work,
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert proc.returncode == 1, proc.stderr
        assert f"on the Ray cluster at {given} (2 workers)" in proc.stdout
        assert_same_rows(rows(work / out), rows(serial))
    args = [sys.executable, "-m", "scenarios", "sweep", "small.toml", "--address", address]
    proc = subprocess.run(
        [*args, "--out", "percpu"], cwd=work, env=env, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 1, proc.stderr
    assert f"on the Ray cluster at {address} (a worker per CPU)" in proc.stdout
    assert "(2 workers)" in proc.stdout
    proc = subprocess.run(
        [*args, "--out", "more", "--workers", "3"],
        cwd=work,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 2 and "has 2 CPUs: 3 workers" in proc.stderr
    assert not (work / "more" / "sweep.json").exists()


def test_an_address_where_nothing_answers_is_refused_at_once(work):
    start = time.monotonic()
    proc = sweep_cli(
        "small.toml",
        "--out",
        "none",
        "--address",
        f"127.0.0.1:{_free_port()}",
        cwd=work,
        timeout=60,
    )
    assert proc.returncode == 2 and "cannot reach the Ray cluster" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and time.monotonic() - start < 30
    assert not (work / "none" / "sweep.json").exists()


def test_an_address_that_is_not_rays_is_refused_at_once(work):
    """A port that answers but is not a Ray cluster (here a web server, as the dashboard's
    port would be): one line at once, not Ray's retries and warnings."""
    import http.server
    import threading

    server = http.server.HTTPServer(("127.0.0.1", 0), http.server.SimpleHTTPRequestHandler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        for given in (f"127.0.0.1:{server.server_port}", f"ray://127.0.0.1:{server.server_port}"):
            start = time.monotonic()
            proc = sweep_cli("small.toml", "--out", "web", "--address", given, cwd=work, timeout=60)
            assert proc.returncode == 2 and "answers, but not as a Ray cluster" in proc.stderr
            assert len(proc.stderr.strip().splitlines()) == 1 and time.monotonic() - start < 30
            assert not (work / "web" / "sweep.json").exists()
    finally:
        server.shutdown()
        server.server_close()


class _FlakyRay:
    """A stand-in for ``ray`` whose ``init`` fails with the given errors, then succeeds."""

    def __init__(self, *errors: Exception) -> None:
        self.errors, self.calls = list(errors), 0

    def init(self, address: str, **options) -> None:
        self.calls += 1
        if self.errors:
            raise self.errors.pop(0)


def test_ray_client_server_failing_to_start_is_tried_once_more(monkeypatch):
    """Ray Client's per-client server can die at start on a busy machine: one more try; any
    other connection error, or a second failure, is raised at once."""
    monkeypatch.setattr(engines.time, "sleep", lambda s: None)
    failed = ConnectionError("Initialization failure: Starting Ray client server failed")
    ray = _FlakyRay(failed)
    engines._init_retrying_client(ray, "ray://127.0.0.1:10001", {})
    assert ray.calls == 2
    for address, errors in [
        ("ray://127.0.0.1:10001", (ConnectionError("refused"),)),
        ("127.0.0.1:6379", (failed,)),
        ("ray://127.0.0.1:10001", (failed, failed)),
    ]:
        ray = _FlakyRay(*errors)
        with pytest.raises(ConnectionError):
            engines._init_retrying_client(ray, address, {})
        assert ray.calls == len(errors)


def test_ray_engine_reuses_each_workers_scene(work, serial):
    """One actor runs all 6 episodes and builds the scene once: the two grid points differ in
    noise only, so they share a scene (``SceneConfig``)."""
    from scenarios.sweep.plan import load

    plan = load(work / "small.toml")
    engine = engines.RayEngine(workers=1)
    try:
        tasks = [engines.Task(p, s, plan.points[p].scenario_toml) for p, s in plan.episodes]
        results = list(engine.run(tasks))
        (actor,) = engine._actors
        import ray

        built = ray.get(actor.scenes_built.remote())
    finally:
        engine.close()
    assert len({p.spec.scene for p in plan.points}) == 1
    assert len(results) == 6 and built == 1


def test_summary_agrees_with_the_tables(serial):
    summary = json.loads((serial / "summary.json").read_text())
    table = rows(serial)
    estimates = pq.read_table(serial / "estimates.parquet").to_pylist()
    assert summary["complete"] is True
    assert summary["episodes"] == {"planned": 6, "done": 6, "passed": 3, "failed": 3, "diverged": 0}
    for point in summary["points"]:
        mine = [r for r in table if r["point"] == point["index"]]
        assert point["episodes"] == len(mine)
        assert point["pass_rate"] == sum(r["passed"] for r in mine) / len(mine)
        rates = [r["detection_rate"] for r in mine]
        assert point["detection_rate"] == {"mean": pytest.approx(np.mean(rates)), "min": min(rates)}
        for m in METHOD_NAMES:
            got = point["methods"][m]
            for stat in ("median", "rmse"):
                per_episode = np.array([r[f"{m}.{stat}_m"] for r in mine])
                per_episode = per_episode[np.isfinite(per_episode)]
                if per_episode.size:
                    across = got[f"{stat}_m"]
                    assert across["median"] == pytest.approx(np.median(per_episode), abs=0)
                    p90 = np.percentile(per_episode, 90)
                    assert across["p90"] == pytest.approx(p90, abs=0)
                    assert across["max"] == pytest.approx(per_episode.max(), abs=0)
                else:
                    assert got[f"{stat}_m"]["median"] is None
            errors = [
                e["error_m"] for e in estimates if e["point"] == point["index"] and e["method"] == m
            ]
            pooled = metrics.error_stats(np.array(errors, dtype=float))
            assert got["pooled"]["count"] == len(errors) == sum(r[f"{m}.count"] for r in mine)
            if errors:
                for stat in ("median", "rmse", "mean", "max"):
                    assert got["pooled"][stat] == pytest.approx(pooled[stat], rel=1e-12)
        worst = max(mine, key=lambda r: (not r["passed"], r["depth_image.median_m"]))
        assert point["worst"]["seed"] == worst["seed"]


def test_worst_seed_replays_to_the_same_numbers(work, serial):
    summary = json.loads((serial / "summary.json").read_text())
    worst = summary["worst"][0]
    assert worst["point"] == 1  # the noisy point's episodes failed
    command = worst["replay"].split()
    assert command[:2] == ["vnav-demo", "run"]
    proc = subprocess.run(
        [sys.executable, "-m", "scenarios", *command[1:], "--out", "replay", "--quiet"],
        cwd=work,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 1, proc.stderr
    (report_path,) = (work / "replay").glob("*.json")
    report = json.loads(report_path.read_text())
    (row,) = [r for r in rows(serial) if (r["point"], r["seed"]) == (1, worst["seed"])]
    for m in METHOD_NAMES:
        for stat, value in report["methods"][m]["position_error_m"].items():
            if stat in ("count", "mean", "median", "rmse", "max"):
                column = f"{m}.{stat}" if stat == "count" else f"{m}.{stat}_m"
                assert same(row[column], math.nan if value is None else value), column
    assert row["detections"] == report["detections"]


def test_plots_are_pngs(serial):
    names = sorted(p.name for p in (serial / "plots").iterdir())
    assert names == ["error_vs_noise.attitude_std_deg.png", "error_vs_range.png"]
    for name in names:
        data = (serial / "plots" / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000


@pytest.mark.parametrize("workers", ["0", "2"])
def test_resume_after_an_interruption_runs_only_the_missing_episodes(work, serial, workers):
    """SIGTERM once the first episode is journalled (in this process, or on 2 Ray workers
    with episodes in flight); --resume finishes without touching what finished."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    # The signal must land while episodes remain. On a starved machine the whole sweep can
    # finish between the first journal entry and the signal (exit 1, 6 entries): that run
    # tested nothing, so it is made again in a new directory (at most three times).
    for attempt in range(3):
        cut = f"cut{workers}-{attempt}"
        command = [sys.executable, "-m", "scenarios", "sweep", "small.toml", "--out", cut]
        proc = subprocess.Popen(
            [*command, "--workers", workers],
            cwd=work,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        journal = work / cut / "episodes"
        deadline = time.monotonic() + 120
        while not (journal.is_dir() and any(journal.glob("*.json"))):
            assert time.monotonic() < deadline and proc.poll() is None
            time.sleep(0.05)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
        if not (proc.returncode == 1 and len(list(journal.glob("*.json"))) == 6):
            break
    assert proc.returncode == 128 + signal.SIGTERM
    assert "--resume" in err and len(err.strip().splitlines()) == 1
    before = {p.name: p.stat().st_mtime_ns for p in journal.glob("*.json")}
    assert 1 <= len(before) < 6
    partial = json.loads((work / cut / "summary.json").read_text())
    assert partial["complete"] is False
    assert partial["episodes"]["done"] == len(before) == len(rows(work / cut))

    again = sweep_cli("small.toml", "--out", cut, "--workers", workers, cwd=work)
    assert again.returncode == 2 and "--resume" in again.stderr
    resumed = sweep_cli("small.toml", "--out", cut, "--workers", workers, "--resume", cwd=work)
    assert resumed.returncode == 1, resumed.stderr
    assert f"{6 - len(before)} to run" in resumed.stdout
    after = {p.name: p.stat().st_mtime_ns for p in journal.glob("*.json")}
    assert len(after) == 6 and all(after[k] == v for k, v in before.items())
    assert_same_rows(rows(work / cut), rows(serial))
    assert json.loads((work / cut / "summary.json").read_text())["complete"] is True


def test_sweep_prints_how_long_it_took(tmp_path):
    """The sweep's last line is its whole duration, wall clock, from the command's start: no
    less than its episodes took (the figure of the line before) and no more than the command
    took, measured around it."""
    (tmp_path / "one.toml").write_text(
        'scenario = "frame-problem"\nseeds = 1\n[grid]\n"noise.attitude_std_deg" = [0.0]\n'
    )
    started = time.perf_counter()
    proc = sweep_cli("one.toml", "--out", "one", "--workers", "0", cwd=tmp_path)
    took_s = time.perf_counter() - started
    assert proc.returncode == 0, proc.stdout + proc.stderr
    episodes = re.search(r"\(1 run in ([\d.]+) s", proc.stdout)
    total = re.search(
        r"^took ([\d.]+) s in all, wall clock \(episodes ([\d.]+) s, planning, tables, plots "
        r"and recordings ([\d.]+) s\)$",
        proc.stdout.splitlines()[-1],
    )
    assert episodes and total, proc.stdout
    assert total[2] == episodes[1]
    assert float(episodes[1]) <= float(total[1]) <= took_s
    assert float(total[1]) == pytest.approx(float(total[2]) + float(total[3]), abs=0.11)


def test_record_worst(work, serial):
    proc = sweep_cli(
        "small.toml",
        "--out",
        "serial",
        "--workers",
        "0",
        "--resume",
        "--record-worst",
        "1",
        cwd=work,
    )
    assert proc.returncode == 1, proc.stderr
    summary = json.loads((serial / "summary.json").read_text())
    worst = summary["worst"][0]
    assert worst["recording"] == f"worst/frame-problem-p1-s{worst['seed']}.rrd"
    opened = f"(open one with: rerun serial/{worst['recording']})"
    assert f"recorded the 1 worst episodes in serial/worst/ {opened}" in proc.stdout
    report = json.loads((serial / worst["recording"]).with_suffix(".json").read_text())
    (row,) = [r for r in rows(serial) if (r["point"], r["seed"]) == (1, worst["seed"])]
    assert (
        report["methods"]["depth_image"]["position_error_m"]["median"]
        == row["depth_image.median_m"]
    )


@pytest.mark.parametrize(
    ("text", "args", "message"),
    [
        (SWEEP + '"camera.pitch_down_deg" = [100.0]\n', [], "grid point 0"),
        (SWEEP + '"camera.pitch_down_deg" = ["30"]\n', [], "must be a number, got '30'"),
        (SWEEP + '"camera.pitch_down_deg" = [true]\n', [], "must be a number, got True"),
        ("scenario = 'nope'\n", [], "unknown built-in 'nope'"),
        ("scenario = [\n", [], "invalid TOML"),
        (SWEEP, ["--workers", "-1"], "--workers must be 0"),
        (SWEEP, ["--workers", "0", "--address", "auto"], "cannot go with --address"),
        (SWEEP, ["--record-worst", "-2"], "--record-worst"),
        (SWEEP, ["--address", "nonsense"], "--address must be auto, host:port or ray://"),
    ],
)
def test_bad_input_exits_2_with_one_line(tmp_path, text, args, message):
    (tmp_path / "bad.toml").write_text(text)
    proc = sweep_cli("bad.toml", "--out", "o", *args, cwd=tmp_path, timeout=60)
    assert proc.returncode == 2
    assert message in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "o" / "sweep.json").exists()


def test_another_sweep_in_the_same_directory_is_refused(work, serial):
    (work / "other.toml").write_text(SWEEP.replace("seeds = 3", "seeds = 4"))
    proc = sweep_cli("other.toml", "--out", "serial", "--resume", cwd=work, timeout=60)
    assert proc.returncode == 2 and "holds another sweep" in proc.stderr


def test_without_ray_the_command_says_how_to_install_it(monkeypatch, tmp_path, capsys):
    from scenarios import cli

    (tmp_path / "s.toml").write_text(SWEEP)
    monkeypatch.setattr(engines, "ray_missing", lambda: "Ray is not installed: pip install x")
    status = cli.main(["sweep", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o")])
    assert status == 2
    assert "Ray is not installed" in capsys.readouterr().err


def test_an_internal_error_costs_its_episode_only(monkeypatch, tmp_path, capsys):
    """An episode that raises is not a row: the others are kept, the exit status is 3, and
    --resume runs that one again."""
    from scenarios import cli
    from scenarios.sweep.episode import EpisodeRunner

    (tmp_path / "s.toml").write_text(SWEEP)
    real = EpisodeRunner.run

    def broken(self, scenario_toml, point, seed):
        if (point, seed) == (1, 2):
            raise RuntimeError("a bug")
        return real(self, scenario_toml, point, seed)

    monkeypatch.setattr(EpisodeRunner, "run", broken)
    out = tmp_path / "o"
    args = ["sweep", str(tmp_path / "s.toml"), "--out", str(out), "--workers", "0", "--quiet"]
    assert cli.main(args) == 3
    err = capsys.readouterr().err
    assert "1 episodes could not run (point 1 seed 2: RuntimeError: a bug)" in err
    assert len(err.strip().splitlines()) == 1
    assert len(rows(out)) == 5
    monkeypatch.setattr(EpisodeRunner, "run", real)
    assert cli.main([*args, "--resume"]) == 1
    assert [(r["point"], r["seed"]) for r in rows(out)] == [
        (p, s) for p in (0, 1) for s in (1, 2, 3)
    ]
