"""Real nodes join their rig while a hostile advertiser claims the rig's mDNS name without conflict
probing and points at a tarpit (a port that accepts and never answers): every node tries every
(address, port) that answered for the name, the tarpit costs at most one short timeout, and all of
them join the real coordinator, on loopback and on a virtual venue network; an operator's
`status --rig-dir` over mDNS reaches it too. The times go to the
test report (``record_property``); ``shadowless bench discovery --hostile`` measures them with 16.

Two nodes a trial (four before): a node asks every coordinator advertised for the name at once,
the tarpit included, whichever answers first, so each node takes the path under test by itself;
a second node shows that one node's join does not stand in for another's."""
from __future__ import annotations

import pytest

from bench.discovery import hostile_trial

NODES = 2


@pytest.mark.parametrize("when", ["after", "before"])
def test_nodes_join_past_a_hostile_same_name_advertiser_on_loopback(tmp_path, record_property, when):
    # after: two responders share one instance name; before: the coordinator renamed itself
    rec = hostile_trial(tmp_path, NODES, venue=False, when=when, timeout=60)
    record_property("hostile_trial", rec)
    assert rec["joined"] == rec["started"] == NODES, rec
    assert rec["renamed"] is (when == "before"), rec
    assert rec["operator_found_rig"], rec
    # a name taken after the coordinator claimed it is logged there (a renamed one has its own)
    assert rec["coordinator_saw_hostile"] is (when == "after"), rec


def test_nodes_join_past_a_hostile_same_name_advertiser_in_the_venue(ns, tmp_path, record_property):
    rec = hostile_trial(tmp_path, NODES, venue=True, when="after", timeout=60)
    record_property("hostile_trial", rec)
    assert rec["joined"] == rec["started"] == NODES, rec
    assert rec["operator_found_rig"], rec
