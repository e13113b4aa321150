"""`shadowless stop`, `blackout`, `show --fit`, and Ctrl-C on `play`, through the real CLI against a
real coordinator and node."""
from __future__ import annotations

import asyncio
import signal
import subprocess
import sys

import cv2
import numpy as np
import pytest

from cli_inprocess import cli_capture, shadowless_here  # noqa: F401 - cli_capture: the module's autouse fixture
from shadowless.local import LocalRig
from waits import wait_until


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    r = LocalRig(["r0c0"], tmp_path_factory.mktemp("stop"), output_size=(32, 32), content_size=(64, 32),
                 mdns=False).create()
    r.start_coordinator()
    r.wait_ready()
    r.start_node("r0c0")

    async def live():
        async with await r.client() as c:
            await r.wait_live(c)

    asyncio.run(live())
    yield r
    r.close()


def showing(rig) -> str:
    async def go():
        async with await rig.client() as c:
            return (await c.status()).showing
    return asyncio.run(go())


def cli(rig, *args, check=True, process=False):
    """`shadowless ARGS...` against ``rig``: in this interpreter, or with ``process`` as a real process."""
    argv = [*args, "--coordinator", rig.coordinator_target, "--rig-dir", str(rig.rig_dir)]
    r = subprocess.run([sys.executable, "-m", "shadowless", *argv], capture_output=True, text=True,
                       timeout=120) if process else shadowless_here(argv)
    if check:
        assert r.returncode == 0, r.stderr
    return r


def test_show_refuses_another_aspect_unless_fitted_then_blackout_and_stop(rig, tmp_path):
    img = np.full((40, 40, 3), 200, np.uint8)
    cv2.imwrite(str(tmp_path / "square.png"), img)
    r = cli(rig, "show", str(tmp_path / "square.png"), "--persist", check=False, process=True)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "40x40" in r.stderr and "64x32" in r.stderr and "contain" in r.stderr
    cli(rig, "show", str(tmp_path / "square.png"), "--persist", "--fit", "contain")
    assert "square.png" in showing(rig)
    assert "black (blackout)" in cli(rig, "blackout").stdout
    assert showing(rig) == "black (blackout)"
    out = cli(rig, "stop").stdout
    assert "square.png" in out and "square.png" in showing(rig), "stop brings the rig's content back"
    assert showing(rig).startswith("the rig's content: "), "in words, not the frame's tag (show:restored)"


def test_ctrl_c_on_play_stops_the_sequence_on_the_rig(rig):
    argv = [sys.executable, "-m", "shadowless", "play", "--pattern", "counter", "--frames", "3000", "--fps", "30",
            "--coordinator", rig.coordinator_target, "--rig-dir", str(rig.rig_dir)]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        def playing() -> str:
            assert proc.poll() is None, "play exited before the sequence started"
            return showing(rig)

        wait_until(playing, lambda shown: shown.startswith("a played sequence (3000 frames"),
                   what="the sequence playing on the rig", timeout=120)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, err
    assert "stopped on the rig" in err
    assert "played sequence" not in showing(rig), "the rig no longer plays the sequence"
