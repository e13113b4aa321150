"""The presenter's blend switch, on a clock the test moves (a real renderer, an offscreen output).

An assignment's blend maps are uploaded ahead and shown from the first frame whose pts is at or
after their instant: streamed frames and a show's ticks alike; with a still on screen, the still is
shown again with them at that instant. What the output received is compared with the numpy
reference (:func:`protos.spaces.blended_output`), not with flags; a malformed blend is refused in
one log line and nothing on screen changes. A still held rendered for its maps' instant reads the
pipe: a stop or a frame read meanwhile is handled at once, a clock estimate after the swap.
"""
from __future__ import annotations

import logging
from dataclasses import replace
from fractions import Fraction

import numpy as np
import pytest
from waits import wait_until

from node.clock import ClockEstimate, LocalClock
from node.outputs import OffscreenOutput
from node.presenter import Presenter
from node.records import AssetFiles, FrameOrder, NodeAssignment, ShowUpdateData
from protos.asset_manifest import Blob, Manifest, sha256_hex
from protos.blend import BlendMaps
from protos.spaces import blended_output, quantise
from protos.timeline import Timeline

W, H = 32, 24
MS = 1_000_000
START_NS = 5_000_000_000_000
RIG_OFFSET_NS = 7_000 * MS
GREY = 0.5


class ManualClock:
    """Host time in ns that moves only when told to, or when someone sleeps on it."""

    def __init__(self):
        self.t = START_NS

    def __call__(self) -> int:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += max(1, round(seconds * 1e9))


def maps(seed: int) -> BlendMaps:
    rng = np.random.default_rng(seed)
    return BlendMaps(rng.random((6, 8, 3), dtype=np.float32), rng.random((6, 8), dtype=np.float32) * 0.2)


def assignment(revision: int, blend: BlendMaps | None = None, at_ns: int = 0, error: str = "",
               gain: float = 1.0) -> NodeAssignment:
    return NodeAssignment(revision=revision, slot="r0c0", width=W, height=H, pose_kind="homography",
                          homography=np.eye(3), projection=None, mesh=None, near_mm=100.0, far_mm=10_000.0,
                          lut=None, gain=gain, content_size=(W, H), blend=blend, blend_at_ns=at_ns,
                          blend_error=error)


def blended(m: BlendMaps | None, value: float = GREY) -> np.ndarray:
    values = np.full((H, W, 3), value)
    return quantise(values) if m is None else blended_output(values, m.alpha, m.beta)


class Rig:
    def __init__(self):
        self.host = ManualClock()
        self.clock = LocalClock(source=self.host, sleep=self.host.sleep, anchor_ns=0)
        self.out = OffscreenOutput(slot="r0c0", keep_last=True)
        self.reports: list[tuple[str, object]] = []
        self.p = Presenter(slot="r0c0", output=self.out, clock=self.clock,
                           report=lambda kind, payload: self.reports.append((kind, payload)), realtime=False)

    def rig_now(self) -> int:
        return self.clock.now() + RIG_OFFSET_NS

    def frame(self, frame_id: int, pts_ns: int) -> None:
        self.p.handle("frame", FrameOrder(frame_id=frame_id, pts_ns=pts_ns, content_id="grey", space="content",
                                          apply_lut=True, tag="show"))

    @property
    def status(self):
        return [p for k, p in self.reports if k == "stats"][-1]

    def shown(self) -> np.ndarray:
        return self.out.last_image


@pytest.fixture
def rig():
    r = Rig()
    r.p.open()
    r.p.handle("assignment", assignment(1))
    r.p.handle("clock", ClockEstimate(offset_ns=float(RIG_OFFSET_NS), drift=0.0, ref_local_ns=float(START_NS),
                                      best_rtt_ns=100_000, samples=8))
    r.p.handle("content", ("grey", np.full((H, W, 3), GREY, np.float32)))
    yield r
    r.p.close()


