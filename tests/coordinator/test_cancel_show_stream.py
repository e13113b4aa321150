"""The coordinator's node streams (NodeLink ``Show`` and ``Assignments``, coordinator/wire/node_service.py)
at their worst moments, on a real coordinator on loopback with a real node link: a node's Show call
cancelled right as show changes go out ends with its handler gone (no follower of the show left
subscribed, no task left behind), every change reaches the node, even one made while the stream
writes the one before, and every Show stream ends with its session.

Each stream waits for an event that a change sets. They cleared it after sending, not before reading
what to send, so a change made while the previous message was written was lost: the node heard of a
show's change at the next beacon (BEACON_S, 5 s; the change is due 150 ms ahead) and of an
assignment at the next one.

A session's close woke every stream of the node but the Show stream, which noticed it at its next
beacon, and the report call, which noticed it at the node's next report: a node that left kept its
Show call up to BEACON_S, and a coordinator's graceful stop waited for them until the node tore its
calls down (a real node does when any stream ends; one that does not cost the whole grace, 2 s, and
had its calls cancelled as errors). A coordinator
stopped right as a change goes out (0-4 loop turns after it, or with its streams quiet) now ends
every Show call cleanly, and so does a node that says goodbye as a change goes out. The tests set the
beacon an hour away, so only a change or the close wakes a stream."""
from __future__ import annotations

import asyncio
import contextlib
import time

import numpy as np
import pytest

from coordinator.api import NodeState
from coordinator.assets import AssetStore
from coordinator.rig import Rig, init_rig
from coordinator.wire import node_service
from node.clock import LocalClock
from node.link import CoordinatorLink
from node.records import HeartbeatRecord, NodeInfo
from node.session import ReportStream, SessionCore
from inprocess_coordinator import inprocess_coordinator
from protos import auth
from strict_loop import HANG_S, run_clean
from waits import wait_until_async

SLOT = "r0c0"
#: a beacon never comes while a test runs: only a change or the session's close wakes a stream
NO_BEACON_S = 3600.0


@pytest.fixture
def rig_dir(tmp_path):
    import cv2
    rig_dir = init_rig(tmp_path / "rig", name="cancel", slots=[SLOT], width=32, height=32, content_width=32,
                       content_height=32)
    cv2.imwrite(str(tmp_path / "still.png"), np.zeros((32, 32, 3), np.uint8))
    AssetStore(rig_dir).add(tmp_path / "still.png", name="still")
    return rig_dir


def heartbeat() -> HeartbeatRecord:
    return HeartbeatRecord(assignment_revision=0, frames_shown=0, frames_late=0, frames_dropped=0,
                           render_ms_p50=0.0, host_monotonic_ns=time.monotonic_ns())


class Node:
    """A node's side as node/app.py holds it: joined, reporting, following the show."""

    def __init__(self, target: str, token: bytes, *, heartbeat_s: float = 0.5):
        self.link = CoordinatorLink(target)
        self.core = SessionCore(slot=SLOT, token=token, clock=LocalClock(), info=lambda: NodeInfo(hostname="t"))
        self.reports = ReportStream(heartbeat, heartbeat_s)
        self.updates: list = []

    async def __aenter__(self) -> "Node":
        await self.link.__aenter__()
        await self.core.join(self.link)
        self.report_call = asyncio.create_task(self.reports.run(self.link), name="report")
        return self

    async def __aexit__(self, *exc) -> None:
        self.report_call.cancel()
        await asyncio.gather(self.report_call, return_exceptions=True)
        await self.link.__aexit__(*exc)

    def follow(self) -> asyncio.Task:
        async def go():
            async for update in self.link.show():
                self.updates.append(update)
        return asyncio.create_task(go(), name="follow")

    async def next_update(self, seen: int) -> None:
        await wait_until_async(lambda: len(self.updates) > seen, what=f"show update {seen + 1} on the node")


@contextlib.asynccontextmanager
async def showing(rig_dir, token):
    """A coordinator serving the rig (stopped within HANG_S on the way out) with a still playing as a show."""
    async with inprocess_coordinator(Rig(rig_dir), token, stop_within=HANG_S) as app:
        app.coordinator.play_asset("still", start_without=True, loop=True)
        yield app


def change(c, k: int) -> None:
    """Show change ``k``: a pause, a resume or a seek (each a new revision sent on every stream)."""
    action = ("pause", "resume", "seek")[k % 3]
    c.show_control(action, frame=0)


