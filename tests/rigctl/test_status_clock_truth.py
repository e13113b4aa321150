"""A lost or departed node's clock figures are not shown as current: `shadowless status` (its table
and its JSON) and the console's node table show none ("-", null) for them, as for a slot whose node
never made a clock exchange, and the table says how long ago a silent node last reported. Only a
joined or live node's figures are shown.

The rig is a real coordinator on an injected clock: three nodes join and report their clock
estimates; then one goes silent past ``lost_after_ms`` and one says goodbye. The status goes
through the control wire as the command receives it."""
from __future__ import annotations

import asyncio

from coordinator.api import NodeState
from coordinator.app import CoordinatorApp
from coordinator.console.live import snapshot
from coordinator.rig import Rig, grid_slots, init_rig
from coordinator.sessions import Heartbeat, NodeInfo, Report
from coordinator.wire import control_messages
from rigctl.commands import status_dict, status_table

MS = 1_000_000
CLOCK_KEYS = ("clock_offset_ms", "drift_ppm", "rtt_ms", "clock_error_ms")


def heartbeat() -> Report:
    return Report(heartbeat=Heartbeat(clock_offset_ns=int(0.5 * MS), clock_drift_ppm=3.25, clock_rtt_ns=int(1.2 * MS)))


def test_lost_and_departed_nodes_show_no_clock_figures(tmp_path):
    rig = Rig(init_rig(tmp_path / "rig", name="t", slots=grid_slots(1, 4), width=32, height=32,
                       content_width=32, content_height=32))
    now = [7_000 * MS]

    async def go():
        coord = CoordinatorApp(rig, b"x" * 32, advertise=False, clock_ns=lambda: now[0]).coordinator
        sessions = {slot: coord.join(slot=slot, info=NodeInfo(hostname=f"host-{slot}"), peer="test")
                    for slot in ("r0c0", "r0c1", "r0c2")}                     # r0c3: no node ever
        for s in sessions.values():
            coord.on_report(s, heartbeat())
        assert {n.slot: n.state for n in coord.status().nodes} == {
            "r0c0": NodeState.LIVE, "r0c1": NodeState.LIVE, "r0c2": NodeState.LIVE, "r0c3": NodeState.EXPECTED}

        coord.mark_left(sessions["r0c2"], "stopped (SIGTERM)")
        silent_ms = rig.config.lost_after_ms + 2_000
        for _ in range(silent_ms // 1_000):           # r0c0 keeps reporting, r0c1 is silent
            now[0] += 1_000 * MS
            coord.on_report(sessions["r0c0"], heartbeat())
            coord.sweep()
        status = coord.status()
        assert {n.slot: n.state for n in status.nodes} == {
            "r0c0": NodeState.LIVE, "r0c1": NodeState.LOST, "r0c2": NodeState.LOST, "r0c3": NodeState.EXPECTED}
        # the coordinator still holds the lost nodes' last figures: what is shown is the point here
        assert {n.slot: n.clock_rtt_ms for n in status.nodes}["r0c1"] == 1.2

        # the command: JSON and table, from the status as it comes over the wire
        back = control_messages.status_from_message(control_messages.status_message(status))
        d = status_dict(back)
        nodes = {n["slot"]: n for n in d["nodes"]}
        assert [nodes["r0c0"][k] for k in CLOCK_KEYS[:3]] == [0.5, 3.25, 1.2]
        for slot in ("r0c1", "r0c2", "r0c3"):
            assert [nodes[slot][k] for k in CLOCK_KEYS] == [None] * 4, (slot, nodes[slot])
        assert nodes["r0c1"]["last_seen_age_ms"] == silent_ms and nodes["r0c3"]["last_seen_age_ms"] is None
        lines = status_table(d).splitlines()
        rows = {line.split()[0]: line.split() for line in lines if line.startswith("r0c")}
        assert rows["r0c0"][1:6] == ["live", "host-r0c0", "0.500", "3.2", "1.200"], rows["r0c0"]
        assert rows["r0c1"][1:6] == ["lost", "host-r0c1", "-", "-", "-"], rows["r0c1"]
        assert rows["r0c2"][1:6] == ["left", "host-r0c2", "-", "-", "-"], rows["r0c2"]
        assert rows["r0c3"][1:6] == ["expected", "-", "-", "-", "-"], rows["r0c3"]
        assert f"r0c1: lost: its node went silent {silent_ms / 1000:.1f} s ago" in lines
        assert "r0c2: left on purpose: stopped (SIGTERM)" in lines

        # the console's node table says the same
        page = {s["slot"]: s for s in snapshot(status, coord, [])["slots"]}
        assert page["r0c0"]["clock_offset_ms"] == 0.5 and page["r0c0"]["clock_rtt_ms"] == 1.2
        for slot in ("r0c1", "r0c2", "r0c3"):
            assert [page[slot][k] for k in ("clock_offset_ms", "clock_drift_ppm", "clock_rtt_ms", "clock_error_ms")] \
                == [None] * 4, (slot, page[slot])

    asyncio.run(go())