def close(got: np.ndarray, want: np.ndarray) -> None:
    diff = np.abs(got.astype(int) - want.astype(int))
    assert diff.max() <= 1 and (diff > 0).mean() <= 0.01, f"{(diff > 0).sum()} values differ, up to {diff.max()}"


def test_streamed_frames_switch_at_the_first_pts_at_or_after_the_instant(rig):
    m = maps(1)
    at = rig.rig_now() + 100 * MS
    rig.p.handle("assignment", assignment(2, m, at))
    assert rig.status.blend_id == "", "uploaded ahead, not shown"
    rig.frame(1, at - 40 * MS)
    assert (rig.shown() == blended(None)).all() and rig.status.blend_id == ""
    rig.frame(2, at - 1)
    assert (rig.shown() == blended(None)).all(), "one ns before the instant: still without"
    rig.frame(3, at + 20 * MS)
    close(rig.shown(), blended(m))
    assert not (rig.shown() == blended(None)).all()
    assert rig.out.last_info.swap_rig_ns == at + 20 * MS
    assert (rig.status.blend_id, rig.status.blend_since_rig_ns) == (m.blend_id, at + 20 * MS)
    rig.frame(4, at + 40 * MS)
    assert rig.status.blend_since_rig_ns == at + 20 * MS, "since: the first frame shown with it"


def test_a_still_is_shown_again_with_the_maps_at_their_instant(rig):
    rig.frame(1, rig.rig_now() + 10 * MS)
    assert (rig.shown() == blended(None)).all()
    m = maps(2)
    at = rig.rig_now() + 300 * MS
    before = rig.out.last_info
    rig.p.handle("assignment", assignment(2, m, at))
    assert rig.out.last_info is before, "maps due later: the frame is not shown again before their instant"
    wait = rig.p.timeline_wait()
    assert wait is not None and wait == pytest.approx(0.3 - Presenter.BLEND_EARLY_NS / 1e9)   # rendered early
    rig.p.timeline_step()                                          # too early: nothing happens
    assert (rig.shown() == blended(None)).all() and rig.status.blend_id == ""
    rig.host.t += int(wait * 1e9)
    rig.p.timeline_step()
    assert rig.rig_now() == at, "swapped at the instant, not before"
    close(rig.shown(), blended(m))
    assert rig.out.last_info.frame_id == 1 and rig.out.last_info.swap_rig_ns == at
    assert (rig.status.blend_id, rig.status.blend_since_rig_ns) == (m.blend_id, at)
    assert rig.p.timeline_wait() is None, "nothing more to do"
    assert [p.frame_id for k, p in rig.reports if k == "swap"] == [1], "no second swap report for the same frame"


def test_maps_at_once_and_none_again_apply_to_the_frame_on_screen(rig):
    rig.frame(1, rig.rig_now() + 10 * MS)
    plain = rig.shown().copy()
    m = maps(3)
    rig.p.handle("assignment", assignment(2, m, 0))
    close(rig.shown(), blended(m))
    assert rig.status.blend_id == m.blend_id and rig.status.blend_since_rig_ns == rig.rig_now()
    rig.p.handle("assignment", assignment(3, None, 0))
    assert (rig.shown() == plain).all(), "without maps: bit for bit what it was"
    assert rig.status.blend_id == "" and rig.status.blend_since_rig_ns == 0


