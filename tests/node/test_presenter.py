"""The presenter's drop rules, on a clock the test moves (never the wall clock).

The presenter runs here in the test's thread with a real renderer (EGL, llvmpipe) and an
offscreen output; only time is simulated: its clock reads a counter that moves when the
test says so, or when the presenter sleeps until a frame's presentation time.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from waits import wait_until

from node.clock import ClockEstimate, LocalClock
from node.outputs import OffscreenOutput
from node.pacing import LATE_TOLERANCE_NS, FramePacer
from node.presenter import Presenter
from node.records import (
    DropReason,
    DropRecord,
    FrameOrder,
    NodeAssignment,
    PresenterStatus,
    SwapRecord,
)
from protos import codec, node_pb2

W, H = 32, 24
MS = 1_000_000
START_NS = 5_000_000_000_000
#: the rig clock runs this far ahead of the node's local clock
RIG_OFFSET_NS = 7_000 * MS


class ManualClock:
    """Host time in ns that moves only when told to, or when someone sleeps on it."""

    def __init__(self, start_ns: int = START_NS):
        self.t = start_ns
        self.slept_ns: list[int] = []

    def __call__(self) -> int:
        return self.t

    def sleep(self, seconds: float) -> None:
        step = max(1, round(seconds * 1e9))
        self.slept_ns.append(step)
        self.t += step

    def advance(self, ns: int) -> None:
        self.t += ns


def estimate() -> ClockEstimate:
    """An estimate that knows the rig clock exactly: rig = local + RIG_OFFSET_NS."""
    return ClockEstimate(offset_ns=float(RIG_OFFSET_NS), drift=0.0, ref_local_ns=float(START_NS), best_rtt_ns=100_000,
                         samples=8)


def assignment(revision: int = 1) -> NodeAssignment:
    return NodeAssignment(revision=revision, slot="r0c0", width=W, height=H, pose_kind="none", homography=None,
                          projection=None, mesh=None, near_mm=100.0, far_mm=10_000.0, lut=None, gain=1.0,
                          content_size=(W, H))


def still(value: int) -> np.ndarray:
    return np.full((H, W, 3), value, np.uint8)


class SlowOutput(OffscreenOutput):
    """An offscreen output whose prepare() takes ``prepare_ns`` of the test's clock (a slow blit)."""

    def __init__(self, clock: ManualClock, **kwargs):
        super().__init__(**kwargs)
        self.clock = clock
        self.prepare_ns = 0
        self.swaps = 0

    def prepare(self, renderer) -> None:
        self.clock.advance(self.prepare_ns)

    def swap(self) -> None:
        self.swaps += 1


class Rig:
    """A presenter with its clock, output and the reports it made."""

    def __init__(self):
        self.host = ManualClock()
        self.clock = LocalClock(source=self.host, sleep=self.host.sleep, anchor_ns=0)
        self.out = SlowOutput(self.host, slot="r0c0", keep_last=True)
        self.reports: list[tuple[str, object]] = []
        self.presenter = Presenter(slot="r0c0", output=self.out, clock=self.clock, report=self._report,
                                   realtime=False)

    def _report(self, kind: str, payload) -> None:
        self.reports.append((kind, payload))

    @property
    def swaps(self) -> list[SwapRecord]:
        return [p for k, p in self.reports if k == "swap"]

    @property
    def drops(self) -> list[DropRecord]:
        return [p for k, p in self.reports if k == "drop"]

    @property
    def status(self) -> PresenterStatus:
        return [p for k, p in self.reports if k == "stats"][-1]

    def rig_now(self) -> int:
        return self.clock.now() + RIG_OFFSET_NS

    def frame(self, frame_id: int, *, in_ms: float, content: str = "", tag: str = "show") -> FrameOrder:
        """A frame due ``in_ms`` from now (negative: already past)."""
        return FrameOrder(frame_id=frame_id, pts_ns=self.rig_now() + int(in_ms * MS), content_id=content,
                          space="projector", apply_lut=False, tag=tag)

    def show(self, frame: FrameOrder) -> None:
        self.presenter.handle("frame", frame)


@pytest.fixture
def rig():
    r = Rig()
    r.presenter.open()
    r.presenter.handle("assignment", assignment())
    r.presenter.handle("clock", estimate())
    for value in (10, 20, 30):
        r.presenter.handle("content", (f"c{value}", still(value)))
    r.reports.clear()
    r.out.swaps = 0   # open() showed black
    yield r
    r.presenter.close()


# ----------------------------------------------------------------------------- through the presenter


