"""node/session.py's handshake with a real coordinator (in this process, on loopback).

A node that finds its coordinator over mDNS first screens every advertised one with a Hello on a
connection of its own (node/app.py), then joins the one that proved the rig token. The Hello it
verified is the first half of that Join: a rejoin makes one handshake, not two. Should the
coordinator restart between the two (another instance, another secret: the old nonces are refused),
the core shakes hands again, once, and joins.
"""
from __future__ import annotations

import asyncio
import logging

from coordinator.rig import Rig
from node.clock import LocalClock
from node.link import CoordinatorLink
from node.records import NodeInfo
from node.session import SessionCore
from shadowless.local import LocalRig
from inprocess_coordinator import inprocess_coordinator

SLOT = "r0c0"


class CountedLink:
    """A real CoordinatorLink whose Hello calls are counted."""

    def __init__(self, link: CoordinatorLink):
        self.link, self.target, self.hellos = link, link.target, 0

    async def hello(self, **kw):
        self.hellos += 1
        return await self.link.hello(**kw)

    async def join(self, request):
        return await self.link.join(request)


async def screen(core: SessionCore, target: str) -> None:
    """What node/app.py does with an advertised coordinator: a Hello on a connection of its own."""
    async with CoordinatorLink(target) as link:
        await core.hello(link)


async def join(core: SessionCore, target: str):
    async with CoordinatorLink(target) as raw:
        link = CountedLink(raw)
        joined = await core.join(link)
        return joined, link.hellos


def test_a_join_after_screening_shakes_hands_once_and_again_only_when_the_coordinator_restarted(tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="node")
    rig = LocalRig([SLOT], tmp_path, mdns=False)
    rig.create()
    core = SessionCore(slot=SLOT, token=rig.token, clock=LocalClock(), info=lambda: NodeInfo(hostname="test"))

    async def go():
        async with inprocess_coordinator(Rig(rig.rig_dir), rig.token) as app:
            target = f"127.0.0.1:{app.port}"
            await screen(core, target)
            screened = await join(core, target)         # the screening's Hello is the Join's
            plain = await join(core, target)            # no screening before: a Hello of its own
            await screen(core, target)
            instance = app.coordinator.instance_id
        # the coordinator restarts on the same address between the screening and the join
        async with inprocess_coordinator(Rig(rig.rig_dir), rig.token, listen=target) as again:
            restarted = await join(core, target)
            joined_slots = sorted(again.coordinator.by_slot)
            return screened, plain, restarted, instance, again.coordinator.instance_id, joined_slots

    try:
        screened, plain, restarted, first_instance, second_instance, joined_slots = asyncio.run(go())
    finally:
        rig.close()
    (joined, hellos) = screened
    assert hellos == 0 and joined.reply.session and joined.reply.instance_id == first_instance
    (joined, hellos) = plain
    assert hellos == 1 and joined.reply.session
    (joined, hellos) = restarted
    assert first_instance != second_instance
    assert hellos == 1 and joined.reply.instance_id == second_instance and joined.reply.session
    assert "refused the handshake it answered" in caplog.text      # the old nonces were tried, then a fresh Hello
    assert joined_slots == [SLOT]
