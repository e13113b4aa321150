"""A node's network side (the node process: link, session, cache, reports) holds no numpy: its
presenter process decodes what needs arrays (an assignment's pose and maps, frame packets' images).

numpy with OpenBLAS is about 16 MB resident and 6-7 MB of a process's own memory; a node is two
processes, and only the presenter needs it. A real coordinator and node play a clip, so that the
node process has joined, taken an assignment, fetched the asset and followed the show; then its
mappings (/proc/PID/maps) are read: numpy's libraries are not among them, and they are among the
presenter's (the probe sees them where they are).
"""
from __future__ import annotations

import asyncio
import subprocess
import sys
from pathlib import Path

import numpy as np

from clip_rig import clip_rig
from waits import wait_until_async

SLOT = "r0c0"


def maps_numpy(pid: int) -> bool:
    return "/numpy/" in Path(f"/proc/{pid}/maps").read_text()


def test_the_node_process_entry_imports_no_numpy():
    probe = ("import sys\nimport node.cli, node.app\n"
             "print(sorted(m for m in sys.modules if m == 'numpy' or m.startswith('numpy.')))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.strip().splitlines()[-1] == "[]"


def test_a_node_playing_holds_numpy_in_its_presenter_alone(tmp_path):
    rig = clip_rig([SLOT], tmp_path, size=(64, 48), fps=30, seconds=1)
    with rig:
        async def play():
            async with await rig.client() as c:
                await rig.wait_live(c)
                await c.configure(SLOT, homography=np.eye(3))          # an assignment with a pose (arrays)
                await wait_until_async(lambda: c.status(), lambda s: s.nodes[0].assets_ready == 1,
                                       what="the node holding the clip")
                p = await c.play_asset("clip", loop=True, delay_s=0.3)
                await wait_until_async(lambda: c.status(), lambda s: (s.nodes[0].show.state.value == "playing"
                                                                      and s.nodes[0].show.revision == p.revision
                                                                      and s.nodes[0].assignment_revision >= 1),
                                       what=f"the node playing revision {p.revision} with its assignment")

        asyncio.run(play())
        node = rig.nodes[SLOT].pid
        kids = [int(k) for k in Path(f"/proc/{node}/task/{node}/children").read_text().split()]
        presenters = [k for k in kids if b"child_main" in Path(f"/proc/{k}/cmdline").read_bytes()]
        assert len(presenters) == 1, kids
        assert maps_numpy(presenters[0])
        assert not maps_numpy(node)
        assert "node.presenter: assignment r1: homography pose" in rig.log("node-" + SLOT)
