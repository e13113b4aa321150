"""The node's mDNS discovery (protos/discovery.py's Discovery, which node/app.py's loop waits on) is
stopped right as a coordinator appears, many times, and each time the stop lands and leaves no task.

A watcher of its own (another zeroconf on 127.0.0.1) receives the same announcement datagram as the
node's discovery, in the same loop turn: it cancels the node's wait in that turn or 1-2 turns later,
the moments around the wake-up that asyncio.wait_for (3.11) lost a cancel at. A node stopped on
purpose (Node.stop(), a SIGTERM) while it looks for its coordinator, in the instant one appears,
ends its run and leaves no task and no process."""
from __future__ import annotations

import asyncio
import os
import socket

import pytest
from zeroconf import DNSService, IPVersion, RecordUpdateListener
from zeroconf.asyncio import AsyncServiceInfo, AsyncZeroconf

from protos.discovery import Discovery
from strict_loop import HANG_S, run_clean
from waits import wait_until_async


def service_type(tag: str) -> str:
    return f"_sl-{tag}-{os.getpid() % 10**6}._tcp.local."


class Sighting(RecordUpdateListener):
    """Calls ``on_sight(instance)`` in the loop turn a response carrying an SRV record of ``service``
    arrives (zeroconf hands every listener a received message synchronously)."""

    def __init__(self, service: str):
        super().__init__()
        self.suffix = "." + service.lower()
        self.on_sight = lambda name: None

    def async_update_records(self, zc, now, records) -> None:
        for update in records:
            rec = update.new
            if isinstance(rec, DNSService) and rec.name.lower().endswith(self.suffix) and rec.ttl > 0:
                self.on_sight(rec.name)
                return


class Room:
    """On 127.0.0.1: a responder that advertises coordinators (pointing at a closed port) and a
    watcher that sees their announcements as the node's discovery does."""

    def __init__(self, service: str):
        self.service = service
        self.responder = AsyncZeroconf(interfaces=["127.0.0.1"], ip_version=IPVersion.V4Only)
        self.watcher = AsyncZeroconf(interfaces=["127.0.0.1"], ip_version=IPVersion.V4Only)
        self.sighting = Sighting(service)
        self.watcher.zeroconf.async_add_listener(self.sighting, None)
        self.infos: list[AsyncServiceInfo] = []
        self.broadcasts: set[asyncio.Task] = set()      # zeroconf's announcements, repeated for a second or two

    async def appear(self, name: str, rig: str) -> None:
        """A coordinator of rig ``rig`` appears as ``name`` (announced at once, no probing)."""
        info = AsyncServiceInfo(self.service, f"{name}.{self.service}", addresses=[socket.inet_aton("127.0.0.1")],
                                port=9, properties={"rig": rig, "name": name, "proto": "4", "instance": name},
                                server=f"{name}.local.")
        self.infos.append(info)
        self.broadcasts.add(await self.responder.async_register_service(info, cooperating_responders=True))

    def others(self) -> set[asyncio.Task]:
        """The loop's tasks but its announcements'."""
        return asyncio.all_tasks() - self.broadcasts

    async def close(self) -> None:
        await asyncio.gather(*self.broadcasts, return_exceptions=True)
        goodbyes = [await self.responder.async_unregister_service(info) for info in self.infos]
        await asyncio.gather(*goodbyes, return_exceptions=True)
        self.watcher.zeroconf.async_remove_listener(self.sighting)
        await self.watcher.async_close()
        await self.responder.async_close()


