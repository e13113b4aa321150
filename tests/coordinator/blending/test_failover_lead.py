"""The automatic switch lead learns what the rig's nodes need.

Each node's heartbeat says which maps it shows and from which pts. A switch that some node showed
more than the slack after its instant makes the next switch lead by that switch's lead plus the
delay, never beyond the content's latency budget; a switch every node showed in time gives a part
of it back; a blend job's push, at once to every node, teaches a still's first failover how far apart
the nodes put the same redraw on screen (not a show's: its ticks are rendered anyway); a fixed ``switch_lead_ms`` is kept as it is.
"""
from __future__ import annotations

import asyncio
import sys
from dataclasses import dataclass
from pathlib import Path

from coordinator.blending.state import AUTO_LEAD_BASE_NS, LATE_SLACK_NS, LEARNED_DECAY, BlendState
from coordinator.rig import Rig

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_failover_ahead import SLOTS, blended  # noqa: E402  (three projectors side by side, blended)

MS = 1_000_000


@dataclass
class Session:
    """What a node's heartbeat told the core: the maps on its screen and the pts they show from."""
    blend_id: str = ""
    blend_since_rig_ns: int = 0
    closed: bool = False


def test_a_late_switch_lengthens_the_next_lead_within_the_latency_budget_and_a_timely_one_shortens_it(tmp_path):
    path, _, _ = blended(tmp_path)                 # latency budget 40 ms
    rig = Rig(path)
    now = [5_000_000_000]
    sessions = {s: Session() for s in SLOTS}

    def show(at: int, late: dict[str, int]) -> None:
        """Every live node shows its new maps: from the instant, or ``late[slot]`` after it."""
        for s, sess in sessions.items():
            if not sess.closed:
                sess.blend_id, sess.blend_since_rig_ns = rig.slot(s).blend.blend_id, at + late.get(s, 0)

    async def go():
        state = BlendState(rig, update_slot=rig.update_slot, clock_ns=lambda: now[0], lead_ns=None,
                           node_session=sessions.get)
        state.load()                               # (each loss's maps computed when it comes)
        sessions["right"].closed = True
        state.node_lost("right")                   # nothing learned yet: the maps' own lead
        await state.settled()
        auto = state.last_lead_parts["auto"]
        assert state.last_lead_ns == auto < 40 * MS and state.last_lead_parts["learned"] == 0
        show(now[0] + auto, {"left": 25 * MS, "mid": 3 * MS})     # left showed them 25 ms late: in the slack
        now[0] += 10**9
        sessions["right"] = Session()
        state.node_live("right")
        await state.settled()
        lead = state.last_lead_ns
        assert lead == state.last_lead_parts["auto"], "a delay within the slack teaches nothing"
        show(now[0] + lead, {"mid": 45 * MS})      # mid 45 ms late: beyond the slack
        now[0] += 10**9
        sessions["left"].closed = True
        state.node_lost("left")
        await state.settled()
        assert state.learned_lead_ns == min(lead + 45 * MS, 40 * MS) and state.last_late_ns == 45 * MS
        assert state.last_lead_ns == 40 * MS, "at most the latency budget"
        at = now[0] + state.last_lead_ns
        show(at, {})                               # every node in time: the next lead is a part shorter
        now[0] += 10**9
        sessions["left"] = Session()
        state.node_live("left")
        await state.settled()
        assert state.learned_lead_ns == int(40 * MS * (1 - LEARNED_DECAY))
        assert state.last_lead_ns == max(state.last_lead_parts["auto"], int(40 * MS * (1 - LEARNED_DECAY)))
        # a node that never showed the switch's maps is as late as now
        at = now[0] + state.last_lead_ns
        show(at, {})
        sessions["mid"].blend_id = "something else"
        now[0] = at + 2 * LATE_SLACK_NS
        sessions["right"].closed = True
        state.node_lost("right")
        await state.settled()
        assert state.last_late_ns == 2 * LATE_SLACK_NS
        state.close()

    asyncio.run(go())


def test_a_fixed_switch_lead_is_kept_whatever_the_nodes_showed(tmp_path):
    path, _, _ = blended(tmp_path, "\n[blend]\nswitch_lead_ms = 12.5\n")
    rig = Rig(path)
    now = [5_000_000_000]
    sessions = {s: Session() for s in SLOTS}

    async def go():
        state = BlendState(rig, update_slot=rig.update_slot, clock_ns=lambda: now[0], lead_ns=12_500_000,
                           node_session=sessions.get)
        state.load()
        state.node_lost("right")
        await state.settled()
        for s in ("left", "mid"):
            sessions[s] = Session(rig.slot(s).blend.blend_id, now[0] + 12_500_000 + 200 * MS)
        now[0] += 10**9
        state.node_live("right")
        await state.settled()
        assert state.last_lead_ns == 12_500_000
        state.close()

    asyncio.run(go())


def test_the_blend_jobs_push_teaches_the_first_failover_how_far_apart_the_nodes_show_a_redraw(tmp_path):
    path, _, _ = blended(tmp_path)                 # latency budget 40 ms
    rig = Rig(path)
    now = [5_000_000_000]
    sessions = {s: Session() for s in SLOTS}

    async def go():
        playing = [False]
        state = BlendState(rig, update_slot=rig.update_slot, clock_ns=lambda: now[0], lead_ns=None,
                           node_session=sessions.get, show_active=lambda: playing[0])
        state.load()
        for spread, learned in ((LATE_SLACK_NS // 2, 0), (60 * MS, AUTO_LEAD_BASE_NS + 60 * MS)):
            for k, s in enumerate(SLOTS):          # the job's maps on every screen, the last `spread` after the first
                sessions[s] = Session(rig.slot(s).blend.blend_id, now[0] - 500 * MS + spread * k // 2)
            await state.reload()
            assert state.redraw_lead_ns == learned, spread
        playing[0] = True                          # a show's ticks are rendered anyway: nothing more to wait for
        state.node_lost("right")
        await state.settled()
        assert state.last_lead_ns == state.last_lead_parts["auto"] < 40 * MS
        at = now[0] + state.last_lead_ns
        for s in ("left", "mid"):                  # late ticks of a show: the CPU's, not the lead's
            sessions[s] = Session(rig.slot(s).blend.blend_id, at + 200 * MS)
        playing[0] = False
        now[0] += 10**9
        state.node_live("right")
        await state.settled()
        assert state.learned_lead_ns == 0, "a switch during a show teaches nothing"
        assert state.last_lead_ns == 40 * MS, "a still's switch leads by what the job's push showed (capped)"
        at = now[0] + state.last_lead_ns
        for s in SLOTS:                            # every node showed that switch in time
            sessions[s] = Session(rig.slot(s).blend.blend_id, at)
        now[0] += 10**9
        state.node_lost("right")
        await state.settled()
        # an in-time switch cannot tell how much of its lead it needed: the lead decays no lower than the
        # job's push showed a redraw on every node needs (80 ms, capped at 40)
        assert state.redraw_lead_ns == AUTO_LEAD_BASE_NS + 60 * MS
        assert state.learned_lead_ns == int(40 * MS * (1 - LEARNED_DECAY))
        assert state.last_lead_ns == 40 * MS, state.last_lead_parts
        state.close()

    asyncio.run(go())
