"""A blend switch on a still is made ready during the switch's lead and shown at its instant.

The frame on screen is rendered again with the new maps (and finished) before the common instant,
then only swapped in at it: not before, and not never. What the output received and when is
recorded at each swap and compared with the numpy reference, and the node's log line of that swap
says when the frame was ready (before the instant), which a failover's stages read.
"""
from __future__ import annotations

import logging
import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_presenter_blend import (MS, SlowPrepare, assignment, blended, close, maps,  # noqa: E402
                                  rig)  # noqa: F401  (rig: the fixture, a presenter on the test's clock)


class Recording(SlowPrepare):
    """A slow output that records, at each swap, the rig instant the test's clock says and the picture,
    and when each frame was ready (its prepare done)."""

    def __init__(self, host, rig_now, **kwargs):
        super().__init__(host, **kwargs)
        self.rig_now = rig_now
        self.swaps: list[tuple[int, np.ndarray]] = []
        self.ready: list[int] = []

    def prepare(self, renderer) -> None:
        super().prepare(renderer)
        self.ready.append(self.rig_now())

    def after_swap(self, renderer, info) -> None:
        super().after_swap(renderer, info)
        self.swaps.append((self.rig_now(), self.last_image.copy()))


def test_the_still_with_new_maps_is_ready_before_the_instant_and_swapped_in_at_it(rig, caplog):
    rig.out = rig.p.out = Recording(rig.host, rig.rig_now, slot="r0c0", keep_last=True)
    rig.out.prepare_ns = 30 * MS                     # a slow GPU: 30 ms to finish a frame
    rig.frame(1, rig.rig_now() + 100 * MS)
    plain = blended(None)
    assert (rig.shown() == plain).all()
    m = maps(11)
    at = rig.rig_now() + 300 * MS
    rig.p.handle("assignment", assignment(2, m, at))
    swaps_before = len(rig.out.swaps)
    with caplog.at_level(logging.INFO, logger="node.presenter"):
        for _ in range(10):                          # the presenter's loop: wait as told, then step
            wait = rig.p.timeline_wait()
            if wait is None:
                break
            rig.host.t += int(wait * 1e9)
            rig.p.timeline_step()
    new = rig.out.swaps[swaps_before:]
    assert len(new) == 1, f"the still is swapped in once with the maps, got {len(new)} swaps"
    when, image = new[0]
    assert when == at, f"swapped in {(when - at) / 1e6:+.1f} ms from the instant"
    close(image, blended(m))
    assert not (image == plain).all()
    ready = rig.out.ready[-1]
    assert ready < at, "the frame with the maps was finished ahead of the instant, not at it"
    line = re.search(r"on screen from rig instant (\d+); timing instant=(\d+) .* ready=(\d+) swapped=(\d+)", caplog.text)
    assert line is not None, caplog.text
    shown, instant, ready_logged, swapped = (int(v) for v in line.groups())
    assert shown == instant == at and ready_logged == ready < at <= swapped
    assert (rig.status.blend_id, rig.status.blend_since_rig_ns) == (m.blend_id, at)


def test_maps_that_come_after_their_instant_are_shown_at_once_and_say_they_were_late(rig, caplog):
    rig.out = rig.p.out = Recording(rig.host, rig.rig_now, slot="r0c0", keep_last=True)
    rig.frame(1, rig.rig_now() + 10 * MS)
    m = maps(12)
    at = rig.rig_now() - 5 * MS                      # the instant has passed when the maps arrive
    rig.out.prepare_ns = 4 * MS
    with caplog.at_level(logging.INFO, logger="node.presenter"):
        rig.p.handle("assignment", assignment(2, m, at))
    when, image = rig.out.swaps[-1]
    close(image, blended(m))
    assert when > at and rig.status.blend_since_rig_ns == when
    line = re.search(r"timing instant=(\d+) .* ready=(\d+) swapped=(\d+)", caplog.text)
    assert line is not None and int(line.group(2)) > int(line.group(1)), "ready after the instant: late"


def test_a_still_is_rendered_again_as_soon_as_its_maps_arrive_and_held_until_their_instant(rig):
    """Nodes that share cores render in turn: a still's redraw starts when the maps arrive (up to
    BLEND_EARLY_NS ahead), not PREPARE_NS before the instant, so the last in the queue is still on time."""
    rig.out = rig.p.out = Recording(rig.host, rig.rig_now, slot="r0c0", keep_last=True)
    rig.out.prepare_ns = 5 * MS
    rig.frame(1, rig.rig_now() + 20 * MS)
    m = maps(13)
    arrived = rig.rig_now()
    at = arrived + 120 * MS                          # a failover's lead: more than PREPARE_NS
    rig.p.handle("assignment", assignment(2, m, at))
    swaps_before = len(rig.out.swaps)
    wait = rig.p.timeline_wait()
    assert wait == 0, f"the redraw waits {wait * 1e3:.1f} ms after the maps arrived"
    rig.p.timeline_step()
    new = rig.out.swaps[swaps_before:]
    assert [when for when, _ in new] == [at], "swapped in once, at the instant"
    close(new[0][1], blended(m))
    assert rig.out.ready[-1] - arrived <= 5 * MS < at - rig.out.ready[-1], "ready as soon as the maps came"
    assert rig.p.timeline_wait() is None and rig.status.blend_since_rig_ns == at
