"""Which slots hold a trial back (the trial loop itself runs on a real rig in test_run_rig.py)."""
from __future__ import annotations

from coordinator.api import NodeState, NodeStatus, RigStatus
from studies.runner import not_ready


def test_a_trial_waits_for_slots_that_are_not_live_or_have_no_pose():
    st = RigStatus("id", "rig", nodes=(NodeStatus("a", NodeState.LIVE, pose_kind="homography"),
                                       NodeStatus("b", NodeState.LOST, pose_kind="homography"),
                                       NodeStatus("c", NodeState.LIVE, pose_kind="none")))
    assert not_ready(st, ["a", "b", "c", "d"]) == ["b", "c", "d"]
    assert not_ready(st, ["a"]) == []