def test_a_show_switches_at_its_first_tick_at_or_after_the_instant(rig, tmp_path):
    path = tmp_path / "grey.npy"
    np.save(path, np.full((H, W, 3), GREY, np.float32))
    data = path.read_bytes()
    man = Manifest(kind="still", name="grey", width=W, height=H, channels=3, bit_depth=32, frames=1,
                   blobs=(Blob(sha256=sha256_hex(data), size=len(data), name="grey.npy"),))
    files = AssetFiles(asset_id=man.asset_id, manifest=man.canonical(), blob_paths={sha256_hex(data): str(path)})
    anchor = rig.rig_now() + 100 * MS
    tl = Timeline(asset_id=man.asset_id, frames=1, rate=Fraction(10), anchor_ns=anchor, loop=True, revision=1)
    rig.p.handle("asset", files)
    rig.p.handle("show", ShowUpdateData(timeline=tl, frame_id_base=500))
    wait_until(rig.p.player.decode_stats, lambda st: st is not None and st.decoded >= 1,
               what="the decoder thread's first frame (the test's clock stands still meanwhile)")
    m = maps(4)
    at = anchor + 150 * MS                       # between the second and third ticks
    rig.p.handle("assignment", assignment(2, m, at))
    seen = []
    for _ in range(4):
        rig.p.timeline_step()
        seen.append((rig.out.last_info.frame_id, rig.out.last_info.swap_rig_ns, rig.shown().copy()))
    assert [(f, t) for f, t, _ in seen] == [(500 + k, anchor + k * 100 * MS) for k in range(4)]
    for _, t, image in seen:
        if t < at:
            assert (image == blended(None)).all()
        else:
            close(image, blended(m))
    assert (rig.status.blend_id, rig.status.blend_since_rig_ns) == (m.blend_id, anchor + 200 * MS)


