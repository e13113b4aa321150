"""The coordinator's core without its edges: built with no listening address, no gRPC server, no
console and no mDNS, and driven through its own methods (what the edges call): nodes join, a still
reaches them as packets, their reports make them live, refusals are domain errors, and whoever
listens to the job tracker hears every change."""
from __future__ import annotations

import asyncio
import os
from pathlib import Path

import numpy as np
import pytest

from coordinator.api import NodeState, Space
from coordinator.errors import Refusal, RefusalKind
from coordinator.jobs.context import Progress
from coordinator.jobs.tracker import JobTracker
from coordinator.ports import ConsoleRig, ServiceRig
from coordinator.rig import Content, Rig, grid_slots, init_rig
from coordinator.server import Coordinator
from coordinator.sessions import NodeInfo, Report, Swaps

TOKEN = b"c" * 32


class Packets:
    """A packet encoding that keeps what it was asked to send, readable by the test: each packet is
    an index into :attr:`sent`, a list of (frame id or None, content ids)."""

    def __init__(self) -> None:
        self.sent: list[tuple[int | None, tuple[str, ...]]] = []

    def encoder(self) -> "Packets":
        return self

    def prepare(self, contents) -> None:
        pass

    def packet(self, *, frame=None, contents=(), evict=(), video=None) -> bytes:
        self.sent.append((frame.frame_id if frame is not None else None, tuple(c.content_id for c in contents)))
        return str(len(self.sent) - 1).encode()


def _sockets() -> int:
    """The sockets this process holds open (file descriptors that are sockets)."""
    n = 0
    for fd in os.listdir("/proc/self/fd"):
        try:
            n += os.readlink(f"/proc/self/fd/{fd}").startswith("socket:")
        except OSError:
            pass
    return n


def _rig(tmp_path: Path) -> Rig:
    return Rig(init_rig(tmp_path / "rig", name="alone", slots=grid_slots(1, 2), width=32, height=32,
                        content_width=32, content_height=32))


def test_the_core_serves_a_still_to_its_nodes_without_a_network(tmp_path):
    rig = _rig(tmp_path)
    now = [5_000_000_000]

    async def go():
        sockets = _sockets()
        coord = Coordinator(rig, TOKEN, encoding=Packets, clock_ns=lambda: now[0])
        assert isinstance(coord, ServiceRig) and isinstance(coord, ConsoleRig), "it has what its edges call"
        coord.open()
        try:
            packets: Packets = coord.fanout.encoding
            a = coord.join(slot="r0c0", info=NodeInfo(hostname="pi-a", pid=1), peer="ipv4:10.0.0.2:5000")
            b = coord.join(slot="r0c1", info=NodeInfo(hostname="pi-b", pid=2), peer="ipv4:10.0.0.3:5000")
            for s in (a, b):
                coord.on_frames_open(s)
            grey = Content(np.full((32, 32, 3), 128, np.uint8), name="grey")
            shown = coord.show(coord.prepare_still(grey, Space.CONTENT), space=Space.CONTENT, apply_lut=True)
            assert shown.frame_id > 0 and shown.content_id
            for s in (a, b):        # each node's queue ends with the still's frame and its content
                frame_id, contents = packets.sent[int(s.packets[-1])]
                assert frame_id == shown.frame_id and shown.content_id in contents, (s.slot, packets.sent)

            assert {n.slot: n.state for n in coord.status().nodes} == {"r0c0": NodeState.JOINED,
                                                                       "r0c1": NodeState.JOINED}
            now[0] += 10_000_000
            for s in (a, b):
                coord.on_report(s, Report(swaps=Swaps.of([(shown.frame_id, shown.pts_ns, shown.pts_ns)])))
            status = coord.status()
            assert {n.slot: (n.state, n.frames_shown) for n in status.nodes} == {
                "r0c0": (NodeState.LIVE, 1), "r0c1": (NodeState.LIVE, 1)}
            assert status.showing == "show grey" and status.console == "off"

            # refusals are the core's own errors, with a kind and no transport in them
            with pytest.raises(Refusal) as unknown:
                coord.join(slot="r9c9", info=NodeInfo(hostname="pi-c", pid=3), peer="ipv4:10.0.0.4:5000")
            assert unknown.value.kind == RefusalKind.NOT_FOUND and "r9c9" in unknown.value.message
            with pytest.raises(Refusal) as closed:
                coord.node_session("no such session")
            assert closed.value.kind == RefusalKind.UNAUTHENTICATED
            assert [r.slot for r in coord.status().refusals] == ["r9c9"]
        finally:
            await coord.close()
        assert _sockets() == sockets, "the core opened no socket"

    asyncio.run(go())


def test_every_job_listener_hears_each_change_until_it_unsubscribes():
    now = [100.0]
    tracker = JobTracker(clock=lambda: now[0])
    heard = {"a": 0, "b": 0}
    tracker.subscribe(lambda: heard.__setitem__("a", heard["a"] + 1))
    stop_b = tracker.subscribe(lambda: heard.__setitem__("b", heard["b"] + 1))
    tracker.begin("transport", {})
    tracker.event(Progress("dots", done=1, total=4))
    assert heard == {"a": 2, "b": 2}
    stop_b()
    stop_b()                        # a second unsubscribe changes nothing
    tracker.event("a log line")
    tracker.end(result={"frames": 4})
    assert heard == {"a": 4, "b": 2}


def test_the_core_tells_its_job_listeners_of_a_job_it_ran(tmp_path):
    """Through the core: a job started with no node connected begins and fails; both listeners hear
    both changes, and one that unsubscribed before hears nothing."""
    rig = _rig(tmp_path)

    async def go():
        coord = Coordinator(rig, TOKEN, encoding=Packets)
        coord.open()
        try:
            heard: dict[str, list] = {"a": [], "b": [], "gone": []}
            for name in heard:
                stop = coord.listen_jobs(lambda name=name: heard[name].append(coord.job_snapshot()["state"]))
                if name == "gone":
                    stop()
            assert coord.running_job() is None
            task = coord.start_job("transport", {"frames": 2})
            with pytest.raises(Exception, match="no projector is connected"):
                await task
            assert heard["a"] == heard["b"] and heard["a"][0] == "running" and heard["a"][-1] == "failed"
            assert heard["gone"] == []
            assert coord.running_job() is None and coord.current_job().state == "failed"
        finally:
            await coord.close()

    asyncio.run(go())


def test_a_pattern_no_node_answers_for_fails_naming_the_silent_nodes(tmp_path):
    """A node that joins and opens its frames but never reports: each try times out, and after the
    last the call fails with the coordinator's own error naming that node (a bare TimeoutError
    used to escape, which an operator saw as an empty message)."""
    from coordinator.errors import CoordinatorError
    rig = _rig(tmp_path)

    async def go():
        coord = Coordinator(rig, TOKEN, encoding=Packets)
        coord.open()
        try:
            for slot, pid in (("r0c0", 1), ("r0c1", 2)):
                s = coord.join(slot=slot, info=NodeInfo(hostname=f"pi-{pid}", pid=pid), peer=f"ipv4:10.0.0.{pid}:5000")
                coord.on_frames_open(s)
            with pytest.raises(CoordinatorError) as failed:
                await coord.playback.show_patterns({}, content=np.zeros((32, 32, 3), np.uint8), attempts=2,
                                                   timeout_s=0.05, settle_s=0)
            assert "r0c0, r0c1" in str(failed.value) and "2 tries" in str(failed.value), str(failed.value)
        finally:
            await coord.close()

    asyncio.run(go())