def test_a_show_call_cancelled_as_changes_go_out_leaves_no_handler(rig_dir, monkeypatch):
    monkeypatch.setattr(node_service, "BEACON_S", NO_BEACON_S)
    token = auth.read_token(rig_dir / "token")
    trials = 40

    async def go():
        async with showing(rig_dir, token) as app:
            c = app.coordinator
            async with Node(f"127.0.0.1:{app.port}", token) as node:
                await wait_until_async(lambda: [n.state for n in c.status().nodes], lambda s: s == [NodeState.LIVE],
                                       what="the node live (its report stream open)")
                call = node.follow()
                await node.next_update(0)
                call.cancel()
                await asyncio.gather(call, return_exceptions=True)
                await wait_until_async(lambda: c.show_state.followers, lambda n: n == 0, what="no follower")
                base = len(asyncio.all_tasks())     # the session's own calls open, no Show call
                for trial in range(trials):
                    call = node.follow()
                    await node.next_update(len(node.updates))
                    for k in range(trial % 7):      # a burst: the handler is writing when the cancel comes
                        change(c, k)
                        await asyncio.sleep(0)
                    change(c, trial)
                    for _ in range(trial % 5):      # the cancel 0-4 loop turns after the last change
                        await asyncio.sleep(0)
                    call.cancel()
                    async with asyncio.timeout(HANG_S):
                        await asyncio.gather(call, return_exceptions=True)
                    await wait_until_async(lambda: (c.show_state.followers, len(asyncio.all_tasks())),
                                           lambda s: s == (0, base), timeout=HANG_S,
                                           what=f"trial {trial}: the cancelled call's handler gone "
                                                f"(followers, tasks; {base} tasks before)")

    run_clean(go())


def revision_of(update) -> int:
    return update.timeline.revision if update.timeline is not None else update.stop_revision


def test_every_change_reaches_the_node_even_one_made_while_the_stream_writes(rig_dir, monkeypatch):
    """The Show and Assignments streams wake on an event that a change sets; one that cleared it after
    sending (not before reading what to send) lost a change made while it wrote the previous one: the
    node heard of it at the next beacon (a show's change is due 150 ms ahead), or never (an assignment)."""
    monkeypatch.setattr(node_service, "BEACON_S", NO_BEACON_S)
    token = auth.read_token(rig_dir / "token")
    rounds = 40

    async def go():
        async with showing(rig_dir, token) as app:
            c = app.coordinator
            async with Node(f"127.0.0.1:{app.port}", token) as node:
                assignments: list = []

                async def follow_assignments():
                    async for a in node.link.assignments():
                        assignments.append(a)

                show_call, assignment_call = node.follow(), asyncio.create_task(follow_assignments())
                try:
                    await node.next_update(0)
                    await wait_until_async(lambda: assignments, what="the node's first assignment")
                    for r in range(rounds):
                        for k in range(1 + r % 6):      # a burst, its changes 0-3 loop turns apart
                            change(c, k)
                            c.update_slot(SLOT, gain=0.5 + 0.01 * ((r + k) % 40))
                            for _ in range(k % 4):
                                await asyncio.sleep(0)
                        want = (c.show_state.revision, c.rig.slots[SLOT].revision)
                        await wait_until_async(lambda: (revision_of(node.updates[-1]), assignments[-1].revision),
                                               lambda got: got == want, timeout=HANG_S,
                                               what=f"round {r}: the last show change and assignment on the node")
                finally:
                    for t in (show_call, assignment_call):
                        t.cancel()
                    await asyncio.gather(show_call, assignment_call, return_exceptions=True)

    run_clean(go())


def test_a_quiet_show_is_repeated_in_beacons(rig_dir, monkeypatch):
    monkeypatch.setattr(node_service, "BEACON_S", 0.05)
    token = auth.read_token(rig_dir / "token")

    async def go():
        async with showing(rig_dir, token) as app:
            async with Node(f"127.0.0.1:{app.port}", token) as node:
                call = node.follow()
                try:
                    await node.next_update(0)
                    change(app.coordinator, 0)
                    revision = app.coordinator.show_state.revision

                    def since_the_change() -> list:
                        sent = [i for i, u in enumerate(node.updates) if revision_of(u) == revision]
                        return node.updates[sent[0]:] if sent else []
                    after = await wait_until_async(since_the_change, lambda us: sum(u.beacon for u in us) >= 3,
                                                   timeout=HANG_S, what="three beacons after the change")
                    assert not after[0].beacon, "the change went as a change, not in a beacon"
                    assert {revision_of(u) for u in after} == {revision}, "a beacon repeats the show as it is"
                    assert [revision_of(u) for u in node.updates if not u.beacon] == [revision - 1, revision]
                finally:
                    call.cancel()
                    await asyncio.gather(call, return_exceptions=True)

    run_clean(go())


