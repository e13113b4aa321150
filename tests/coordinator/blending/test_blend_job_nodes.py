"""End to end through real processes: the `shadowless room` service with uneven projectors, node
processes rendering into it (their shader applies the blend maps), a coordinator process capturing
from it, and the commands `shadowless calibrate`, `response` and `blend`. The blend's flat-white
captures are the nodes' own output: were the maps not applied, the capture after would be the
capture before."""
from __future__ import annotations

import asyncio
import json
from dataclasses import replace

import numpy as np

from bench.calibration import table_points_from_truth
from coordinator.blend_store import load_blend
from coordinator.rig import Rig
from shadowless.cli import main
from shadowless.local import LocalRig
from sim.photometry import Photometry
from sim.room import Room
from sim.scene import reference_scene
from sim.wire.service import RoomServerThread

SLOTS = ["r1c1", "r1c3", "r3c2"]
CONTENT = (200, 100)


def test_blend_through_nodes_the_coordinator_and_the_room_service(tmp_path, capsys):
    uneven = Photometry(brightness_spread=0.15, white_spread=0.15, hotspot=0.2, vignetting=0.3)
    scene = reference_scene(projector_scale=0.125, camera_scale=0.15, photometry=uneven)
    scene = replace(scene, cameras=(replace(scene.cameras[0], exposure=6.0),))   # three of 25: open the camera up
    room = Room(scene, seed=3)
    room.set_active(SLOTS)
    points = tmp_path / "marks.json"
    table_points_from_truth(room, points, click_noise_px=0.3)
    with RoomServerThread(room) as server:
        rig = LocalRig(SLOTS, tmp_path / "local", output_size=room.projector_size(SLOTS[0]), content_size=CONTENT,
                       node_output=f"room://{server.address}", mdns=False)
        with rig:
            async def live():
                async with await rig.client() as c:
                    await rig.wait_live(c, timeout=120)

            asyncio.run(live())
            common = ["--coordinator", f"127.0.0.1:{rig.port}", "--rig-dir", str(rig.rig_dir),
                      "--camera", f"room://{server.address}"]
            assert main(["calibrate", *common, "--table-points", str(points), "--json"]) == 0
            assert main(["response", *common, "--json"]) == 0
            capsys.readouterr()

            assert main(["blend", *common, "--frames", "2", "--json"]) == 0
            out = json.loads(capsys.readouterr().out)
            assert out["slots"] == SLOTS
            # the nodes applied the maps: the flat white they showed became even
            assert out["uniformity_before"] > 0.05, out
            assert out["uniformity_after"] < 0.03 and out["uniformity_after"] < out["uniformity_before"] / 2.5, out
            assert out["uniformity_predicted"] < 0.015, out
            stored = load_blend(rig.rig_dir)
            assert stored is not None and sorted(stored.maps) == sorted(SLOTS)
            assert stored.info["uniformity_after"] == out["uniformity_after"]
            assert np.all(stored.pictures["after"][stored.pictures["after"] > 0] < 1.1)

            # the operator's report, and a bad headroom refused by the coordinator in one line
            assert main(["blend", *common, "--headroom", "0.95"]) == 1
            err = capsys.readouterr().err
            assert "headroom must be 'auto' or a number in 0..0.9" in err and len(err.strip().splitlines()) == 1
            state = Rig(rig.rig_dir)
            assert all(state.slot(s).lut is not None for s in SLOTS)
