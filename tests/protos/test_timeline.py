"""The timeline's arithmetic against an independent reference (exact rationals), and its
changes (pause, resume, seek, loop, stop) as every node must apply them."""
from __future__ import annotations

import math
import random
from fractions import Fraction

import pytest

from protos.timeline import NS, Schedule, Timeline, TimelineError, as_rate


def reference_frame(tl: Timeline, t_ns: int) -> int | None:
    """Brute force with exact rationals: the period index is floor(elapsed seconds x rate)."""
    if t_ns < tl.anchor_ns:
        return None
    if tl.paused:
        return tl.anchor_frame
    k = tl.anchor_frame + math.floor(Fraction(t_ns - tl.anchor_ns, NS) * tl.rate)
    if k >= tl.frames:
        return k % tl.frames if tl.loop else None
    return k


@pytest.mark.parametrize("rate", [Fraction(30), Fraction(30000, 1001), Fraction(24000, 1001), Fraction(60), Fraction(25, 2)])
def test_frame_at_matches_exact_rationals_and_inverts_pts(rate):
    rng = random.Random(int(rate * 1000))
    for loop in (False, True):
        tl = Timeline("a" * 64, frames=1000, rate=rate, anchor_ns=5 * NS + 123, anchor_frame=17, loop=loop)
        for _ in range(2000):
            t = tl.anchor_ns + rng.randrange(-NS, 200 * NS)
            assert tl.frame_at(t) == reference_frame(tl, t)
        for tick in list(range(0, 50)) + [rng.randrange(0, 10**7) for _ in range(200)]:
            p = tl.pts(tick)
            assert tl.tick_at(p) == tick and tl.tick_at(p - 1) == tick - 1 if tick else tl.tick_at(p) == 0
            assert Fraction(p - tl.anchor_ns, NS) * rate >= tick > Fraction(p - 1 - tl.anchor_ns, NS) * rate


def test_an_ntsc_show_does_not_drift_over_hours():
    assert as_rate(29.97) == Fraction(30000, 1001) and as_rate("25") == 25 and as_rate(23.976) == Fraction(24000, 1001)
    tl = Timeline("v" * 64, frames=10**9, rate=as_rate(29.97), anchor_ns=0)
    three_hours = 3 * 3600 * NS
    assert tl.frame_at(three_hours) == 3 * 3600 * 30000 // 1001 == 323_676   # exact, whatever the show length
    assert tl.frame_at(tl.pts(323_676)) == 323_676 and tl.frame_at(tl.pts(323_676) - 1) == 323_675


def test_end_loop_pause_resume_and_seek():
    tl = Timeline("s" * 64, frames=10, rate=Fraction(10), anchor_ns=1_000)
    assert tl.frame_at(999) is None and tl.frame_at(1_000) == 0 and tl.frame_at(1_000 + NS - 1) == 9
    assert tl.frame_at(1_000 + NS) is None and tl.end_ns() == 1_000 + NS
    looping = Timeline("s" * 64, frames=10, rate=Fraction(10), anchor_ns=1_000, loop=True)
    assert looping.frame_at(1_000 + NS + NS // 10) == 1 and looping.end_ns() is None

    p = tl.paused_at(1_000 + 350_000_000)                 # frame 3 is on at 0.35 s: hold it
    assert p.paused and p.frame_at(10 * NS) == 3 and p.revision == tl.revision + 1
    assert p.frame_at(1_000 + 349_999_999) is None, "before its instant the pause is not in force"
    r = p.resumed_at(20 * NS)                              # frame 3 for one more period, then on
    assert [r.frame_at(20 * NS + k * NS // 10) for k in range(3)] == [3, 4, 5]
    s = r.seeked(8, 30 * NS)
    assert s.frame_at(30 * NS) == 8 and s.frame_at(30 * NS + NS // 5) is None
    with pytest.raises(TimelineError, match="cannot seek to frame 10"):
        r.seeked(10, 0)
    with pytest.raises(TimelineError):
        Timeline("x" * 64, frames=0, rate=Fraction(30), anchor_ns=0)
    assert Timeline.from_json(s.to_json()) == s


def test_schedule_switches_every_node_at_the_same_instant_and_keeps_the_newest():
    sch = Schedule()
    start = Timeline("a" * 64, frames=100, rate=Fraction(25), anchor_ns=10 * NS, revision=1)
    assert sch.offer(start) and sch.at(9 * NS) is None and sch.at(10 * NS) == start
    seek = start.seeked(50, 20 * NS)                        # announced early, in force at 20 s
    assert sch.offer(seek)
    assert sch.at(19 * NS) == start and sch.at(20 * NS) == seek
    assert not sch.offer(start), "a beacon repeating an older revision changes nothing"
    assert sch.offer_stop(30 * NS, seek.revision + 1)
    assert sch.at(29 * NS) == seek and sch.at(30 * NS) is None
    # a newer change at an earlier instant cancels what was pending after it
    pause = seek.paused_at(25 * NS)
    pause = Timeline.from_json({**pause.to_json(), "revision": seek.revision + 2})
    assert sch.offer(pause)
    assert sch.at(31 * NS) == pause, "the stop at 30 s was cancelled by the newer pause at 25 s"
    sch.forget_before(40 * NS)
    assert sch.pending == [(25 * NS, pause)]


def test_schedule_ticks_walk_every_change_in_order():
    """Ticks across a play, a pause, a stop and a short show that does not loop, checked against
    the instants written out by hand."""
    t0, ms = 10 * NS, NS // 1000
    s = Schedule()
    s.offer(Timeline(asset_id="a", frames=100, rate=Fraction(10), anchor_ns=t0, loop=True, revision=1))
    s.offer(Timeline(asset_id="a", frames=100, rate=Fraction(10), anchor_ns=t0 + 1000 * ms, anchor_frame=10,
                     paused=True, revision=2))
    s.offer_stop(t0 + 2000 * ms, 3)
    s.offer(Timeline(asset_id="b", frames=5, rate=Fraction(10), anchor_ns=t0 + 3000 * ms, revision=4))
    bases = {1: 100, 2: 200, 4: 400}
    expect = ([(100 + k, t0 + k * 100 * ms) for k in range(10)] + [(200, t0 + 1000 * ms)]
              + [(400 + k, t0 + 3000 * ms + k * 100 * ms) for k in range(5)])
    assert list(s.ticks(bases, t0 - 5 * ms, t0 + 10_000 * ms)) == expect
    assert list(s.ticks(bases, t0 - 5 * ms)) == expect                      # no end: the show's own end
    assert list(s.ticks(bases, t0 + 250 * ms, t0 + 450 * ms)) == expect[3:5]
    assert list(s.ticks({1: 100, 4: 400}, t0 + 950 * ms, t0 + 3050 * ms)) == [expect[11]]   # no base for r2
