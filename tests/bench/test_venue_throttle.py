"""bench/venue_throttle.py: the sampler sees a group's throttle counter grow (read from a real file that
stands in for the group's cpu.stat, which only root can make), and a node's missed ticks are sorted
into decode, throttled, unthrottled and not dropped from its log's drops and the sampler's instants."""
from __future__ import annotations

import os
import time

from bench.venue_throttle import ThrottleSampler, drops, miss_causes, throttles_per_s
from waits import wait_until

PERIOD = 33_333_333


def _stat(n: int) -> str:
    return f"nr_periods {10 * n}\nnr_throttled {n}\nthrottled_time {n * 1000}\n"


def _rewrite(path, text: str) -> None:
    """The file's text replaced in one write at its start, never truncated first: a kernel makes a
    cgroup file afresh at each read, and a truncate-then-write (write_text) let the sampler read the
    empty file between the two, which it counts as unreadable, so the growth across it went unseen."""
    data = text.encode()
    fd = os.open(path, os.O_WRONLY)
    try:
        assert os.pwrite(fd, data, 0) == len(data)
    finally:
        os.close(fd)


def test_the_sampler_keeps_the_instants_at_which_the_throttle_count_grew(tmp_path):
    stat = tmp_path / "cpu.stat"
    stat.write_text(_stat(3))
    with ThrottleSampler({"r0c0": stat}, period_s=0.002) as s:
        wait_until(lambda: s.samples, lambda n: n >= 3, what="three samples")
        assert s.events["r0c0"] == []               # the count it started with is no throttle
        before = time.monotonic_ns()
        _rewrite(stat, _stat(5))                    # as long as the text before: no stale tail
        wait_until(lambda: list(s.events["r0c0"]), lambda ev: len(ev) == 1, what="the growth seen once")
    t = s.events["r0c0"][0]
    assert t >= before
    assert s.throttled_between("r0c0", before, t) and not s.throttled_between("r0c0", 0, before - 1)
    assert not s.throttled_between("other", 0, t)
    assert throttles_per_s(s, "r0c0", t, t + 1_000_000_000) == 1.0
    assert s.cpu_s > 0                               # its own CPU, for the document


def test_a_group_file_that_cannot_be_read_is_no_throttle(tmp_path):
    stat = tmp_path / "cpu.stat"
    stat.write_text(_stat(1))
    with ThrottleSampler({"r0c0": stat, "gone": tmp_path / "missing"}, period_s=0.002) as s:
        for text in ("nr_periods 3\n", _stat(4)):    # no nr_throttled line: not counted either way
            seen = s.samples
            wait_until(lambda: s.samples, lambda n: n >= seen + 2, what="two samples")   # one read the text before
            stat.write_text(text)
        seen = s.samples
        wait_until(lambda: s.samples, lambda n: n >= seen + 2, what="two samples after the last")
    assert s.events == {"r0c0": [], "gone": []}


def test_missed_ticks_are_sorted_by_cause(tmp_path):
    log = ("x INFO node r0c0 node.presenter: timing frame 11: dropped (late) -1.341 ms late\n"
           "x INFO node r0c0 node.presenter: timing frame 12: dropped (late) 15.073 ms late\n"
           "x INFO node r0c0 node.presenter: timing frame 13: dropped (late) 3.500 ms late\n"
           "x INFO node r0c0 node.presenter: timing frame 14: swap 0.066 ms after deadline\n")
    d = drops(log)
    assert d == {11: -1.341, 12: 15.073, 13: 3.5}
    instant = lambda t: t * PERIOD  # noqa: E731
    stat = tmp_path / "cpu.stat"
    stat.write_text(_stat(0))
    s = ThrottleSampler({"r0c0": stat})
    s.events["r0c0"] = [instant(12) - PERIOD // 2]          # held back half a tick before tick 12's instant
    causes = miss_causes([11, 12, 13, 15], instant, PERIOD, d, s, "r0c0")
    assert causes == {"decode": 1, "throttled": 1, "unthrottled": 1, "not_dropped": 1}
    # without a sampler a late drop of the presenter's is not told apart
    assert miss_causes([12, 13], instant, PERIOD, d, None, "r0c0")["unthrottled"] == 2
