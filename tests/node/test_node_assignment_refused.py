"""A malformed assignment is refused by the node process, whole: a coordinator (in this process) and a
real node process on loopback. The coordinator's assignment message is spoiled on its way (a homography
of 8 values, as from a coordinator with a bug or another version): the node says so in one log line, its
presenter never sees it, and its heartbeats go on naming the revision its projector keeps, with the
refusal and its reason, which `shadowless status` and the console's health banner show; the next good
assignment is taken as usual and clears it."""
from __future__ import annotations

import asyncio

import numpy as np

from coordinator.console.health import health_view
from coordinator.rig import HomographyPose, Rig
from coordinator.wire import node_messages
from rigctl.commands import status_dict, status_table
from shadowless.local import LocalRig
from waits import wait_until_async
from inprocess_coordinator import inprocess_coordinator

SLOT = "r0c0"
W, H = 32, 24


async def c_status(rig):
    async with await rig.client() as c:
        return await c.status()


def test_a_malformed_assignment_is_refused_in_the_node_process_and_the_previous_one_kept(tmp_path, monkeypatch):
    rig = LocalRig([SLOT], tmp_path, output_size=(W, H), content_size=(W, H), mdns=False).create()

    async def go():
        async with inprocess_coordinator(Rig(rig.rig_dir), rig.token, listen=f"127.0.0.1:{rig.port}") as app:
            coord = app.coordinator
            coord.update_slot(SLOT, pose=HomographyPose(np.eye(3)))
            rig.start_node(SLOT)
            async with await rig.client() as c:
                await rig.wait_live(c, timeout=120)
            good = coord.rig.slots[SLOT].revision
            sess = coord.by_slot[SLOT]
            await wait_until_async(lambda: sess.heartbeat and sess.heartbeat.assignment_revision,
                                   lambda r: r == good, what=f"the node holding r{good}")

            real = node_messages.assignment_message

            def spoiled(st, *, content_size):
                msg = real(st, content_size=content_size)
                del msg.homography.m[-1]             # 8 values: no homography
                return msg

            monkeypatch.setattr(node_messages, "assignment_message", spoiled)
            coord.update_slot(SLOT, gain=0.5)
            bad = coord.rig.slots[SLOT].revision
            line = f"assignment r{bad} refused"
            await wait_until_async(lambda: rig.log("node-" + SLOT), lambda text: line in text,
                                   what="the node refusing the spoiled assignment")
            # the next heartbeat, made after the refusal, still names the revision the projector keeps
            before = sess.heartbeat
            hb = await wait_until_async(lambda: sess.heartbeat, lambda h: h is not before,
                                        what="a heartbeat after the refusal")
            assert hb.assignment_revision == good
            # and says why, as far as the operator's status and the console's health banner
            assert hb.assignment_refused == f"r{bad}: homography needs 9 values, got 8", hb.assignment_refused
            st = await c_status(rig)
            node = next(n for n in st.nodes if n.slot == SLOT)
            assert node.assignment_refused == hb.assignment_refused
            assert f"{SLOT}: refused assignment r{bad}: homography needs 9 values" in status_table(status_dict(st))
            alarm = [a for a in health_view(st)["alarms"] if a["kind"] == "assignment"]
            assert alarm and f"still shows r{good}" in alarm[0]["text"], health_view(st)["alarms"]

            monkeypatch.setattr(node_messages, "assignment_message", real)
            coord.update_slot(SLOT, gain=0.75)
            after = coord.rig.slots[SLOT].revision
            await wait_until_async(lambda: sess.heartbeat.assignment_revision, lambda r: r == after,
                                   what=f"the node taking the good r{after}")
            assert sess.heartbeat.assignment_refused == ""
            return bad, after

    try:
        bad, after = asyncio.run(go())
    finally:
        rig.close()
    log = rig.log("node-" + SLOT)
    refused = [ln for ln in log.splitlines() if f"assignment r{bad} " in ln]
    assert len(refused) == 1 and "homography needs 9 values, got 8" in refused[0], refused
    assert "malformed" not in log, "the presenter never saw it"
    assert f"node.presenter: assignment r{after}: homography pose" in log
