"""The coordinator's show state with plain objects: a clock the test moves, a dict of manifests,
a frame id counter, nodes' progress as the test says."""
from __future__ import annotations

from fractions import Fraction

import pytest

from coordinator.api import AssetProgress
from coordinator.errors import AssetError
from coordinator.show import SHOW_FILE, Show, ShowError, manifest_rate, ticks_before
from protos.asset_manifest import Blob, Manifest
from protos.timeline import Timeline

MS = 1_000_000
AID = "a" * 64
CLIP = Manifest(kind="video", name="clip", width=64, height=48, channels=3, bit_depth=8, frames=90, fps=30.0,
                blobs=(Blob(name="clip.mp4", sha256="b" * 64, size=1000),), extra={"rate": "30/1"})


class Ids:
    def __init__(self, start: int = 1000):
        self.next = start

    def new_frame_id(self) -> int:
        self.next += 1
        return self.next

    def reserve_ids_through(self, last_id: int) -> None:
        self.next = max(self.next, last_id)


class Rig:
    """Everything a Show needs, as plain objects."""

    def __init__(self, tmp_path):
        self.t = 10_000 * MS
        self.ids = Ids()
        self.progress = {"r0c0": AssetProgress(AID, 1000, 1000, True), "r0c1": AssetProgress(AID, 1000, 1000, True)}
        self.dir = tmp_path

    def resolve(self, key: str) -> str:
        if key in (AID, "clip", AID[:6]):
            return AID
        raise AssetError(f"no asset matches {key!r}")

    def show(self) -> Show:
        return Show(self.dir, resolve=self.resolve, manifest=lambda a: CLIP, ids=self.ids,
                    progress=lambda a: dict(self.progress), clock_ns=lambda: self.t, lead_ns=150 * MS)


@pytest.fixture
def rig(tmp_path):
    return Rig(tmp_path)


def test_play_is_refused_while_a_live_node_lacks_the_asset_unless_asked(rig):
    rig.progress["r0c1"] = AssetProgress(AID, 250, 1000, False)
    rig.progress["r0c2"] = None
    s = rig.show()
    with pytest.raises(ShowError, match=r"r0c1 \(25%.*r0c2 \(nothing fetched yet\).*--start-without"):
        s.play("clip")
    assert s.timeline is None and s.update() is None
    st = s.play("clip", start_without=True)
    assert st.state == "scheduled" and st.anchor_ns == rig.t + 150 * MS
    assert s.ready_slots(["r0c0", "r0c1", "r0c2"]) == {"r0c0"}


def test_unknown_assets_and_bad_rates_are_refused(rig):
    s = rig.show()
    with pytest.raises(AssetError, match="no asset matches"):
        s.play("nope")
    with pytest.raises(ValueError):
        s.play("clip", fps=0.0001 - 1)


def test_play_pause_seek_resume_stop(rig):
    s = rig.show()
    st = s.play("clip", delay_ns=500 * MS)
    t0 = st.anchor_ns
    assert (st.state, st.frames, st.fps, st.revision) == ("scheduled", 90, 30.0, 1)
    rig.t = t0 + 1000 * MS                      # one second in: frame 30
    st = s.state()
    assert (st.state, st.frame) == ("playing", 30)
    paused = s.pause()
    assert paused.paused and paused.anchor_ns == rig.t + 150 * MS and paused.anchor_frame == 34
    assert paused.frame_id_base > st.frame_id_base + 34           # above every tick shown before
    rig.t += 1000 * MS
    assert (s.state().state, s.state().frame) == ("paused", 34)
    sought = s.seek(80)
    rig.t += 200 * MS
    assert (s.state().state, s.state().frame) == ("paused", 80)
    resumed = s.resume()
    rig.t = resumed.anchor_ns + 1000 * MS       # 80 + 30 = 110 > 89: a show that does not loop has ended
    assert s.state().state == "ended" and s.state().frame == -1
    assert sought.revision < resumed.revision and resumed.frame_id_base > sought.frame_id_base
    stopped = s.stop()
    assert stopped.revision == resumed.revision + 1
    rig.t += 200 * MS
    assert s.state().state == "stopped"
    assert s.update().timeline is None and s.update().stop_revision == stopped.revision
    with pytest.raises(ShowError, match="no show is playing"):
        s.pause()
    with pytest.raises(ShowError):
        s.seek(5)