def test_frames_on_time_are_shown_at_their_time_and_reported_in_order(rig):
    frames = [rig.frame(1, in_ms=5, content="c10"), rig.frame(2, in_ms=10, content="c20"),
              rig.frame(3, in_ms=40, content="c30")]
    for f in frames:
        rig.show(f)
    assert [s.frame_id for s in rig.swaps] == [1, 2, 3]
    assert rig.drops == []
    for swap, f in zip(rig.swaps, frames):
        # the presenter slept until each frame's time on the (simulated) clock, and swapped then
        assert swap.pts_ns == f.pts_ns and swap.swap_rig_ns == f.pts_ns
        assert swap.host_monotonic_ns == f.pts_ns - RIG_OFFSET_NS
    assert rig.host.t == frames[-1].pts_ns - RIG_OFFSET_NS
    assert rig.out.swaps == 3
    assert (rig.out.last_image == 30).all() and rig.out.last_info.frame_id == 3   # really rendered
    assert rig.status == PresenterStatus(shown=3, late=0, dropped=0, render_ms_p50=rig.status.render_ms_p50,
                                         revision=1, decoder="software", decoder_note=rig.status.decoder_note)


def test_a_frame_that_arrives_after_its_time_is_dropped_as_late(rig):
    rig.show(rig.frame(1, in_ms=-2, content="c10"))
    assert rig.drops == [DropRecord(1, DropReason.LATE, 2 * MS)]
    assert rig.swaps == [] and rig.out.swaps == 0 and rig.host.slept_ns == []
    assert (rig.status.late, rig.status.dropped, rig.status.shown) == (1, 0, 0)
    # a frame a little late, within the tolerance, is still shown (at once: no sleep)
    rig.show(rig.frame(2, in_ms=-0.4, content="c20"))
    assert [s.frame_id for s in rig.swaps] == [2] and rig.host.slept_ns == []
    assert rig.swaps[0].swap_rig_ns - rig.swaps[0].pts_ns == 400_000 < LATE_TOLERANCE_NS


def test_a_frame_rendered_after_its_time_is_dropped_as_late(rig):
    rig.out.prepare_ns = 3 * MS   # the frame is ready 3 ms after it arrived
    rig.show(rig.frame(1, in_ms=1, content="c10"))
    assert rig.drops == [DropRecord(1, DropReason.LATE, 2 * MS)]
    assert rig.out.swaps == 0 and rig.status.late == 1


def test_without_a_clock_estimate_frames_are_late(rig):
    rig.presenter.handle("clock", None)
    rig.show(rig.frame(1, in_ms=50, content="c10"))
    assert rig.drops == [DropRecord(1, DropReason.LATE, 0)]


def test_a_frame_superseded_by_a_newer_one_before_its_time_is_dropped(rig):
    old = rig.frame(1, in_ms=30, content="c10")
    rig.show(rig.frame(2, in_ms=10, content="c20"))   # the newer frame is due first and is shown
    rig.show(old)                                     # still before its time, but older: never shown
    rig.show(rig.frame(2, in_ms=40, content="c30"))   # the same id again
    assert [s.frame_id for s in rig.swaps] == [2]
    assert rig.drops == [DropRecord(1, DropReason.SUPERSEDED), DropRecord(2, DropReason.SUPERSEDED)]
    assert (rig.out.last_image == 20).all()
    assert (rig.status.shown, rig.status.late, rig.status.dropped) == (1, 0, 2)
    # a new coordinator instance restarts the ids
    rig.presenter.handle("reset", None)
    rig.show(rig.frame(1, in_ms=5, content="c30"))
    assert [s.frame_id for s in rig.swaps] == [2, 1]


def test_a_frame_whose_content_is_missing_is_dropped_with_that_reason(rig):
    rig.show(rig.frame(1, in_ms=5, content="never-sent"))
    assert rig.drops == [DropRecord(1, DropReason.MISSING_CONTENT)]
    assert rig.out.swaps == 0 and rig.status.dropped == 1 and rig.status.late == 0
    # content evicted while not on screen is missing too
    rig.presenter.handle("evict", ["c10"])
    rig.show(rig.frame(2, in_ms=5, content="c10"))
    assert rig.drops[-1] == DropRecord(2, DropReason.MISSING_CONTENT)


