"""The status's event ages on the coordinator's injected clock: how long a node has been live
(``live_age_ms``) and how long each asset has been ready on it (``ready_age_ms``), NaN until then;
and that the ages survive the wire and `shadowless status --json`."""
from __future__ import annotations

import asyncio
import math

import numpy as np

from coordinator.wire import control_messages
from coordinator.api import AssetProgress, NodeState
from coordinator.assets import AssetStore
from rigctl.commands import status_dict
from coordinator.distribution import note_ready
from coordinator.rig import Rig, grid_slots, init_rig
from coordinator.app import CoordinatorApp
from coordinator.sessions import Heartbeat, NodeInfo, Report

MS = 1_000_000


def still(path, seed):
    path.parent.mkdir(parents=True, exist_ok=True)
    np.save(path, np.random.default_rng(seed).random((4, 4, 3), dtype=np.float32))
    return path


def test_note_ready_keeps_the_first_instant_and_forgets_an_asset_no_longer_ready():
    since: dict[str, float] = {}
    assert not note_ready(since, [AssetProgress("a"), AssetProgress("b")], 1.0) and since == {}
    assert note_ready(since, [AssetProgress("a", ready=True), AssetProgress("b")], 2.0) and since == {"a": 2.0}
    assert not note_ready(since, [AssetProgress("a", ready=True)], 3.0) and since == {"a": 2.0}
    assert note_ready(since, [AssetProgress("a"), AssetProgress("b", ready=True)], 4.0) and since == {"b": 4.0}
    assert note_ready(since, [AssetProgress("a", ready=True), AssetProgress("b", ready=True)], 5.0)
    assert since == {"a": 5.0, "b": 4.0}


def test_live_and_ready_ages_on_the_injected_clock(tmp_path):
    rig = Rig(init_rig(tmp_path / "rig", name="t", slots=grid_slots(1, 2), width=32, height=32,
                       content_width=32, content_height=32))
    store = AssetStore(rig.path)
    a = store.add(still(tmp_path / "src" / "a.npy", 0), name="a")
    b = store.add(still(tmp_path / "src" / "b.npy", 1), name="b")
    now = [7_000 * MS]

    def hb(*ready_ids, partial=()):
        return Report(heartbeat=Heartbeat(assets=tuple(AssetProgress(aid, ready=True) for aid in ready_ids)
                                          + tuple(AssetProgress(aid, have_bytes=1) for aid in partial)))

    def nodes(coord):
        return {n.slot: n for n in coord.status().nodes}

    async def go():
        coord = CoordinatorApp(rig, b"x" * 32, advertise=False, clock_ns=lambda: now[0]).coordinator
        coord.distribution.load()
        s = coord.join(slot="r0c0", info=NodeInfo(), peer="test")
        n = nodes(coord)
        assert n["r0c0"].state == NodeState.JOINED and math.isnan(n["r0c0"].live_age_ms)
        assert math.isnan(n["r0c1"].live_age_ms) and all(math.isnan(p.ready_age_ms) for p in n["r0c1"].assets)

        now[0] += 40 * MS
        coord.on_report(s, hb(partial=(a.asset_id, b.asset_id)))        # the first report: live
        now[0] += 250 * MS
        n = nodes(coord)["r0c0"]
        assert n.state == NodeState.LIVE and n.live_age_ms == 250.0
        assert [p.name for p in n.assets] == ["a", "b"] and all(math.isnan(p.ready_age_ms) for p in n.assets)

        coord.on_report(s, hb(a.asset_id, partial=(b.asset_id,)))        # a ready
        now[0] += 100 * MS
        coord.on_report(s, hb(a.asset_id, partial=(b.asset_id,)))        # still ready: the instant stays
        coord.on_report(s, Report())                                     # swaps only: nothing changes
        now[0] += 20 * MS
        n = nodes(coord)["r0c0"]
        assert n.live_age_ms == 370.0
        assert [p.ready_age_ms for p in n.assets[:1]] == [120.0] and math.isnan(n.assets[1].ready_age_ms)

        coord.on_report(s, hb(a.asset_id, b.asset_id))                   # b ready too
        now[0] += 5 * MS
        n = nodes(coord)["r0c0"]
        assert [p.ready_age_ms for p in n.assets] == [125.0, 5.0] and n.assets_ready == 2

        # through the wire and the JSON the operator's command prints
        back = control_messages.status_from_message(control_messages.status_message(coord.status()))
        got = {x.slot: x for x in back.nodes}
        assert got["r0c0"].live_age_ms == 375.0 and [p.ready_age_ms for p in got["r0c0"].assets] == [125.0, 5.0]
        assert math.isnan(got["r0c1"].live_age_ms) and all(math.isnan(p.ready_age_ms) for p in got["r0c1"].assets)
        d = {x["slot"]: x for x in status_dict(back)["nodes"]}
        assert d["r0c0"]["live_age_ms"] == 375.0 and d["r0c1"]["live_age_ms"] is None
        assert [i["ready_age_ms"] for i in d["r0c0"]["assets"]["items"]] == [125.0, 5.0]
        assert [i["ready_age_ms"] for i in d["r0c1"]["assets"]["items"]] == [None, None]

        # a rejoin starts over: joined (no live age) until its first report, readiness as seen anew
        s2 = coord.join(slot="r0c0", info=NodeInfo(), peer="test")
        n = nodes(coord)["r0c0"]
        assert n.state == NodeState.JOINED and math.isnan(n.live_age_ms)
        now[0] += 10 * MS
        coord.on_report(s2, hb(a.asset_id, b.asset_id))
        now[0] += 30 * MS
        n = nodes(coord)["r0c0"]
        assert n.live_age_ms == 30.0 and [p.ready_age_ms for p in n.assets] == [30.0, 30.0]
        assert set(coord.live_at) == set(coord.ready_at) == {s2.session}

        # a lost node has no live age any more
        now[0] += rig.config.lost_after_ms * MS + MS
        coord.sweep()
        n = nodes(coord)["r0c0"]
        assert n.state == NodeState.LOST and math.isnan(n.live_age_ms)

    asyncio.run(go())
