"""The node's book of advertised coordinators: every one tried, the known rig first, own backoffs."""
from __future__ import annotations

import random

from node.targets import Candidate, TargetBook, read_known_rig, write_known_rig

OURS = Candidate("10.0.0.2:7600", "rig-ours", "table")
ROGUE = Candidate("10.0.0.9:7600", "rig-other", "other")
TWIN = Candidate("10.0.0.8:7600", "rig-ours", "table")      # claims our id (cannot prove our token)


def test_the_known_rig_goes_first_and_the_rest_in_varying_order():
    book = TargetBook(known_rig="rig-ours", rng=random.Random(1))
    orders = {tuple(c.target for c in book.order([ROGUE, TWIN, OURS], now=0.0)) for _ in range(40)}
    assert all(set(o[:2]) == {OURS.target, TWIN.target} and o[2] == ROGUE.target for o in orders)
    assert len(orders) == 2, "the two candidates of the known rig come in both orders"

    fresh = TargetBook(rng=random.Random(2))
    firsts = {fresh.order([ROGUE, OURS], now=0.0)[0] for _ in range(40)}
    assert firsts == {ROGUE, OURS}, "no advertiser can always go first"


def test_a_refusal_backs_off_that_target_only():
    book = TargetBook(refusal_s=10.0, rng=random.Random(3))
    assert book.refused(ROGUE, "not trusted", now=100.0) is True
    assert book.refused(ROGUE, "not trusted", now=100.0) is False, "the same reason again is not news"
    assert book.order([ROGUE, OURS], now=105.0) == [OURS]
    assert book.next_due([ROGUE], now=105.0) == 5.0
    assert set(book.order([ROGUE, OURS], now=110.0)) == {ROGUE, OURS}


def test_unreachable_targets_back_off_exponentially_up_to_the_cap():
    book = TargetBook(unreachable_min_s=0.2, unreachable_max_s=5.0, rng=random.Random(4))
    waits = []
    for _ in range(8):
        book.unreachable(OURS, "UNAVAILABLE", now=0.0)
        waits.append(book.next_due([OURS], now=0.0))
    assert all(0.8 * 0.2 * 2 ** i <= w <= 1.2 * 0.2 * 2 ** i for i, w in enumerate(waits[:4]))
    assert all(4.0 <= w <= 6.0 for w in waits[5:])
    book.joined(OURS, "rig-ours")
    assert book.order([OURS], now=0.0) == [OURS], "a join clears the target's backoff"


def test_a_join_records_the_rig_and_absent_targets_are_forgotten():
    book = TargetBook()
    assert book.joined(OURS, "rig-ours") is True
    assert book.joined(OURS, "rig-ours") is False
    book.refused(ROGUE, "slot taken", now=0.0)
    book.forget_absent([OURS])
    assert book.order([ROGUE], now=0.0) == [ROGUE]


def test_the_known_rig_survives_a_restart_and_garbage_is_ignored(tmp_path):
    path = tmp_path / "cache" / "joined-rig"
    assert read_known_rig(path) == ""
    write_known_rig(path, "rig-ours")
    assert read_known_rig(path) == "rig-ours"
    path.write_bytes(b"\x00\xff" * 10)
    assert read_known_rig(path) == ""
    path.write_text("x" * 500)
    assert read_known_rig(path) == ""