def test_a_frame_the_renderer_refuses_is_dropped_as_unrenderable(rig):
    rig.presenter.handle("content", ("small", np.zeros((H // 2, W, 3), np.uint8)))
    rig.show(rig.frame(1, in_ms=5, content="small"))   # projector space needs W x H
    assert rig.drops == [DropRecord(1, DropReason.UNRENDERABLE)]


def test_packets_cache_content_show_the_frame_and_report_malformed_content_as_missing(rig):
    def packet(frame_id: int, in_ms: float, cid: str, image: np.ndarray | None) -> bytes:
        pkt = node_pb2.FramePacket()
        if image is not None:
            pkt.contents.add(content_id=cid, image=codec.encode_image(image))
        else:  # malformed: an image that claims more pixels than it holds
            pkt.contents.add(content_id=cid, image=codec.encode_image(still(1))).image.width = W + 1
        pkt.frame.frame_id = frame_id
        pkt.frame.pts_ns = rig.rig_now() + int(in_ms * MS)
        pkt.frame.content_id = "other-slot-content"
        pkt.frame.slot_content["r0c0"] = cid
        pkt.frame.space = node_pb2.SPACE_PROJECTOR
        pkt.frame.tag = "show"
        return pkt.SerializeToString()

    rig.presenter.handle("packet", packet(1, 5, "p77", still(77)))
    assert [s.frame_id for s in rig.swaps] == [1] and (rig.out.last_image == 77).all()
    rig.presenter.handle("packet", packet(2, 5, "broken", None))
    assert rig.drops == [DropRecord(2, DropReason.MISSING_CONTENT)]


# ----------------------------------------------------------------------------- the rules alone


class Frames:
    def __init__(self):
        self.host = ManualClock()
        self.clock = LocalClock(source=self.host, sleep=self.host.sleep, anchor_ns=0)
        self.pacer = FramePacer(self.clock)
        self.pacer.estimate = estimate()

    def due(self, frame_id: int, in_ms: float, content: str = "c") -> FrameOrder:
        return FrameOrder(frame_id, self.clock.now() + RIG_OFFSET_NS + int(in_ms * MS), content, "content", True, "")


def test_pacer_rules_in_order():
    f = Frames()
    has = {"c"}.__contains__
    assert f.pacer.admit(f.due(1, 10), has) is None
    assert f.pacer.deadline(f.due(1, 10)) == f.clock.now() + 10 * MS
    late = f.due(1, -1)
    assert f.pacer.admit(late, has) == DropRecord(1, DropReason.LATE, MS)
    assert f.pacer.admit(f.due(1, 10, "x"), has) == DropRecord(1, DropReason.MISSING_CONTENT)
    assert f.pacer.admit(f.due(1, 10, ""), has) is None   # black needs no content
    # a late frame is late before its content is looked at; an old one is superseded before either
    assert f.pacer.admit(f.due(1, -1, "x"), has).reason is DropReason.LATE
    frame = f.due(5, 2)
    f.host.advance(2 * MS)
    swap = f.pacer.shown(frame, f.host())
    assert swap == SwapRecord(5, frame.pts_ns, frame.pts_ns, f.host())
    assert f.pacer.admit(f.due(4, -1, "x"), has) == DropRecord(4, DropReason.SUPERSEDED)
    assert f.pacer.admit(f.due(5, 10), has).reason is DropReason.SUPERSEDED
    f.pacer.reset()
    assert f.pacer.admit(f.due(4, 10), has) is None


def test_pacer_ready_checks_the_time_again():
    f = Frames()
    frame = f.due(1, 1)
    assert f.pacer.ready(frame) is None
    f.host.advance(MS + LATE_TOLERANCE_NS)
    assert f.pacer.ready(frame) is None        # exactly at the tolerance: still shown
    f.host.advance(1)
    assert f.pacer.ready(frame) == DropRecord(1, DropReason.LATE, LATE_TOLERANCE_NS + 1)


def test_pacer_follows_the_clock_hooks():
    """A node whose local clock is offset and drifting times frames on the rig clock all the same."""
    host = ManualClock()
    clock = LocalClock(offset_ns=-300 * MS, drift_ppm=150.0, source=host, sleep=host.sleep, anchor_ns=START_NS)
    pacer = FramePacer(clock)
    local = clock.now()
    pacer.estimate = ClockEstimate(offset_ns=float(RIG_OFFSET_NS), drift=0.0, ref_local_ns=float(local),
                                   best_rtt_ns=1, samples=1)
    frame = FrameOrder(1, local + RIG_OFFSET_NS + 20 * MS, "", "content", True, "")
    deadline = pacer.deadline(frame)
    assert deadline == local + 20 * MS
    woke = clock.sleep_until(deadline)
    assert clock.from_host(woke) >= deadline and pacer.ready(frame) is None
    assert sum(host.slept_ns) == woke - START_NS


# ----------------------------------------------------------------------------- the show's timeline
def _still_asset(tmp_path):
    from node.records import AssetFiles
    from protos.asset_manifest import Blob, Manifest, sha256_hex

    path = tmp_path / "grey.npy"
    np.save(path, np.full((H, W, 3), 0.5, np.float32))
    data = path.read_bytes()
    m = Manifest(kind="still", name="grey", width=W, height=H, channels=3, bit_depth=32, frames=1,
                 blobs=(Blob(sha256=sha256_hex(data), size=len(data), name="grey.npy"),))
    return AssetFiles(asset_id=m.asset_id, manifest=m.canonical(), blob_paths={sha256_hex(data): str(path)})


def first_frame_decoded(presenter) -> None:
    """Wait (in real time) for the decoder thread's first frame of the show's asset: the test's
    clock stands still, so a first tick due a few of its milliseconds from now would otherwise
    give that thread only those few real milliseconds before the tick counts as late."""
    wait_until(presenter.player.decode_stats, lambda st: st is not None and st.decoded >= 1,
               what="the decoder thread's first frame of the show's asset")


def _timeline_update(files, anchor_ns: int, *, revision: int = 1, base: int = 500):
    from fractions import Fraction

    from node.records import ShowUpdateData
    from protos.timeline import Timeline

    tl = Timeline(asset_id=files.asset_id, frames=1, rate=Fraction(10), anchor_ns=anchor_ns, loop=True,
                  revision=revision)
    return ShowUpdateData(timeline=tl, frame_id_base=base)


def test_timeline_ticks_are_swapped_at_their_time_with_ids_from_the_base(rig, tmp_path):
    files = _still_asset(tmp_path)
    p = rig.presenter
    anchor = rig.rig_now() + 100 * MS
    p.handle("asset", files)
    p.handle("show", _timeline_update(files, anchor))
    first_frame_decoded(p)
    assert p.timeline_wait() == pytest.approx(0.05)      # prepared 50 ms ahead of the first tick
    for _ in range(3):
        p.timeline_step()
    assert [s.frame_id for s in rig.swaps] == [500, 501, 502]
    assert [s.pts_ns for s in rig.swaps] == [anchor, anchor + 100 * MS, anchor + 200 * MS]
    assert [s.swap_rig_ns for s in rig.swaps] == [s.pts_ns for s in rig.swaps]


def test_decoding_starts_when_the_show_and_its_asset_are_known_not_at_the_first_tick(rig, tmp_path):
    files = _still_asset(tmp_path)
    p = rig.presenter
    p.handle("show", _timeline_update(files, rig.rig_now() + 500 * MS))
    assert p.player.decode_stats() is None                # no asset yet: nothing to decode
    p.handle("asset", files)
    st = wait_until(p.player.decode_stats, lambda st: st is not None and st.decoded >= 1,
                    what="the decoder thread's first frame, before any tick is due")
    assert st.hits == st.misses == 0
    p.timeline_step()
    st = p.player.decode_stats()
    assert [s.frame_id for s in rig.swaps] == [500] and st.hits == 1 and st.misses == 0


def test_the_presenter_reports_the_show_as_it_follows_it(rig, tmp_path):
    files = _still_asset(tmp_path)
    p = rig.presenter
    anchor = rig.rig_now() + 20 * MS
    p.handle("show", _timeline_update(files, anchor, revision=4))
    assert p.status().show.state == "none" and p.status().show.revision == 4   # not begun yet
    p.handle("asset", files)
    first_frame_decoded(p)
    for _ in range(2):
        p.timeline_step()
    st = p.status().show
    assert (st.state, st.revision, st.last_frame, st.shown, st.late) == ("playing", 4, 0, 2, 0)
    rig.host.advance(350 * MS)                # at tick 1 + 3.5 ticks: ticks 2, 3, 4 pass unseen
    p.timeline_step()
    st = p.status().show
    assert (st.shown, st.late, st.last_frame) == (3, 3, 0), st
    rig.show(rig.frame(10_000, in_ms=5, content="c10"))
    assert p.status().show.state == "suspended"


def test_a_coordinator_frame_suspends_the_timeline_until_a_newer_revision(rig, tmp_path):
    files = _still_asset(tmp_path)
    p = rig.presenter
    anchor = rig.rig_now() + 10 * MS
    p.handle("asset", files)
    p.handle("show", _timeline_update(files, anchor))
    first_frame_decoded(p)
    p.timeline_step()
    rig.show(rig.frame(10_000, in_ms=5, content="c10"))          # a still: it takes the output
    assert p.timeline_wait() is None
    p.handle("show", _timeline_update(files, anchor))            # a beacon of the same revision
    assert p.timeline_wait() is None
    p.handle("show", _timeline_update(files, rig.rig_now() + 100 * MS, revision=2, base=20_000))
    p.timeline_step()
    assert [s.frame_id for s in rig.swaps] == [500, 10_000, 20_000]


def test_a_coordinator_frame_issued_before_the_newest_show_does_not_suspend_it(rig, tmp_path):
    """A still's resend sent just before a show began (Frames stream) may reach the node after the
    show (Show stream): its id is below the show's frame id base, so it is dropped as superseded and
    the show plays on, where it used to leave this one node suspended until the next revision."""
    files = _still_asset(tmp_path)
    p = rig.presenter
    p.handle("asset", files)
    p.handle("show", _timeline_update(files, rig.rig_now() + 100 * MS, base=20_000))
    first_frame_decoded(p)
    rig.show(rig.frame(19_999, in_ms=5, content="c10"))          # issued before the show's base
    assert [(d.frame_id, d.reason) for d in rig.drops] == [(19_999, DropReason.SUPERSEDED)]
    assert p.status().show.state != "suspended"
    p.timeline_step()
    assert [s.frame_id for s in rig.swaps] == [20_000]

def test_a_paused_shows_frame_that_misses_its_instant_is_shown_a_moment_later(rig, tmp_path):
    """Every node must hold the paused frame for the whole pause: one rendered too late for its
    instant is tried again CATCH_UP_NS later (no drop reported), not left out."""
    from node.timeline_player import CATCH_UP_NS

    files = _still_asset(tmp_path)
    p = rig.presenter
    p.handle("asset", files)
    anchor = rig.rig_now() + 60 * MS
    update = _timeline_update(files, anchor, revision=3, base=700)
    p.handle("show", replace(update, timeline=replace(update.timeline, paused=True)))
    first_frame_decoded(p)
    rig.out.prepare_ns = 70 * MS          # the first attempt finishes 10 ms after the frame's instant
    p.timeline_step()
    assert rig.swaps == [] and rig.drops == []
    rig.out.prepare_ns = 1 * MS
    assert p.timeline_wait() is not None       # the held frame is due again, CATCH_UP_NS from now
    p.timeline_step()
    assert [s.frame_id for s in rig.swaps] == [700] and rig.drops == []
    sw = rig.swaps[0]
    assert sw.pts_ns >= anchor + CATCH_UP_NS and sw.swap_rig_ns == sw.pts_ns     # re-timed, then on time
    p.timeline_step()                     # held: nothing more to do until the show changes
    assert len(rig.swaps) == 1 and p.timeline_wait() is None
    assert p.status().show.state == "paused"


def test_a_stop_blacks_the_output_without_a_report(rig, tmp_path):
    from node.records import ShowUpdateData

    files = _still_asset(tmp_path)
    p = rig.presenter
    anchor = rig.rig_now() + 10 * MS
    p.handle("asset", files)
    p.handle("show", _timeline_update(files, anchor))
    first_frame_decoded(p)
    p.timeline_step()
    p.handle("show", ShowUpdateData(stop_at_ns=anchor + 50 * MS, stop_revision=2))
    swaps_before = rig.out.swaps
    p.timeline_step()
    assert rig.out.swaps == swaps_before + 1 and [s.frame_id for s in rig.swaps] == [500]
    assert p.timeline_wait() is None


def test_an_assignment_the_renderer_refuses_blacks_the_projector_and_the_presenter_lives_on(rig, caplog):
    from dataclasses import replace

    from node.records import MeshData

    quad = MeshData(mesh_id="tri", vertices=np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32),
                    uvs=np.array([[0, 0], [1, 0], [0, 1]], np.float32), faces=np.array([[0, 1, 2]], np.uint32))
    affine = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])     # no depth axis
    bad = replace(assignment(revision=2), pose_kind="projection", projection=affine, mesh=quad)
    with caplog.at_level("ERROR"):
        rig.presenter.handle("assignment", bad)
    assert "assignment r2 cannot be rendered" in caplog.text
    assert rig.presenter.assignment.revision == 2
    good = replace(assignment(revision=3), pose_kind="homography", homography=np.eye(3))
    rig.presenter.handle("assignment", good)          # the next good one renders again
    rig.show(rig.frame(1, in_ms=20, content="c10"))
    assert rig.presenter.assignment.revision == 3 and [s.frame_id for s in rig.swaps] == [1]