@pytest.mark.parametrize("wait", ["wait_change", "find"])
def test_a_wait_cancelled_as_a_coordinator_appears_is_cancelled(wait):
    service = service_type(f"cw{wait[0]}")
    trials = 18

    async def go():
        room = Room(service)
        disc = Discovery(interfaces=["127.0.0.1"], service_type=service)
        await disc.start()
        loop = asyncio.get_running_loop()
        landed = 0
        try:
            base = len(room.others())
            for trial in range(trials):
                name = f"coord-{trial}"
                if wait == "wait_change":
                    waiter = asyncio.create_task(disc.wait_change(disc.generation, HANG_S * 2))
                else:
                    waiter = asyncio.create_task(disc.find(rig=name, timeout=HANG_S * 2))
                outcome: list[bool] = []

                def cancel_after(turns: int) -> None:
                    if turns == 0:
                        outcome.append(waiter.cancel())     # False: the wait had ended already
                    else:
                        loop.call_soon(cancel_after, turns - 1)

                room.sighting.on_sight = lambda seen, name=name, turns=trial % 3: (
                    cancel_after(turns) if seen.startswith(name + ".") and not outcome else None)
                await room.appear(name, rig=name)
                async with asyncio.timeout(HANG_S):
                    await asyncio.gather(waiter, return_exceptions=True)
                await wait_until_async(lambda: outcome, timeout=HANG_S,
                                       what=f"trial {trial}: the announcement seen and the cancel made")
                if outcome[0]:      # the cancel reached the wait before it returned: it must end cancelled
                    landed += 1
                    assert waiter.cancelled(), (f"trial {trial}: the cancel was lost as {name} appeared "
                                                f"(the wait returned {waiter.result()!r})")
                assert len(room.others()) == base, f"trial {trial}: a task of the wait is left: {room.others()}"
            assert landed >= trials // 3, f"only {landed} of {trials} cancels came before the wait's end"
        finally:
            room.sighting.on_sight = lambda name: None
            await disc.close()
            await room.close()

    run_clean(go())


#: when the coordinator appears after the node starts (s): while its presenter starts and its first
#: look runs, during a later look, and after a look found nothing (the sleep only chooses the moment)
APPEAR_AFTER_S = (0.0, 1.5, 3.6)


def test_a_node_stopped_as_its_coordinator_appears_stops(tmp_path):
    from node.app import Node, NodeConfig
    from protos.version import SERVICE_TYPE

    async def go():
        room = Room(SERVICE_TYPE)
        try:
            for trial, after in enumerate(APPEAR_AFTER_S):
                rig = f"cancel-{os.getpid()}-{trial}"      # this node looks for this rig only
                node = Node(NodeConfig(slot="r0c0", token=b"x" * 32, rig=rig, mdns_interfaces=["127.0.0.1"],
                                       cache_dir=tmp_path / "cache", realtime=False))
                run = asyncio.create_task(node.run(), name="node")
                stopped: list[str] = []

                def stop(seen: str, rig=rig, node=node) -> None:     # in the loop turn the announcement arrives
                    if seen.startswith(rig + ".") and not stopped:
                        stopped.append(seen)
                        node.stop("stopped by the test")
                room.sighting.on_sight = stop
                await asyncio.sleep(after)
                await room.appear(rig, rig=rig)
                try:
                    async with asyncio.timeout(HANG_S):
                        status = await run
                except TimeoutError:
                    pytest.fail(f"trial {trial}: the node stopped as {rig} appeared ({stopped}) did not end its run")
                assert stopped and status == 0, (trial, stopped, status)
                me = asyncio.current_task()
                await wait_until_async(lambda: room.others() - {me}, lambda left: not left, timeout=HANG_S,
                                       what=f"trial {trial}: no task of the node left")
        finally:
            room.sighting.on_sight = lambda name: None
            await room.close()

    run_clean(go())


def test_a_node_stopped_during_a_long_look_ends_it_at_once(tmp_path, monkeypatch):
    """A stop (a SIGTERM, Ctrl-C) while the node looks over mDNS ends the look; it used to wait the
    look out (DISCOVERY_TIMEOUT_S, 3 s). The look is made an hour long, so only a stop that ends it
    lets the run end before HANG_S."""
    import node.app
    from node.app import Node, NodeConfig

    monkeypatch.setattr(node.app, "DISCOVERY_TIMEOUT_S", 3600.0)

    async def go():
        rig = f"nobody-{os.getpid()}"       # no coordinator of this rig is advertised
        n = Node(NodeConfig(slot="r0c0", token=b"x" * 32, rig=rig, mdns_interfaces=["127.0.0.1"],
                            cache_dir=tmp_path / "cache", realtime=False))
        looking: list[str] = []
        ready = n.notifier.ready
        n.notifier.ready = lambda status: (looking.append(status), ready(status))[-1]
        run = asyncio.create_task(n.run(), name="node")
        await wait_until_async(lambda: looking or run.done(), what="the node looking for its coordinator")
        assert not run.done(), run
        n.stop("stopped by the test")
        try:
            async with asyncio.timeout(HANG_S):
                status = await run
        except TimeoutError:
            pytest.fail(f"a node stopped during its hour-long look did not end its run ({looking})")
        assert status == 0

    run_clean(go())
