"""One recording's picture in the real Rerun viewer, at the instant its 3D views are framed for.

Usage (on an X display, as ``scripts/screenshots.sh`` runs it)::

    python scripts/screenshot.py RECORDING.rrd OUT.png

The viewer that ships in rerun-sdk opens the recording in a 1400 x 900 point window; once the
recording is loaded its time cursor is moved, paused, to the recording's ``moment`` (the tick
the scenario's ``show_at_s`` names, else the last: ``scenarios.record.viewer.shown_tick``), on
the timeline its blueprint shows. Then the viewer's own "Screenshot" command takes the picture,
styled for capture at two pixels per point (as ``rerun --screenshot-to`` does, which takes it
ten frames after start whatever has loaded); it lands on the X clipboard, read with xclip, and
is written at half size. Each step waits for the one before: the picture shows the moment.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pyarrow as pa
import rerun_cli
from rerun.chunk import RrdReader
from rerun.experimental import ViewerClient

WINDOW_POINTS = "1400x900"
LOAD_TIMEOUT_S = 240.0
SHOT_TIMEOUT_S = 240.0
SETTLE_S = 3.0
"""After the cursor moves: time for the images at the new instant to decode and draw."""


def moment(rrd: Path) -> dict[str, float]:
    """The recording's static ``moment`` row: ``camera_tick`` and ``sim_time_s``."""
    chunks = RrdReader(str(rrd)).stream().filter(content="/moment").to_chunks()
    for chunk in chunks:
        table = pa.Table.from_batches([chunk.to_record_batch()])
        row = {name: table.column(name).to_pylist()[0] for name in table.column_names}
        # AnyValues columns are named by the value alone (some versions prefix a type).
        tick = next((v for k, v in row.items() if k.split(":")[-1] == "camera_tick"), None)
        sim_time_s = next((v for k, v in row.items() if k.split(":")[-1] == "sim_time_s"), None)
        if tick is not None and sim_time_s is not None:
            return {"tick": _scalar(tick), "sim_time_s": _scalar(sim_time_s)}
    raise SystemExit(f"screenshot.py: {rrd} has no moment (recorded before show_at_s existed?)")


def _scalar(value) -> float:
    return float(np.asarray(value, dtype=np.float64).reshape(-1)[0])


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _clipboard(args: list[str], env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run(
        ["xclip", "-selection", "clipboard", *args], env=env, capture_output=True, timeout=30
    )


def _wait(what: str, timeout_s: float, ready) -> object:
    """Call ``ready()`` until it returns something, every half second; fail after the timeout."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        try:
            value = ready()
        except (ConnectionError, RuntimeError, TimeoutError):
            value = None
        if value:
            return value
        time.sleep(0.5)
    raise SystemExit(f"screenshot.py: the viewer did not {what} within {timeout_s:g} s")


def main(rrd: Path, out: Path) -> None:
    if shutil.which("xclip") is None:
        raise SystemExit("screenshot.py: needs xclip (the viewer's picture comes by clipboard)")
    at = moment(rrd)
    port = _free_port()
    env = dict(os.environ, RUST_LOG="error")
    viewer = Path(rerun_cli.__file__).parent / "rerun"
    process = subprocess.Popen(
        [str(viewer), "--port", str(port), "--window-size", WINDOW_POINTS, str(rrd)],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        url = f"rerun+http://127.0.0.1:{port}/proxy"
        client = _wait("answer", LOAD_TIMEOUT_S, lambda: ViewerClient.connect(url))

        def loaded():
            state = client.get_state()
            return state.recordings and not state.loading and state.recordings[0]

        recording = _wait("load the recording", LOAD_TIMEOUT_S, loaded)
        if recording.current_timeline == "tick":
            client.set_time(sequence=int(at["tick"]), play_state="paused")
            want = int(at["tick"])
        else:
            client.set_time(duration=at["sim_time_s"], play_state="paused")
            want = round(at["sim_time_s"] * 1e9)

        def placed():
            current = client.get_state().recordings[0].current_time
            return current is not None and abs(current - want) <= 1

        _wait("move its time cursor", 30.0, placed)
        time.sleep(SETTLE_S)
        # The clipboard is this viewer's alone: an earlier viewer's picture went with it.
        client.run_command("ui.copy_screenshot_to_clipboard")

        def picture():
            targets = _clipboard(["-t", "TARGETS", "-o"], env).stdout
            return b"image/png" in targets and _clipboard(["-t", "image/png", "-o"], env).stdout

        png = _wait("take its picture", SHOT_TIMEOUT_S, picture)
    finally:
        process.terminate()
        try:
            process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            process.kill()
    image = cv2.imdecode(np.frombuffer(png, dtype=np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        raise SystemExit("screenshot.py: the clipboard held no readable PNG")
    # The viewer draws at twice the window size; half of that reads as well and weighs less.
    half = cv2.resize(image, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
    partial = out.with_name(f".{out.name}.{os.getpid()}.partial.png")
    if not cv2.imwrite(str(partial), half, [cv2.IMWRITE_PNG_COMPRESSION, 9]):
        partial.unlink(missing_ok=True)
        raise SystemExit(f"screenshot.py: could not write {out}")
    os.replace(partial, out)  # the old picture or the new one, never half of one


if __name__ == "__main__":
    # A timeout's SIGTERM unwinds main, whose clean-up ends the viewer it started.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    if len(sys.argv) != 3:
        raise SystemExit("usage: python scripts/screenshot.py RECORDING.rrd OUT.png")
    main(Path(sys.argv[1]), Path(sys.argv[2]))