def test_seek_outside_the_asset_is_refused(rig):
    s = rig.show()
    s.play("clip", loop=True)
    with pytest.raises(ShowError, match="frames 0..89"):
        s.seek(90)


def test_upcoming_ticks_list_each_tick_once_with_its_id_and_stop_at_a_change(rig):
    s = rig.show()
    st = s.play("clip", delay_ns=100 * MS)
    base, t0 = st.frame_id_base, st.anchor_ns
    assert s.upcoming_ticks(ahead_ns=50 * MS) == []           # nothing due before the start
    rig.t = t0
    first = s.upcoming_ticks(ahead_ns=100 * MS)
    tl = s.timeline
    assert first == [(base + k, tl.pts(k)) for k in range(3)]   # 0, 33.3, 66.7 ms
    rig.t = t0 + 50 * MS
    second = s.upcoming_ticks(ahead_ns=100 * MS)
    assert second == [(base + 3, tl.pts(3)), (base + 4, tl.pts(4))]
    paused = s.pause(delay_ns=200 * MS)                         # at t0 + 250 ms
    rig.t = t0 + 200 * MS
    ticks = s.upcoming_ticks(ahead_ns=100 * MS)
    ids = [i for i, _ in ticks]
    assert ids[-1] == paused.frame_id_base and all(i < base + 8 for i in ids[:-1])
    assert ticks[-1][1] == paused.anchor_ns


def test_takeover_stops_the_show_and_reserves_the_ids_it_may_still_show(rig):
    s = rig.show()
    st = s.play("clip", loop=True)
    rig.t = st.anchor_ns + 10_000 * MS                          # tick 300
    s.takeover()
    assert not s.active and s.state().state == "stopped"
    assert rig.ids.next >= st.frame_id_base + 300 + 60          # 2 s more of ticks
    s.takeover()                                                 # nothing to stop: no new revision
    assert s.revision == 2


def test_a_restarted_coordinator_takes_the_running_show_back(rig):
    s = rig.show()
    st = s.play("clip", loop=True, fps=25)
    assert (rig.dir / SHOW_FILE).exists()
    rig.ids = Ids(start=5)
    again = rig.show()
    assert again.active and again.timeline == s.timeline and again.frame_id_base == st.frame_id_base
    assert again.timeline.rate == Fraction(25)
    assert rig.ids.next >= st.frame_id_base
    assert again.pause().revision == st.revision + 1
    s.stop()
    third = rig.show()
    assert not third.active and third.update().stop_revision == s.revision


def test_a_damaged_show_file_is_ignored(rig):
    (rig.dir / SHOW_FILE).write_text("{not json")
    s = rig.show()
    assert s.timeline is None and s.state().state == "none"


def test_helpers():
    tl = Timeline(asset_id=AID, frames=10, rate=Fraction(10), anchor_ns=1000, loop=True)
    assert ticks_before(tl, 1000) == 0 and ticks_before(tl, 1001) == 1
    assert ticks_before(tl, 1000 + 100 * MS) == 1 and ticks_before(tl, 1001 + 100 * MS) == 2
    assert manifest_rate(CLIP) == 30
    assert manifest_rate(Manifest(kind="still", name="s", width=1, height=1, channels=3, bit_depth=8, frames=1,
                                  blobs=(Blob(name="s.png", sha256="c" * 64, size=1),))) == 1


def test_show_updates_cross_the_wire_as_the_node_reads_them(rig):
    from coordinator.wire import control_messages, node_messages
    from node import wire as node_wire
    from protos import node_pb2

    s = rig.show()
    s.play("clip", loop=True, fps=29.97)
    msg = node_pb2.ShowUpdate.FromString(node_messages.show_update_message(s.update(beacon=True)).SerializeToString())
    got = node_wire.show_update_from_message(msg)
    assert got.timeline == s.timeline and got.frame_id_base == s.frame_id_base and got.beacon
    assert got.timeline.rate == Fraction(30000, 1001)
    assert msg.ByteSize() < 150          # what a beacon costs per node per second
    s.stop()
    got = node_wire.show_update_from_message(
        node_pb2.ShowUpdate.FromString(node_messages.show_update_message(s.update()).SerializeToString()))
    assert got.timeline is None and (got.stop_at_ns, got.stop_revision) == (s.stop_at_ns, s.stop_revision)
    state = s.state()
    assert control_messages.show_state_from_message(control_messages.show_state_message(state)) == state
