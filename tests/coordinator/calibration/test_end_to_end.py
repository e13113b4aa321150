"""End to end: `shadowless room` service, node processes sending what they show to it, a
coordinator, and `shadowless calibrate` / `shadowless alignment` run through the CLI; the poses the
nodes received are checked against the room's truth."""
from __future__ import annotations

import asyncio
import json

import numpy as np

from bench.calibration import planar_errors, table_points_from_truth
from coordinator.rig import HomographyPose, Rig
from shadowless.cli import main
from shadowless.local import LocalRig
from sim.room import Room
from sim.scene import reference_scene
from sim.wire.service import RoomServerThread
from waits import wait_until_async

SLOTS = ["r1c1", "r3c3"]


def test_calibrate_and_check_alignment_through_nodes_and_the_room_service(tmp_path, capsys):
    room = Room(reference_scene(projector_scale=0.1, camera_scale=0.15), seed=3)
    room.set_active(SLOTS)
    points = tmp_path / "marks.json"
    table_points_from_truth(room, points, click_noise_px=0.3)
    with RoomServerThread(room) as server:
        rig = LocalRig(SLOTS, tmp_path / "local", output_size=room.projector_size(SLOTS[0]), content_size=(1200, 600),
                       node_output=f"room://{server.address}", mdns=False)
        with rig:
            async def live():
                async with await rig.client() as c:
                    await rig.wait_live(c, timeout=120)

            asyncio.run(live())
            common = ["--coordinator", f"127.0.0.1:{rig.port}", "--rig-dir", str(rig.rig_dir), "--camera", f"room://{server.address}"]
            # the constant-capture mode first
            assert main(["calibrate", *common, "--table-points", str(points), "--json"]) == 0
            mux = json.loads(capsys.readouterr().out)
            assert mux["mode"] == "multiplexed" and set(mux["slots"]) == set(SLOTS) and mux["captures"] == 2 + 20 + 4
            state = Rig(rig.rig_dir)
            mux_poses = {s: state.slot(s).pose.matrix for s in SLOTS}
            for s in SLOTS:
                assert isinstance(state.slot(s).pose, HomographyPose)
                rms, mx = planar_errors(room, s, mux_poses[s], (1200, 600))
                assert rms <= 0.3 and mx <= 1.0, (s, rms, mx)

            # the nodes have the new poses (their heartbeats report the calibrated revision)
            async def revisions():
                async with await rig.client() as c:
                    async def seen():
                        st = await c.status()
                        return {n.slot: (n.pose_kind, n.assignment_revision) for n in st.nodes}

                    return await wait_until_async(
                        seen, lambda got: all(got.get(s) == ("homography", state.slot(s).revision) for s in SLOTS),
                        what="every node's heartbeat to report its calibrated revision")

            asyncio.run(revisions())

            # the reference mode on one projector, through the same nodes: Gray codes pass pixel-exact
            assert main(["calibrate", *common, "--table-points", str(points), "--mode", "sequential",
                         "--slots", SLOTS[0], "--force"]) == 0
            table = capsys.readouterr().out
            assert "sequential mode" in table and SLOTS[0] in table and "rms px" in table
            seq = Rig(rig.rig_dir).slot(SLOTS[0]).pose.matrix
            rms, mx = planar_errors(room, SLOTS[0], seq, (1200, 600))
            assert rms <= 0.3 and mx <= 1.0, (rms, mx)

            # the alignment check through the nodes: every projector lands where its pose says
            assert main(["alignment", *common, "--json"]) == 0
            al = json.loads(capsys.readouterr().out)
            for s in SLOTS:
                assert al["slots"][s]["dots"] > 20 and al["slots"][s]["rms_px"] < 0.3, al["slots"][s]
            assert (rig.rig_dir / "calibration" / "alignment.png").exists()

            # an operator error travels back to the command line with the slot named
            assert main(["calibrate", *common, "--table-points", str(points), "--slots", "r9c9"]) != 0
            assert "r9c9" in capsys.readouterr().err
    assert np.all(np.isfinite(seq))
