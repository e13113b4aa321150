"""A lost coordinator is one line in the node's log, and its return one more: a real coordinator process
killed (SIGKILL) or stopped (SIGTERM) under a real node process on loopback, then started again; what
the node says is read from its log (its stderr).

Every stream of a session (assignments, frames, reports, show, previews, assets, pings) breaks when the
coordinator is killed, and ends when it stops on purpose; either way one loss must read as one ``lost the
coordinator`` line, not one per broken stream nor none, and one ``coordinator back`` line when the node has
rejoined (a node that knows itself alone also looks for its coordinator at least every second)."""
from __future__ import annotations

import asyncio
import signal

import pytest

from shadowless.local import LocalRig
from waits import wait_until, wait_until_async

SLOT = "r0c0"
LOST = "lost the coordinator"
BACK = "coordinator back after"
#: the node's next pass after the loss: it tried the coordinator again and found nothing there
RETRIED = "could not reach the coordinator"


@pytest.mark.allow_leaks     # the restarted coordinator belongs to the rig, stopped with it
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["killed", "stopped"])
def test_one_loss_of_the_coordinator_is_one_line_and_its_return_one_more(tmp_path, sig):
    with LocalRig([SLOT], tmp_path, output_size=(32, 24), content_size=(32, 24), mdns=False) as rig:
        async def live():
            async with await rig.client() as c:
                await rig.wait_live(c, timeout=120)

        asyncio.run(live())
        since = len(rig.log("node-" + SLOT))
        rig.stop_coordinator(sig)
        # every broken stream has been seen by the time the node tries the coordinator again
        wait_until(lambda: rig.log("node-" + SLOT)[since:], lambda text: RETRIED in text.split(LOST, 1)[-1]
                   and LOST in text, what="the loss logged and the coordinator tried again")
        lost = rig.log("node-" + SLOT)[since:]
        assert lost.count(LOST) == 1, [ln for ln in lost.splitlines() if LOST in ln]
        assert BACK not in lost

        rig.start_coordinator()

        async def rejoined():
            async with await rig.client(timeout=90.0) as c:
                await rig.wait_live(c, min_joins={SLOT: 1}, timeout=120)
                await wait_until_async(lambda: rig.log("node-" + SLOT)[since:], lambda text: BACK in text,
                                       what="the node saying the coordinator is back")

        asyncio.run(rejoined())
        after = rig.log("node-" + SLOT)[since:]     # (the rig's own stop, next, is another loss)
    assert after.count(LOST) == 1, [ln for ln in after.splitlines() if LOST in ln]
    assert after.count(BACK) == 1, [ln for ln in after.splitlines() if BACK in ln]
