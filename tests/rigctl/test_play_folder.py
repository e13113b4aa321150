"""`shadowless play FOLDER` takes the frames a show's images come as, .jpeg included, and says in
words when there is no skew to report (None is not a figure). A running coordinator with no node
and the real `shadowless play` process: the frames are sent, nobody shows them, and the command
says so and exits 1."""
from __future__ import annotations

import asyncio
import subprocess
import sys

import cv2
import numpy as np

from coordinator.rig import Rig, grid_slots, init_rig
from protos.auth import read_token
from inprocess_coordinator import inprocess_coordinator


def test_a_folder_of_jpeg_frames_plays_and_no_skew_reads_as_words(tmp_path):
    path = init_rig(tmp_path / "rig", name="jpeg", slots=grid_slots(1, 1), width=32, height=32,
                    content_width=32, content_height=32)
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(3):
        cv2.imwrite(str(frames / f"{k:03d}.jpeg"), np.full((32, 32, 3), 60 * k, np.uint8))
    rig = Rig(path)

    async def go():
        async with inprocess_coordinator(rig, read_token(rig.path / "token")) as app:
            return await asyncio.to_thread(subprocess.run, [
                sys.executable, "-m", "shadowless", "play", str(frames), "--fps", "30",
                "--coordinator", f"127.0.0.1:{app.port}", "--rig-dir", str(rig.path)],
                capture_output=True, text=True, timeout=120)

    r = asyncio.run(go())
    assert "no images in" not in r.stderr, r.stderr
    assert r.stdout.startswith("played 3 frames on 0 nodes:"), r
    assert r.stdout.rstrip().endswith("; no skew measured") and "None" not in r.stdout, r.stdout
    assert r.returncode == 1 and "no live node showed the sequence" in r.stderr, r
