"""The presenter's timeline logic: which tick comes next, with which frame id, and when; pure
logic on rig-clock instants the test picks (the real-process test is
tests/coordinator/test_show_rig.py)."""
from __future__ import annotations

from dataclasses import replace
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from node.asset_frames import FrameError
from node.records import AssetFiles, ShowUpdateData
from node.timeline_player import AssetFilesView, TimelinePlayer, fit_frame
from protos.asset_manifest import Blob, Manifest, sha256_hex
from protos.timeline import NS, Timeline
from tests.support.clip_rig import write_clip
from tests.support.waits import wait_until

MS = 1_000_000
AID = "a" * 64
T0 = 5_000 * MS
BASE = 10_000


def timeline(**kw) -> Timeline:
    args = dict(asset_id=AID, frames=20, rate=Fraction(10), anchor_ns=T0, revision=1)
    args.update(kw)
    return Timeline(**args)


def player_with(tl: Timeline, base: int = BASE) -> TimelinePlayer:
    p = TimelinePlayer()
    assert p.offer(ShowUpdateData(timeline=tl, frame_id_base=base))
    return p


def play(p: TimelinePlayer, after: int, n: int) -> list[tuple[str, int, int, int]]:
    """Handle ``n`` events from ``after`` on: (kind, frame_id, frame, pts) each."""
    out = []
    for _ in range(n):
        ev = p.next_event(after)
        if ev is None:
            break
        out.append((ev.kind, ev.frame_id, ev.frame, ev.pts_ns))
        p.mark_done(ev)
        after = ev.pts_ns + 1
    return out


def test_ticks_follow_the_timeline_with_ids_from_the_base():
    p = player_with(timeline())
    assert play(p, T0 - 50 * MS, 3) == [("frame", BASE, 0, T0), ("frame", BASE + 1, 1, T0 + 100 * MS),
                                        ("frame", BASE + 2, 2, T0 + 200 * MS)]


def test_a_node_joining_mid_show_starts_at_the_next_tick_with_the_same_ids():
    p = player_with(timeline(loop=True))
    ev = p.next_event(T0 + 2_050 * MS)                   # 20.5 ticks in: tick 21 is frame 1 (looped)
    assert (ev.tick, ev.frame, ev.frame_id, ev.pts_ns) == (21, 1, BASE + 21, T0 + 2_100 * MS)


def test_a_show_that_does_not_loop_ends_on_its_last_frame():
    p = player_with(timeline(frames=3))
    assert [e[2] for e in play(p, T0, 10)] == [0, 1, 2]


def test_pause_holds_one_frame_and_a_late_joiner_catches_up_with_it():
    tl = timeline()
    p = player_with(tl)
    p.offer(ShowUpdateData(timeline=replace(tl.paused_at(T0 + 250 * MS), revision=2), frame_id_base=BASE + 100))
    events = play(p, T0, 10)
    assert events == [("frame", BASE, 0, T0), ("frame", BASE + 1, 1, T0 + 100 * MS),
                      ("frame", BASE + 2, 2, T0 + 200 * MS), ("frame", BASE + 100, 2, T0 + 250 * MS)]
    late = player_with(replace(tl.paused_at(T0 + 250 * MS), revision=2), base=BASE + 100)
    ev = late.next_event(T0 + 5_000 * MS)
    assert (ev.frame_id, ev.frame) == (BASE + 100, 2) and ev.pts_ns > T0 + 5_000 * MS


def test_a_stop_blacks_the_output_once_and_a_newer_show_plays_again():
    p = player_with(timeline())
    p.offer(ShowUpdateData(stop_at_ns=T0 + 150 * MS, stop_revision=2))
    assert play(p, T0, 10) == [("frame", BASE, 0, T0), ("frame", BASE + 1, 1, T0 + 100 * MS),
                               ("stop", 0, 0, T0 + 150 * MS)]
    assert not p.offer(ShowUpdateData(stop_at_ns=T0 + 150 * MS, stop_revision=2))     # a beacon
    p.offer(ShowUpdateData(timeline=timeline(anchor_ns=T0 + 1_000 * MS, revision=3), frame_id_base=BASE + 50))
    assert play(p, T0 + 200 * MS, 1) == [("frame", BASE + 50, 0, T0 + 1_000 * MS)]


def test_a_coordinator_frame_suspends_the_timeline_until_a_newer_revision():
    tl = timeline(loop=True)
    p = player_with(tl)
    p.suspend()
    assert p.next_event(T0) is None
    assert not p.offer(ShowUpdateData(timeline=tl, frame_id_base=BASE, beacon=True))
    assert p.next_event(T0) is None
    p.offer(ShowUpdateData(timeline=replace(tl.seeked(5, T0 + 300 * MS), revision=2), frame_id_base=BASE + 40))
    ev = p.next_event(T0 + 100 * MS)           # the old revision stays suspended until the new anchor
    assert (ev.frame_id, ev.frame, ev.pts_ns) == (BASE + 40, 5, T0 + 300 * MS)


def test_ticks_passed_over_are_listed_for_late_reports():
    p = player_with(timeline())
    p.mark_done(p.next_event(T0))
    ev = p.next_event(T0 + 450 * MS)
    assert ev.tick == 5 and p.skipped_ids(ev) == [BASE + 1, BASE + 2, BASE + 3, BASE + 4]


