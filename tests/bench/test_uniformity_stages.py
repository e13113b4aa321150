"""`bench uniformity`'s failover stages read what a node writes: the log line of a node's first swap with
new blend maps (node/blend_switch.py, made here by a real BlendSwitch) becomes the stages, the frame's
readiness against the common instant included (before it: the node only waited; after it: late)."""
from __future__ import annotations

import logging
from types import SimpleNamespace

import numpy as np

from bench.uniformity_live import _stages
from node.blend_switch import BlendSwitch
from node.records import NodeAssignment
from protos.blend import BlendMaps

MS = 1_000_000


class Renderer:
    """What a blend switch asks of the renderer."""

    def __init__(self):
        self.blend_id = ""

    def load_blend(self, maps) -> None:
        pass

    def set_blend(self, maps) -> None:
        self.blend_id = maps.blend_id if maps is not None else ""


def node_line(caplog, maps: BlendMaps, at: int, stamps: dict[str, int]) -> str:
    """The log line a node writes when it first shows ``maps`` (instant ``at``), its way there at ``stamps``
    (rig ns; the host clock is the rig clock here)."""
    host = [stamps["presenter"]]
    switch = BlendSwitch(lambda: host[0], lambda h, est: h)
    a = NodeAssignment(revision=2, slot="s", width=8, height=8, pose_kind="none", homography=None, projection=None,
                       mesh=None, near_mm=1.0, far_mm=2.0, lut=None, gain=1.0, content_size=(8, 8), blend=maps,
                       blend_at_ns=at, received_host_ns=stamps["received"], decoded_host_ns=stamps["decoded"])
    r = Renderer()
    host[0] = stamps["uploaded"]
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="node.presenter"):
        assert not switch.offer(r, a, at - 50 * MS, stamps["presenter"])
        switch.switch(r)
        host[0] = stamps["ready"]
        switch.ready()
        host[0] = stamps["swapped"]
        switch.shown(r.blend_id, stamps["shown"], estimate=object())
    return caplog.text


def two_nodes():
    """Maps, the set and instant of a switch, and the stamps of a node in time and of one 21 ms late."""
    maps = BlendMaps(np.full((2, 2, 3), 0.5, np.float32), np.zeros((2, 2), np.float32))
    set_ns, at = 1_000 * MS, 1_080 * MS
    early = dict(received=1_010 * MS, decoded=1_011 * MS, presenter=1_012 * MS, uploaded=1_013 * MS,
                 ready=1_040 * MS, shown=at, swapped=at + 1 * MS)
    late = dict(received=1_050 * MS, decoded=1_051 * MS, presenter=1_060 * MS, uploaded=1_061 * MS,
                ready=1_100 * MS, shown=1_101 * MS, swapped=1_101 * MS)
    return maps, set_ns, at, early, late


def test_the_stages_follow_each_node_from_the_coordinator_to_its_swap(caplog):
    maps, set_ns, at, early, late = two_nodes()
    logs = {"node-a": node_line(caplog, maps, at, early), "node-b": node_line(caplog, maps, at, late)}
    state = SimpleNamespace(last_switch={"wanted": set_ns, "ready": set_ns, "set": set_ns, "instant": at})
    live = SimpleNamespace(core=SimpleNamespace(blending=state), slot_blend_id=lambda s: maps.blend_id,
                           local=SimpleNamespace(log=lambda name: logs[name]))
    st = _stages(live, ["a", "b"], declared_ns=990 * MS, reported={"a": at + 5 * MS})
    assert st["nodes"] == 2
    assert st["set_to_received"] == {"min": 10.0, "p50": 30.0, "max": 50.0}
    assert st["uploaded_to_rendered"] == {"min": 27.0, "p50": 33.0, "max": 39.0}
    assert st["rendered_to_instant"] == {"min": -20.0, "p50": 10.0, "max": 40.0}, "b's frame was ready 20 ms late"
    assert st["wanted_to_ready"]["max"] == 0.0 and st["ready_to_set"]["max"] == 0.0, "the coordinator's own stamps"
    assert st["instant_to_shown"]["max"] == 21.0 and st["declared_to_shown"]["max"] == 111.0
    assert st["swapped_to_reported"] == {"min": 4.0, "p50": 4.0, "max": 4.0}


def test_the_switch_benchmark_reads_each_switch_from_the_same_lines(caplog):
    """bench.uniformity_switch repeats a failover's switch: per switch (the lines of its instant alone), the last
    node's delay past the instant, the arrivals after the set, and what a failover with that lead would score."""
    from bench.uniformity_switch import _summary, _switch_way
    maps, set_ns, at, early, late = two_nodes()
    other = dict(early, shown=at + 500 * MS)       # a line of another switch (instant) is left out
    logs = {"node-a": node_line(caplog, maps, at, early),
            "node-b": node_line(caplog, maps, at + 1, other) + node_line(caplog, maps, at, late)}
    way = _switch_way(SimpleNamespace(log=lambda name: logs[name]), ["a", "b"], at, set_ns)
    assert way["nodes"] == 2 and way["late_nodes"] == 1
    assert way["last_after_instant_ms"] == 21.0
    assert way["set_to_received_by_slot"] == {"a": 10.0, "b": 50.0} and way["received_max_ms"] == 50.0
    assert way["rendered_before_instant_min_ms"] == -20.0
    s = _summary([way, dict(way, last_after_instant_ms=0.0), {}], lead_ms=80.0, frame_ms=1e3 / 30)
    assert s["switches_read"] == 2
    f = s["frames_at_lead"]      # (80 + 21) / 33.3 and 80 / 33.3 frames
    assert (f["max"], f["within_3"]) == (3.03, 1) and abs(f["p50"] - 2.715) <= 0.006
