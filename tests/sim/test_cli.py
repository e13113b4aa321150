"""`shadowless room`: help that teaches, a real process serving on 127.0.0.1, clean shutdown. The help and
the refusals run in the test's interpreter (output captured at the file descriptors), the first help also
as a real process."""
from __future__ import annotations

import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cli_inprocess import cli_capture, run_here  # noqa: F401 - cli_capture: the module's autouse fixture
from sim.link import RoomClient
from sim.scene import load_layout

ROOT = Path(__file__).resolve().parents[2]


def shadowless(*args: str, process: bool = False) -> subprocess.CompletedProcess:
    """`shadowless ARGS...`: in this interpreter, or with ``process`` as a real process."""
    if process:
        return subprocess.run([sys.executable, "-m", "shadowless", *args], capture_output=True, text=True, cwd=ROOT,
                              timeout=120)
    code, out, err = run_here(list(args))
    return subprocess.CompletedProcess(list(args), code, out, err)


def test_help_teaches_layout_scales_port_and_hands():
    out = shadowless("room", "--help", process=True)
    assert out.returncode == 0
    text = out.stdout
    for needle in ("--layout", "--projector-scale", "--camera-scale", "--port", "--hand X,Y", "--hand-height", "--hand-path",
                   "room://127.0.0.1:50070", "P9D", "--write-layout", "127.0.0.1"):
        assert needle in text, needle


def test_room_process_serves_captures_and_stops_on_sigterm():
    proc = subprocess.Popen(
        [sys.executable, "-m", "shadowless", "room", "--port", "0", "--no-noise", "--projector-scale", "0.125",
         "--camera-scale", "0.125", "--hand", "0,0", "--hand-height", "150", "--subset", "P9D"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
    )
    try:
        line = proc.stdout.readline()
        m = re.search(r"listening on (127\.0\.0\.1:\d+)", line)
        assert m, line + proc.stderr.read() if proc.poll() is not None else line
        with RoomClient(m.group(1)) as client:
            d = client.describe()
            assert sum(p.powered for p in d.projectors) == 9
            client.display({s: np.full((100, 160, 3), 255, np.uint8) for s in d.rig_slots})
            cap = client.capture()
            assert cap.image.shape == (243, 324, 3) and cap.image.max() > 0.1
            assert client.occluder_mask().any()  # the hand is there
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0
        assert "stopped" in proc.stdout.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_write_layout_and_argument_errors(tmp_path):
    path = tmp_path / "rig.toml"
    out = shadowless("room", "--write-layout", str(path), "--pitch", "300")
    assert out.returncode == 0, out.stderr
    scene = load_layout(path)
    assert len(scene.slots) == 25
    assert scene.projector("r0c4").native.center[0] - scene.projector("r0c0").native.center[0] == pytest.approx(1200, abs=10)
    bad = shadowless("room", "--subset", "P99", "--write-layout", str(tmp_path / "x.toml"))
    assert bad.returncode == 2 and "unknown subset 'P99'" in bad.stderr and "P9D" in bad.stderr
    bad = shadowless("room", "--hand", "12")
    assert bad.returncode == 2 and "X,Y" in bad.stderr
    bad = shadowless("room", "--layout", str(tmp_path / "missing.toml"))
    assert bad.returncode == 2 and "missing.toml" in bad.stderr


def test_help_explains_uneven_light_with_units():
    text = shadowless("room", "--help").stdout
    for needle in ("--brightness-spread F", "--white-spread F", "--hotspot F", "--hotspot-width W", "--vignetting F",
                   "1 +- F", "half-diagonals", "0.2 = +20 %", "[photometry]", "set_lamp", "wall-3x1", "bust-walls"):
        assert needle in text, needle
    bad = shadowless("room", "--hotspot", "-1", "--write-layout", "/dev/null")
    assert bad.returncode == 2 and "--hotspot" in bad.stderr
