"""`shadowless status` speaks in human times and counts: a node's last swap as the frame of the
show it follows, the clock time and how long ago (not a frame id of sixteen digits), the uptime in
minutes and hours, and "1 projector" but "3 projectors"."""
from __future__ import annotations

import time

from coordinator.api import NodeShow, NodeShowState, NodeState, NodeStatus, RigStatus
from protos.wording import ago, count, duration, wall_time
from rigctl.commands import last_swap_cell, status_dict, status_table


def test_counts_durations_and_ages_read_as_an_operator_says_them():
    assert [count(n, "projector") for n in (0, 1, 3)] == ["0 projectors", "1 projector", "3 projectors"]
    assert count(2, "capture") == "2 captures" and count(1, "entry") == "1 entry" and count(2, "entry") == "2 entries"
    assert [duration(s) for s in (0.23, 42.4, 61, 3725, 90061)] == ["0.2 s", "42 s", "1 min 1 s", "1 h 2 min", "1 d 1 h"]
    assert ago(0.2) == "0.2 s ago" and ago(float("nan")) == "-"
    noon = time.mktime((2026, 12, 6, 14, 2, 3, 0, 0, -1))
    assert wall_time(noon, now=noon + 5) == "14:02:03"
    assert wall_time(noon, now=noon + 86400 * 2) == "Dec 06 14:02:03"


def test_the_last_swap_is_a_frame_a_clock_time_and_an_age():
    now = time.mktime((2026, 12, 6, 14, 2, 3, 0, 0, -1)) + 0.2
    playing = NodeStatus(slot="a", state=NodeState.LIVE, last_swap_frame=1796527603756874, last_swap_age_ms=200.0,
                         show=NodeShow(state=NodeShowState.PLAYING, last_frame=123))
    streamed = NodeStatus(slot="b", state=NodeState.LIVE, last_swap_frame=1796527603756874, last_swap_age_ms=4200.0)
    never = NodeStatus(slot="c", state=NodeState.EXPECTED)
    st = RigStatus(rig_id="r", rig_name="hall", instance_id="i", uptime_s=3725.0, nodes=(playing, streamed, never))
    d = status_dict(st, now=now)
    a, b, c = d["nodes"]
    assert a["last_swap_frame"] == 1796527603756874 and abs(a["last_swap_at"] - (now - 0.2)) < 1e-3   # JSON: both
    assert last_swap_cell(a, now=now) == "frame 123 at 14:02:03, 0.2 s ago"
    assert last_swap_cell(b, now=now) == "at 14:01:59, 4.2 s ago"
    assert last_swap_cell(c, now=now) == "-" and c["last_swap_at"] is None
    text = status_table(d)
    assert "up 1 h 2 min" in text.splitlines()[0] and "1796527603756874" not in text


def test_unmeasured_clocks_read_as_none_and_a_node_that_stopped_reads_left():
    """An expected slot (no node has joined) has no clock offset, drift or round trip: the table
    says "-", not 0.000 ms, which reads as a perfectly synchronised projector (and a drift of
    -0.04 ppm reads 0.0, not -0.0). A node that stopped on purpose reads "left" with its reason, as
    the coordinator's log and the console say, not "lost", and its last clock figures no longer hold:
    "-" too."""
    live = NodeStatus(slot="a", state=NodeState.LIVE, clock_offset_ms=0.25, clock_drift_ppm=-0.04, clock_rtt_ms=1.2)
    never = NodeStatus(slot="b", state=NodeState.EXPECTED)
    gone = NodeStatus(slot="c", state=NodeState.LOST, hostname="h", clock_offset_ms=0.5, clock_drift_ppm=-0.04,
                      clock_rtt_ms=1.0, left="stopped (SIGTERM)")
    d = status_dict(RigStatus(rig_id="r", rig_name="hall", instance_id="i", nodes=(live, never, gone)))
    assert d["nodes"][2]["left"] == "stopped (SIGTERM)" and d["nodes"][0]["left"] is None
    lines = status_table(d).splitlines()
    rows = {line.split()[0]: line.split() for line in lines if line.split() and line.split()[0] in "abc"}
    assert rows["a"][1:6] == ["live", "-", "0.250", "0.0", "1.200"], rows["a"]      # host unknown; not "-0.0"
    assert rows["b"][1:6] == ["expected", "-", "-", "-", "-"], rows["b"]
    assert rows["c"][1:6] == ["left", "h", "-", "-", "-"], rows["c"]
    assert "c: left on purpose: stopped (SIGTERM)" in lines