def test_a_stop_as_the_wanted_assets_change_ends_the_wanted_stream(rig_dir, tmp_path):
    """The Wanted stream cleared its wake-up after sending and waited if the list had not changed: a
    session closed while it wrote the list (the rig's assets changed as the coordinator stopped) was
    missed, and the stream held its call until the server's grace ran out (an hour here)."""
    import cv2
    token = auth.read_token(rig_dir / "token")

    async def go():
        for trial in range(10):
            async with showing(rig_dir, token) as app:
                c = app.coordinator
                async with Node(f"127.0.0.1:{app.port}", token) as node:
                    lists: list = []

                    async def follow_wanted():
                        async for w in node.link.wanted():
                            lists.append(w)
                    call = asyncio.create_task(follow_wanted())
                    await wait_until_async(lambda: lists, what=f"trial {trial}: the first wanted list")
                    picture = tmp_path / f"added-{trial}.png"
                    cv2.imwrite(str(picture), np.full((32, 32, 3), trial, np.uint8))
                    AssetStore(rig_dir).add(picture, name=f"added-{trial}")
                    assert await c.refresh_assets()     # the list changes: every Wanted stream wakes to send it
                    for _ in range(trial % 5):          # the stop 0-4 loop turns later, as the list is written
                        await asyncio.sleep(0)
                    try:
                        async with asyncio.timeout(HANG_S):
                            await app.stop(grace=NO_BEACON_S)
                    except TimeoutError:
                        pytest.fail(f"trial {trial}: the coordinator's stop hung (the Wanted stream missed its "
                                    "session's close)")
                    async with asyncio.timeout(HANG_S):
                        ended = (await asyncio.gather(call, return_exceptions=True))[0]
                    assert ended is None, f"trial {trial}: the Wanted call ended by {ended!r}, not by its end"

    run_clean(go())


@pytest.mark.parametrize("moment", [-1, 0, 1, 2, 4])
def test_a_stop_that_meets_a_change_ends_every_show_stream(rig_dir, monkeypatch, moment):
    """The coordinator stops ``moment`` loop turns after a show change (-1: with its streams quiet).
    Its graceful stop waits for every call to end, as long as it takes: a Show stream that waits for
    its next beacon after its session closed holds it, and so does a report call that waits for the
    node's next heartbeat (both an hour away here)."""
    monkeypatch.setattr(node_service, "BEACON_S", NO_BEACON_S)
    token = auth.read_token(rig_dir / "token")

    async def go():
        for trial in range(4):
            async with showing(rig_dir, token) as app:
                async with Node(f"127.0.0.1:{app.port}", token, heartbeat_s=NO_BEACON_S) as node:
                    call = node.follow()
                    await node.next_update(0)
                    if moment >= 0:
                        change(app.coordinator, trial)
                        for _ in range(moment):
                            await asyncio.sleep(0)
                    try:    # the subject: a graceful stop as long as it likes, which ends when every call has
                        async with asyncio.timeout(HANG_S):
                            await app.stop(grace=NO_BEACON_S)
                    except TimeoutError:
                        pytest.fail(f"trial {trial}: the coordinator's stop hung (a call of the node outlived its "
                                    f"session; {app.coordinator.show_state.followers} Show stream(s) still following)")
                    async with asyncio.timeout(HANG_S):
                        ended = (await asyncio.gather(call, return_exceptions=True))[0]
                    assert ended is None, f"trial {trial}: the node's Show call ended by {ended!r}, not by its end"
                    assert app.coordinator.show_state.followers == 0

    run_clean(go())


def test_a_node_that_leaves_ends_its_show_stream(rig_dir, monkeypatch):
    monkeypatch.setattr(node_service, "BEACON_S", NO_BEACON_S)
    token = auth.read_token(rig_dir / "token")

    async def go():
        async with showing(rig_dir, token) as app:
            c = app.coordinator
            for trial in range(5):
                async with Node(f"127.0.0.1:{app.port}", token) as node:
                    call = node.follow()
                    await node.next_update(0)
                    change(c, trial)            # a change on its way as the node says goodbye
                    node.reports.goodbye("stopped")
                    async with asyncio.timeout(HANG_S):
                        await node.report_call
                    await wait_until_async(lambda: c.show_state.followers, lambda n: n == 0, timeout=HANG_S,
                                           what=f"trial {trial}: the Show stream of the node that left ended")
                    async with asyncio.timeout(HANG_S):
                        ended = (await asyncio.gather(call, return_exceptions=True))[0]
                    assert ended is None, f"trial {trial}: the Show call ended by {ended!r}, not by its end"

    run_clean(go())