def test_malformed_maps_are_refused_in_one_line_and_nothing_on_screen_changes(rig, caplog):
    m = maps(5)
    rig.p.handle("assignment", assignment(2, m, 0))
    rig.frame(1, rig.rig_now() + 10 * MS)
    before = rig.shown().copy()
    close(before, blended(m))
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="node.presenter"):
        rig.p.handle("assignment", assignment(3, None, 0, error="alpha map holds NaN or infinite values"))
    errors = [r for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(errors) == 1 and "NaN" in errors[0].getMessage() and "\n" not in errors[0].getMessage()
    assert (rig.shown() == before).all() and rig.status.blend_id == m.blend_id
    rig.frame(2, rig.rig_now() + 10 * MS)
    assert (rig.shown() == before).all(), "the next frame keeps the maps too"
    # the rest of such an assignment applies: a new gain, the maps kept
    rig.p.handle("assignment", replace(assignment(4, None, 0, error="beta map must lie in 0..1"), gain=0.5))
    close(rig.shown(), blended_output(np.full((H, W, 3), GREY), m.alpha, m.beta, gain=0.5))


class SlowPrepare(OffscreenOutput):
    """An output whose prepare() takes ``prepare_ns`` of the test's clock (a slow GPU's frame)."""

    def __init__(self, host: ManualClock, **kwargs):
        super().__init__(**kwargs)
        self.host, self.prepare_ns = host, 0

    def prepare(self, renderer) -> None:
        self.host.t += self.prepare_ns


def test_a_slow_frame_is_rendered_again_early_enough_and_one_too_slow_says_when_it_was_shown(rig, caplog):
    rig.out = rig.p.out = SlowPrepare(rig.host, slot="r0c0", keep_last=True)
    rig.out.prepare_ns = 80 * MS
    rig.frame(1, rig.rig_now() + 200 * MS)          # its work: 80 ms
    m = maps(6)
    at = rig.rig_now() + 400 * MS
    rig.p.handle("assignment", assignment(2, m, at))       # (its frame on screen rendered again: 80 ms)
    wait = rig.p.timeline_wait()
    assert wait == pytest.approx((at - rig.rig_now() - 160 * MS) / 1e9)    # twice the frame's work ahead
    rig.host.t += int(wait * 1e9)
    rig.p.timeline_step()
    assert rig.rig_now() == at and rig.status.blend_since_rig_ns == at
    close(rig.shown(), blended(m))

    slower = maps(7)                                  # this time the frame takes longer than ever before
    at = rig.rig_now() + 400 * MS
    rig.p.handle("assignment", assignment(3, slower, at))
    rig.out.prepare_ns = 300 * MS
    rig.host.t += int(rig.p.timeline_wait() * 1e9)
    with caplog.at_level(logging.WARNING, logger="node.presenter"):
        rig.p.timeline_step()
    assert rig.rig_now() > at and rig.status.blend_since_rig_ns == rig.rig_now(), "on screen from its swap"
    assert rig.out.last_info.swap_rig_ns == rig.rig_now()
    assert "shown 140.0 ms after its instant" in caplog.text
    close(rig.shown(), blended(slower))


class Inbox:
    """The presenter's pipe as a test fills it: ``poll`` says whether a message waits (the time it may
    wait passes on the test's clock when none does), ``recv`` takes it."""

    def __init__(self, host: ManualClock, messages):
        self.host = host
        self.messages = list(messages)
        self.polls = 0

    def poll(self, timeout: float) -> bool:
        self.polls += 1
        if self.messages:
            return True
        self.host.t += max(1, round(timeout * 1e9))
        return False

    def recv(self):
        return self.messages.pop(0)


def test_maps_that_arrive_while_a_frame_waits_for_its_time_are_in_that_frame(rig):
    m = maps(8)
    pts = rig.rig_now() + 500 * MS
    # (room before the frame's time: the last stretch, a frame's work, is left to the swap's sleep)
    # the failover's maps reach the presenter after the frame for pts was rendered, before its time
    rig.p.inbox = Inbox(rig.host, [("assignment", assignment(2, m, pts - 5 * MS))])
    rig.frame(1, pts)
    assert rig.out.last_info.swap_rig_ns == pts
    close(rig.shown(), blended(m))
    assert (rig.status.blend_id, rig.status.blend_since_rig_ns) == (m.blend_id, pts)

    # maps due after the waiting frame are not in it: the first frame at or after their instant has them
    later = maps(9)
    pts = rig.rig_now() + 500 * MS
    rig.p.inbox = Inbox(rig.host, [("assignment", assignment(3, later, pts + 10 * MS))])
    rig.frame(2, pts)
    close(rig.shown(), blended(m))
    rig.frame(3, pts + 33 * MS)
    close(rig.shown(), blended(later))
    assert rig.status.blend_since_rig_ns == pts + 33 * MS


def test_other_messages_read_while_a_frame_waits_are_handled_after_it_in_order(rig):
    m = maps(10)
    pts = rig.rig_now() + 500 * MS
    gain = ("assignment", assignment(2, gain=0.5))           # not the blend alone: it waits for the loop
    blend = ("assignment", assignment(3, m, pts - 5 * MS, gain=0.5))
    rig.p.inbox = inbox = Inbox(rig.host, [gain, blend])
    rig.frame(1, pts)
    close(rig.shown(), blended(None))
    assert len(inbox.messages) == 1 and inbox.messages[0] is blend, "nothing read after a message kept for the loop"
    assert rig.p.next_deferred() is gain and rig.p.next_deferred() is None


class TimedInbox:
    """The presenter's pipe with messages that arrive at given instants of the test's clock (host ns):
    ``poll`` waits, moving the clock, until the next one arrives or its timeout passes."""

    def __init__(self, host: ManualClock, messages):
        self.host = host
        self.messages = sorted(messages, key=lambda m: m[0])

    def poll(self, timeout: float) -> bool:
        end = self.host.t + max(1, round(timeout * 1e9))
        if self.messages and self.messages[0][0] <= end:
            self.host.t = max(self.host.t, self.messages[0][0])
            return True
        self.host.t = end
        return False

    def recv(self):
        return self.messages.pop(0)[1]


def hold_a_still(rig, lead_ns: int = 300 * MS) -> tuple[BlendMaps, int]:
    """A still on screen and maps for it at an instant ``lead_ns`` ahead (its pts over a second before
    it: a still, not a stream); the clock moved to when it is rendered again with them and held."""
    rig.frame(1, rig.rig_now() + 10 * MS)
    m = maps(20)
    at = rig.rig_now() + lead_ns
    rig.p.handle("assignment", assignment(2, m, at))
    rig.host.t += int(rig.p.timeline_wait() * 1e9)
    assert at - rig.rig_now() == Presenter.BLEND_EARLY_NS
    return m, at


def test_a_stop_read_while_a_still_is_held_for_its_maps_is_handled_at_once(rig):
    m, at = hold_a_still(rig)
    before = rig.out.last_info
    arrives = rig.host.t + 20 * MS
    rig.p.inbox = TimedInbox(rig.host, [(arrives, ("stop", None))])
    rig.p.timeline_step()
    assert rig.host.t == arrives and rig.rig_now() < at, "the hold ended when the stop came, not at the instant"
    assert rig.p.next_deferred() == ("stop", None) and rig.p.next_deferred() is None
    assert rig.out.last_info is before and (rig.shown() == blended(None)).all(), "nothing swapped"
    assert rig.status.blend_id == ""


def test_a_clock_read_while_a_still_is_held_waits_for_the_swap_at_the_instant(rig):
    m, at = hold_a_still(rig)
    est = ClockEstimate(offset_ns=float(RIG_OFFSET_NS), drift=0.0, ref_local_ns=float(START_NS), best_rtt_ns=90_000,
                        samples=9)
    rig.p.inbox = TimedInbox(rig.host, [(rig.host.t + 20 * MS, ("clock", est))])
    rig.p.timeline_step()
    assert rig.rig_now() == at and rig.out.last_info.swap_rig_ns == at
    close(rig.shown(), blended(m))
    assert (rig.status.blend_id, rig.status.blend_since_rig_ns) == (m.blend_id, at)
    assert rig.p.next_deferred() == ("clock", est), "kept for the loop, after the swap"


def test_a_still_read_while_another_is_held_shows_at_its_pts_and_the_maps_at_their_instant(rig):
    m, at = hold_a_still(rig, lead_ns=1_500 * MS)
    rig.p.handle("content", ("white", np.full((H, W, 3), 1.0, np.float32)))
    still = FrameOrder(frame_id=2, pts_ns=at - 50 * MS, content_id="white", space="content", apply_lut=True, tag="show")
    arrives = rig.host.t + 20 * MS
    rig.p.inbox = TimedInbox(rig.host, [(arrives, ("frame", still))])
    rig.p.timeline_step()
    assert rig.host.t == arrives and rig.p.next_deferred() == ("frame", still)
    rig.p.handle("frame", still)                          # the loop handles it: before the instant, no maps
    assert rig.out.last_info.frame_id == 2 and rig.out.last_info.swap_rig_ns == at - 50 * MS
    assert (rig.shown() == blended(None, 1.0)).all() and rig.status.blend_id == ""
    rig.host.t += int(rig.p.timeline_wait() * 1e9)        # then the new still is shown again with them
    rig.p.timeline_step()
    assert rig.rig_now() == at and rig.out.last_info.frame_id == 2
    close(rig.shown(), blended(m, 1.0))
    assert (rig.status.blend_id, rig.status.blend_since_rig_ns) == (m.blend_id, at)


def test_a_still_read_while_another_is_held_carries_the_maps_when_it_is_at_or_after_their_instant(rig):
    m, at = hold_a_still(rig)
    rig.p.handle("content", ("white", np.full((H, W, 3), 1.0, np.float32)))
    still = FrameOrder(frame_id=2, pts_ns=at + 10 * MS, content_id="white", space="content", apply_lut=True, tag="show")
    rig.p.inbox = TimedInbox(rig.host, [(rig.host.t + 20 * MS, ("frame", still))])
    rig.p.timeline_step()
    assert rig.rig_now() < at
    rig.p.handle(*rig.p.next_deferred())
    assert rig.out.last_info.frame_id == 2 and rig.out.last_info.swap_rig_ns == at + 10 * MS
    close(rig.shown(), blended(m, 1.0))
    assert (rig.status.blend_id, rig.status.blend_since_rig_ns) == (m.blend_id, at + 10 * MS)
    assert rig.p.timeline_wait() is None, "nothing more to do"
    assert [p.frame_id for k, p in rig.reports if k == "swap"] == [1, 2]
