"""`shadowless show` of a picture whose aspect differs from the rig's content area is refused in one
line that names the option to give (--fit), and with --fit it is shown. A running coordinator (no
nodes needed) and the real `shadowless show` process."""
from __future__ import annotations

import asyncio

import cv2
import numpy as np

from coordinator.rig import Rig, grid_slots, init_rig
from protos.auth import read_token
from procs import shadowless_process
from inprocess_coordinator import inprocess_coordinator



def test_a_picture_of_another_aspect_is_refused_naming_fit(tmp_path):
    rig = Rig(init_rig(tmp_path / "rig", name="fit", slots=grid_slots(1, 1), width=32, height=32,
                       content_width=64, content_height=32))
    square = tmp_path / "square.png"
    cv2.imwrite(str(square), np.full((20, 20, 3), 128, np.uint8))       # 1:1 on a 2:1 content area

    async def go():
        async with inprocess_coordinator(rig, read_token(rig.path / "token")) as app:
            conn = ["--coordinator", f"127.0.0.1:{app.port}", "--rig-dir", str(rig.path)]
            refused, shown = await asyncio.gather(asyncio.to_thread(shadowless_process, "show", str(square), *conn),
                                                  asyncio.to_thread(shadowless_process, "show", str(square), "--fit", "contain", *conn))
            assert refused.returncode == 2 and refused.stdout == "", refused
            assert len(refused.stderr.splitlines()) == 1, refused.stderr
            assert refused.stderr.startswith("shadowless show: the image is 20x20") and \
                "choose how to fit it with --fit: contain" in refused.stderr, refused.stderr
            assert shown.returncode == 0 and shown.stdout.startswith("showing "), shown

    asyncio.run(go())
