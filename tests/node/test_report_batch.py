"""node/report_batch.py: what the report stream sends and when, with the time passed in.

Every test gives the batcher the instants it chooses (seconds), so the rules are checked exactly,
with no event loop, clock or sleep: heartbeats at their period, news at once and the period
restarted, streamed frames within the short batch, timeline ticks with the heartbeat, a heartbeat
due within a few milliseconds riding along with a batch, the newest preview only.
"""
from __future__ import annotations

import math

import pytest

from node.records import DropReason, DropRecord, PreviewRecord, SwapRecord
from node.report_batch import RIDE_ALONG_S, ReportBatcher


class Beats:
    """The heartbeat callable: counts the heartbeats built (one per message that carries one)."""

    def __init__(self):
        self.built = 0

    def __call__(self):
        self.built += 1
        return f"hb{self.built}"


def swap(frame_id: int, *, timeline: bool = False) -> SwapRecord:
    return SwapRecord(frame_id, 0, 0, 0, timeline=timeline)


def test_heartbeats_come_at_once_then_at_their_period():
    b, beats = ReportBatcher(1.0), Beats()
    assert b.next_due() == -math.inf                     # the session's first heartbeat: at once
    first = b.poll(100.0, beats)
    assert first.heartbeat == "hb1" and first.swaps == () and first.drops == ()
    assert b.next_due() == 101.0
    assert b.poll(100.999, beats) is None and beats.built == 1
    assert b.poll(101.0, beats).heartbeat == "hb2"
    assert b.next_due() == 102.0


def test_news_sends_one_heartbeat_at_once_and_restarts_the_period():
    b, beats = ReportBatcher(1.0), Beats()
    b.poll(0.0, beats)
    b.want_heartbeat()
    b.want_heartbeat()                                   # twice in one instant: one heartbeat
    assert b.next_due() == -math.inf
    assert b.poll(0.3, beats).heartbeat == "hb2"
    assert b.poll(0.3, beats) is None
    assert b.next_due() == pytest.approx(1.3)            # a full period after the extra one
    assert b.poll(1.0, beats) is None
    assert b.poll(1.3, beats).heartbeat == "hb3"


def test_a_streamed_frame_goes_within_the_batch_with_what_follows_it():
    b, beats = ReportBatcher(1.0, batch_s=0.05), Beats()
    b.poll(0.0, beats)
    assert b.add(swap(1), 0.2) is True                   # the next message moved forward: wake the sender
    assert b.next_due() == pytest.approx(0.25)
    assert b.add(swap(2), 0.22) is False                 # already due by then: nothing to wake for
    assert b.add(DropRecord(3, DropReason.LATE, 7), 0.23) is False
    assert b.pending == 3
    assert b.poll(0.249, beats) is None
    batch = b.poll(0.25, beats)
    assert batch.heartbeat is None and [s.frame_id for s in batch.swaps] == [1, 2]
    assert batch.drops == (DropRecord(3, DropReason.LATE, 7),)
    assert b.pending == 0 and b.next_due() == 1.0 and beats.built == 1


def test_timeline_ticks_travel_with_the_next_heartbeat():
    b, beats = ReportBatcher(1.0, batch_s=0.05), Beats()
    b.poll(0.0, beats)
    for k in range(5):
        assert b.add(swap(100 + k, timeline=True), 0.1 + 0.1 * k) is False   # never a wake-up of its own
    assert b.next_due() == 1.0
    assert b.poll(0.99, beats) is None
    hb = b.poll(1.0, beats)
    assert hb.heartbeat == "hb2" and [s.frame_id for s in hb.swaps] == [100, 101, 102, 103, 104]


def test_timeline_ticks_wait_at_most_their_batch_when_the_heartbeat_is_further():
    b, beats = ReportBatcher(10.0, batch_s=0.05, timeline_batch_s=0.5), Beats()
    b.poll(0.0, beats)
    assert b.add(swap(7, timeline=True), 1.0) is True
    assert b.next_due() == 1.5
    batch = b.poll(1.5, beats)
    assert batch.heartbeat is None and [s.frame_id for s in batch.swaps] == [7]


def test_a_streamed_frame_takes_the_waiting_ticks_along_in_order():
    b, beats = ReportBatcher(1.0, batch_s=0.01, timeline_batch_s=5.0), Beats()
    b.poll(0.0, beats)
    b.add(swap(105, timeline=True), 0.1)
    b.add(DropRecord(106, DropReason.LATE, timeline=True), 0.1)
    b.add(swap(900), 0.12)                               # a still: it goes at once, with the ticks before it
    batch = b.poll(0.13, beats)
    assert batch.heartbeat is None and [s.frame_id for s in batch.swaps] == [105, 900]
    assert [d.frame_id for d in batch.drops] == [106]


def test_a_heartbeat_due_within_the_ride_along_goes_with_the_batch():
    b, beats = ReportBatcher(1.0, batch_s=0.05), Beats()
    b.poll(0.0, beats)
    b.add(swap(1), 1.0 - 0.05 - RIDE_ALONG_S / 2)        # its batch is due just before the heartbeat
    batch = b.poll(1.0 - RIDE_ALONG_S / 2, beats)
    assert batch.heartbeat == "hb2" and [s.frame_id for s in batch.swaps] == [1]
    assert b.next_due() == pytest.approx(2.0 - RIDE_ALONG_S / 2)

    b.add(swap(2), 1.5)                                  # further from the heartbeat: alone
    batch = b.poll(1.55, beats)
    assert batch.heartbeat is None and [s.frame_id for s in batch.swaps] == [2]


def test_a_preview_goes_like_a_streamed_frame_and_only_the_newest():
    b, beats = ReportBatcher(1.0, batch_s=0.02), Beats()
    b.poll(0.0, beats)
    old = PreviewRecord(request_id=1, frame_id=3, png=b"a", width=1, height=1, output_width=1, output_height=1)
    new = PreviewRecord(request_id=2, frame_id=4, png=b"b", width=1, height=1, output_width=1, output_height=1)
    assert b.add(old, 0.5) is True
    b.add(new, 0.51)
    batch = b.poll(0.52, beats)
    assert batch.preview == new and batch.swaps == () and batch.heartbeat is None


def test_the_heartbeat_interval_must_be_positive():
    with pytest.raises(ValueError, match="heartbeat interval"):
        ReportBatcher(0.0)
