"""Real nodes join their rig while a hostile advertiser claims the rig's mDNS name without conflict
probing and points at a tarpit (a port that accepts and never answers): every node tries every
(address, port) that answered for the name, the tarpit costs at most one short timeout, and all of
them join the real coordinator, on loopback and on a virtual venue network; an operator's
`status --rig-dir` over mDNS reaches it too. The times go to the
test report (``record_property``); ``shadowless bench discovery --hostile`` measures them with 16."""
from __future__ import annotations

import pytest

from bench.discovery import hostile_trial


@pytest.mark.parametrize("when", ["after", "before"])
def test_nodes_join_past_a_hostile_same_name_advertiser_on_loopback(tmp_path, record_property, when):
    # after: two responders share one instance name; before: the coordinator renamed itself
    rec = hostile_trial(tmp_path, 4, venue=False, when=when, timeout=60)
    record_property("hostile_trial", rec)
    assert rec["joined"] == rec["started"] == 4, rec
    assert rec["renamed"] is (when == "before"), rec
    assert rec["operator_found_rig"], rec
    # a name taken after the coordinator claimed it is logged there (a renamed one has its own)
    assert rec["coordinator_saw_hostile"] is (when == "after"), rec


def test_nodes_join_past_a_hostile_same_name_advertiser_in_the_venue(ns, tmp_path, record_property):
    rec = hostile_trial(tmp_path, 4, venue=True, when="after", timeout=60)
    record_property("hostile_trial", rec)
    assert rec["joined"] == rec["started"] == 4, rec
    assert rec["operator_found_rig"], rec
