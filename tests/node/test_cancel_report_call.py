"""The node's report call (node/link.py's ``report``, the session's lifeline) leaves no task behind
when the coordinator ends it while the node waits for its next batch: the coordinator stopped, at
moments around a heartbeat going out.

Given its batches as an async iterator, grpc.aio reads them in a task of its own, cancelled only
when the call is cancelled while it runs. A call the coordinator ended left that task waiting in
the node's report stream for the next batch (up to a heartbeat; an hour here), still pending when
the loop closed. The link now writes the batches from a task it ends with the call."""
from __future__ import annotations

import asyncio
import time

import pytest

from coordinator.api import NodeState
from coordinator.rig import Rig, init_rig
from node.clock import LocalClock
from node.link import CoordinatorLink, LinkError
from node.records import HeartbeatRecord, NodeInfo
from node.session import ReportStream, SessionCore
from inprocess_coordinator import inprocess_coordinator
from protos import auth
from strict_loop import HANG_S, run_clean
from waits import wait_until_async

SLOT = "r0c0"
#: no heartbeat is due while a test runs, once the first went: the node's stream waits for a batch
QUIET_S = 3600.0


def heartbeat() -> HeartbeatRecord:
    return HeartbeatRecord(assignment_revision=0, frames_shown=0, frames_late=0, frames_dropped=0,
                           render_ms_p50=0.0, host_monotonic_ns=time.monotonic_ns())


@pytest.mark.parametrize("turns", [0, 1, 3, None])
def test_a_report_call_the_coordinator_ends_leaves_no_task(tmp_path, turns):
    """The coordinator stops ``turns`` loop turns after the node asked for a heartbeat (None: with the
    node's stream long quiet)."""
    rig_dir = init_rig(tmp_path / "rig", name="report", slots=[SLOT], width=32, height=32, content_width=32,
                       content_height=32)
    token = auth.read_token(rig_dir / "token")

    async def go():
        for trial in range(3):
            async with inprocess_coordinator(Rig(rig_dir), token, stop_within=HANG_S) as app:
                c = app.coordinator
                core = SessionCore(slot=SLOT, token=token, clock=LocalClock(), info=lambda: NodeInfo(hostname="t"))
                async with CoordinatorLink(f"127.0.0.1:{app.port}") as link:
                    await core.join(link)
                    reports = ReportStream(heartbeat, QUIET_S)
                    call = asyncio.create_task(reports.run(link), name="report")
                    await wait_until_async(lambda: [n.state for n in c.status().nodes],
                                           lambda s: s == [NodeState.LIVE],
                                           what=f"trial {trial}: the node live (its first heartbeat taken)")
                    if turns is not None:
                        reports.heartbeat_now()     # a batch on its way as the coordinator goes
                        for _ in range(turns):
                            await asyncio.sleep(0)
                    async with asyncio.timeout(HANG_S):
                        await app.stop()            # the subject: the coordinator ends the node's call
                        ended = (await asyncio.gather(call, return_exceptions=True))[0]
                    assert ended is None or isinstance(ended, LinkError), f"trial {trial}: {ended!r}"
                    me = asyncio.current_task()
                    await wait_until_async(lambda: asyncio.all_tasks() - {me}, lambda left: not left,
                                           timeout=HANG_S, what=f"trial {trial}: no task of the ended report call left")

    run_clean(go())