def test_reset_forgets_the_schedule():
    p = player_with(timeline())
    p.reset()
    assert p.next_event(T0) is None and p.offer(ShowUpdateData(timeline=timeline(), frame_id_base=BASE))


def test_the_state_the_node_reports_follows_the_schedule_its_asset_and_suspension():
    p = TimelinePlayer()
    assert p.state(T0) == "none"
    p.offer(ShowUpdateData(timeline=timeline(), frame_id_base=BASE))
    assert p.state(T0 - MS) == "none"             # scheduled, not begun
    assert p.state(T0) == "waiting"               # begun, but the asset is not here
    p.add_asset(AssetFiles(asset_id=AID, manifest=b"{}", blob_paths={}))
    assert p.state(T0) == "playing" and p.state(None) == "none"
    p.offer(ShowUpdateData(timeline=timeline(revision=2, paused=True, anchor_ns=T0 + 100 * MS), frame_id_base=BASE))
    assert p.state(T0 + 50 * MS) == "playing" and p.state(T0 + 100 * MS) == "paused"
    p.suspend()
    assert p.state(T0 + 100 * MS) == "suspended"
    p.offer(ShowUpdateData(stop_at_ns=T0 + 200 * MS, stop_revision=3))
    assert p.state(T0 + 150 * MS) == "paused" and p.state(T0 + 200 * MS) == "none"


def test_frames_are_decoded_from_the_files_passed_without_a_cache(tmp_path):
    img = (np.arange(4 * 6 * 3, dtype=np.float32) / 100).reshape(4, 6, 3)
    path = tmp_path / "f.npy"
    np.save(path, img)
    data = path.read_bytes()
    sha = sha256_hex(data)
    m = Manifest(kind="still", name="s", width=6, height=4, channels=3, bit_depth=32, frames=1,
                 blobs=(Blob(sha256=sha, size=len(data), name="f.npy"),))
    files = AssetFiles(asset_id=m.asset_id, manifest=m.canonical(), blob_paths={sha: str(path)})
    assert AssetFilesView(files).ready(m.asset_id)
    p = TimelinePlayer(depth=2)
    p.offer(ShowUpdateData(timeline=timeline(asset_id=m.asset_id, frames=1, loop=True), frame_id_base=BASE))
    ev = p.next_event(T0)
    with pytest.raises(FrameError, match="not in the node's cache"):
        p.frame(ev, 1.0)
    p.add_asset(files)
    try:
        assert np.array_equal(p.frame(ev, 5.0), img)
    finally:
        p.close()


def test_fit_frame_resamples_to_the_content_size():
    img = np.arange(2 * 2 * 1, dtype=np.uint8).reshape(2, 2, 1)
    out = fit_frame(img, (4, 4))
    assert out.shape == (4, 4, 1) and out[0, 0, 0] == 0 and out[3, 3, 0] == 3
    assert fit_frame(img, (2, 2)) is img


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS in /proc/self/status")


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads /proc")
@pytest.mark.parametrize("how", ["stop", "suspend"])
def test_a_stop_or_a_suspension_closes_the_video_decoder_and_gives_its_memory_back(tmp_path, how):
    """After a stop (or a coordinator frame suspending the timeline) the presenter's process does not
    keep the video's decoder (its frame pool: six or more pictures) nor the memory glibc would keep
    once it is freed (node/heap_trim.py)."""
    w, h, n = 1280, 720, 24
    path = tmp_path / "v.mp4"
    write_clip(path, size=(w, h), fps=30, seconds=n / 30)
    data = path.read_bytes()
    sha = sha256_hex(data)
    m = Manifest(kind="video", name="v.mp4", blobs=(Blob(sha, len(data), "v.mp4"),), width=w, height=h, channels=3,
                 bit_depth=8, frames=n, fps=30.0)
    files = AssetFiles(asset_id=m.asset_id, manifest=m.canonical(), blob_paths={sha: str(path)})
    p = TimelinePlayer()
    p.add_asset(files)
    p.offer(ShowUpdateData(timeline=timeline(asset_id=m.asset_id, frames=n, rate=Fraction(30)), frame_id_base=BASE))
    p.offer(ShowUpdateData(stop_at_ns=T0 + 10 * NS // 30 + 1, stop_revision=2))
    try:
        after, shown = T0, 0
        while (ev := p.next_event(after)) is not None and ev.kind == "frame":
            p.frame(ev, 10.0)         # the frame as the presenter takes it (its planes: views of the decoder's)
            p.mark_done(ev)
            after, shown = ev.pts_ns + 1, shown + 1
        assert shown >= 9 and ev is not None and ev.kind == "stop"
        assert p.decode_stats() is not None
        playing = _rss_mb()
        if how == "stop":
            p.mark_done(ev)
        else:
            p.suspend()
        assert p.decode_stats() is None          # no decoder kept for a show that stopped
        # the decoder's pictures (1.4 MB each at 720p 4:2:0) and context go back to the system
        wait_until(_rss_mb, lambda mb: mb < playing - 4.0, what=f"resident memory below {playing - 4.0:.1f} MB "
                   f"(playing: {playing:.1f} MB) once the stopped video's decoder closed", timeout=30.0)
    finally:
        p.close()
