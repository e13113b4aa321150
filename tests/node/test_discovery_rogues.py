"""Real nodes, unpinned as the shipped node.env runs them, join their own rig while a twin (same
name and id, another token) and another rig advertise from the start; none is captured."""
from __future__ import annotations

from bench.discovery import trial


def test_nodes_turned_away_by_rogues_join_their_rig_when_it_comes(tmp_path):
    # the rig's own coordinator starts only once every node has asked a rogue and been turned away
    rec = trial(tmp_path, 3, rogues=True, real_late=True, timeout=180)
    assert rec["joined"] == 3 and rec["captured"] == 0, rec
    assert rec["tried_rogue"] == 3
    assert rec["remembered_rig"] == 3, "each node keeps the id of the rig it joined, for its next start"
