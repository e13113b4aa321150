"""The presenter's previews (console thumbnails): what the projector shows, read back between frames
only, downscaled by area, at most two a second, and never at the cost of a frame's time.

As in test_presenter.py: a real renderer (EGL, llvmpipe) and an offscreen output, on a clock the
test moves; a preview's cost is simulated by moving that clock while it is made.
"""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

import node.preview as preview_mod
from node.image_files import decode_png
from node.preview import MAX_HEIGHT, MAX_WIDTH, downscale, preview_factor
from node.records import FrameOrder, PreviewRecord

_spec = importlib.util.spec_from_file_location("presenter_harness", Path(__file__).with_name("test_presenter.py"))
harness = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(harness)
MS, W, H = harness.MS, harness.W, harness.H


@pytest.fixture
def rig():
    r = harness.Rig()
    r.presenter.open()
    r.presenter.handle("assignment", harness.assignment())
    r.presenter.handle("clock", harness.estimate())
    for value in (10, 20, 30):
        r.presenter.handle("content", (f"c{value}", harness.still(value)))
    r.reports.clear()
    yield r
    r.presenter.close()


def previews(rig) -> list[PreviewRecord]:
    return [p for k, p in rig.reports if k == "preview"]


def costly_previews(monkeypatch, rig, cost_ms: float) -> None:
    """Every preview takes ``cost_ms`` of the test's clock (its PNG encoding does)."""
    encode = preview_mod.encode_preview

    def slow(small):
        rig.host.advance(int(cost_ms * MS))
        return encode(small)

    monkeypatch.setattr(preview_mod, "encode_preview", slow)
    rig.presenter.previews._costs.clear()
    rig.presenter.previews._costs.append(int(cost_ms * MS))    # as the one timed at open would say


def stream(rig, n: int, interval_ms: float, *, ask_every_frame: bool = True) -> list[FrameOrder]:
    """Frames ``interval_ms`` apart (contents c10, c20, c30 in turn), a preview asked before each."""
    start = rig.rig_now() + 20 * MS
    frames = [FrameOrder(frame_id=i + 1, pts_ns=start + int(i * interval_ms * MS), content_id=f"c{10 * (i % 3 + 1)}",
                         space="projector", apply_lut=False, tag="play") for i in range(n)]
    for i, f in enumerate(frames):
        if ask_every_frame:
            rig.presenter.handle("preview", i + 1)
        rig.show(f)
    return frames


# ----------------------------------------------------------------------------- downscaling


def test_downscale_is_the_rounded_mean_of_each_block_edges_included():
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (23, 37, 3), dtype=np.uint8)
    for k in (1, 2, 3, 5, 7, 40):
        out = downscale(img, k)
        hb, wb = -(-23 // k), -(-37 // k)
        assert out.shape == (hb, wb, 3) and out.dtype == np.uint8
        ref = np.array([[img[a * k:(a + 1) * k, b * k:(b + 1) * k].reshape(-1, 3).mean(0) for b in range(wb)]
                        for a in range(hb)])
        np.testing.assert_array_equal(out, np.floor(ref + 0.5).astype(np.uint8))
    # the default factor keeps a preview within MAX_WIDTH x MAX_HEIGHT, whatever the output's aspect
    for w, h in ((1920, 1080), (1080, 1920), (1366, 768), (4096, 2160), (160, 120), (64, 36)):
        k = preview_factor(w, h)
        assert -(-w // k) <= MAX_WIDTH and -(-h // k) <= MAX_HEIGHT and (k == 1 or -(-w // (k - 1)) > MAX_WIDTH
                                                                            or -(-h // (k - 1)) > MAX_HEIGHT)
    with pytest.raises(ValueError):
        downscale(np.zeros((4, 4), np.uint8))


# ----------------------------------------------------------------------------- through the presenter


def test_a_preview_after_a_swap_is_what_the_renderer_shows_downscaled(rig):
    from dataclasses import replace

    w, h = 400, 300                     # k = 3: 134 x 100
    p = rig.presenter
    p.handle("assignment", replace(harness.assignment(revision=2), width=w, height=h, content_size=(w, h)))
    yy, xx = np.mgrid[0:h, 0:w]
    img = np.stack([(xx * 255 // (w - 1)), (yy * 255 // (h - 1)), ((xx // 10 + yy // 10) % 2) * 200], -1).astype(np.uint8)
    p.handle("content", ("pattern", img))
    rig.reports.clear()
    p.handle("preview", 6)                 # nothing shown yet: black, at the output's new size
    [black] = previews(rig)
    assert (black.frame_id, black.width, black.height) == (0, 134, 100) and not decode_png(black.png).any()
    rig.host.advance(500 * MS)
    rig.reports.clear()
    rig.show(rig.frame(41, in_ms=10, content="pattern"))
    p.handle("preview", 7)
    assert previews(rig) == [], "no next frame known: it may be a sequence's first (made when idle)"
    p.idle()
    [pv] = previews(rig)
    assert (pv.request_id, pv.frame_id, pv.width, pv.height, pv.output_width, pv.output_height) == (7, 41, 134, 100, w, h)
    kinds = [k for k, _ in rig.reports]
    assert kinds.index("preview") > kinds.index("swap")
    small = decode_png(pv.png)
    assert small.shape == (100, 134, 3) and small.dtype == np.uint8
    # the renderer's own full-resolution read-back of that frame (the output kept it), downscaled the same way
    full = rig.out.last_image
    assert full.shape == (h, w, 3) and rig.out.last_info.frame_id == 41
    np.testing.assert_array_equal(small, downscale(full))
    np.testing.assert_array_equal(small, downscale(img))      # projector space, no LUT: the content itself
    assert len(pv.png) < 60_000


def test_previews_come_only_after_swaps_at_most_twice_a_second_and_no_frame_is_late(rig, monkeypatch):
    """Asked before every one of 300 frames 10 ms apart, with previews that cost 3 ms: each is
    made right after a swap (never between a render and its swap), showing the frame just
    swapped, at most one per half second, and every frame is swapped exactly at its time."""
    costly_previews(monkeypatch, rig, 3.0)
    events: list[tuple[str, int]] = []
    p = rig.presenter
    render, swap, make = p.renderer.render, rig.out.swap, p.previews.make
    monkeypatch.setattr(p.renderer, "render", lambda *a, **k: (events.append(("render", 0)), render(*a, **k))[1])
    monkeypatch.setattr(rig.out, "swap", lambda: (events.append(("swap", 0)), swap())[1])
    monkeypatch.setattr(p.previews, "make", lambda r, f: (events.append(("preview", f)), make(r, f))[1])

    frames = stream(rig, 300, 10.0)
    assert rig.drops == [] and len(rig.swaps) == 300
    assert all(s.swap_rig_ns == s.pts_ns for s in rig.swaps), "a frame was swapped after its time"
    made = previews(rig)
    span_s = (frames[-1].pts_ns - frames[0].pts_ns) / 1e9 + 0.02     # the first asked 20 ms before frame 1
    assert 5 <= len(made) <= span_s * 2 + 1, len(made)
    # after every render comes its swap before any preview: the framebuffer then holds what is shown
    # (the first, asked before any frame, is of the black the presenter opened with)
    assert made[0].frame_id == 0 and events[0] == ("preview", 0)
    last = None
    for kind, _ in events[1:]:
        if kind == "preview":
            assert last == "swap", events
        if kind in ("render", "swap"):
            last = kind
    shown = {0: 0, **{f.frame_id: int(f.content_id[1:]) for f in frames}}
    for pv in made:
        assert (decode_png(pv.png) == shown[pv.frame_id]).all(), "the preview is not of the frame just swapped"
    made_at = [s.swap_rig_ns for s in rig.swaps if s.frame_id in {pv.frame_id for pv in made[1:]}]
    assert 20 + (made[1].frame_id - 1) * 10 >= 500 and min(np.diff(made_at)) >= 500 * MS   # ms after the first


def test_a_preview_that_would_not_fit_before_the_next_frame_waits_for_room(rig, monkeypatch):
    costly_previews(monkeypatch, rig, 8.0)         # 2 x 8 ms + margin does not fit in 10 ms
    frames = stream(rig, 100, 10.0)
    assert rig.drops == [] and all(s.swap_rig_ns == s.pts_ns for s in rig.swaps)
    assert [pv.frame_id for pv in previews(rig)] == [0], "only the black one, asked before the sequence began"
    assert rig.presenter.previews.deferred > 0
    rig.host.advance(50 * MS)                      # the sequence is over: the presenter idles
    rig.presenter.idle()
    pv = previews(rig)[-1]
    assert pv.frame_id == frames[-1].frame_id and (decode_png(pv.png) == 10 * (99 % 3 + 1)).all()


def test_a_still_is_previewed_when_idle_and_again_only_half_a_second_later(rig):
    rig.show(rig.frame(1, in_ms=5, content="c20"))
    p = rig.presenter
    p.handle("preview", 1)
    assert previews(rig) == [], "a frame just swapped may be a sequence's first: the idle loop makes it"
    p.idle()
    [pv] = previews(rig)
    assert (pv.request_id, pv.frame_id) == (1, 1) and (decode_png(pv.png) == 20).all()
    p.handle("preview", 2)
    p.handle("preview", 3)                         # asked twice within the half second: one answer, the newest
    p.idle()
    assert len(previews(rig)) == 1
    rig.host.advance(500 * MS)
    p.idle()
    assert [v.request_id for v in previews(rig)] == [1, 3]
    rig.host.advance(2000 * MS)
    p.idle()                                       # nothing asked: nothing made
    assert len(previews(rig)) == 2
    p.handle("preview", 4)                         # the still has been up for seconds: made at once
    assert [v.request_id for v in previews(rig)] == [1, 3, 4]


def test_no_preview_of_a_frame_rendered_but_not_shown(rig):
    rig.show(rig.frame(1, in_ms=5, content="c10"))
    rig.out.prepare_ns = 3 * MS                    # the next frame is ready 2 ms after its time: dropped
    rig.show(rig.frame(2, in_ms=1, content="c30"))
    assert [d.frame_id for d in rig.drops] == [2]
    rig.out.prepare_ns = 0
    rig.presenter.handle("preview", 1)
    rig.presenter.idle()
    assert previews(rig) == [], "the framebuffer holds frame 2, which the projector never showed"
    rig.show(rig.frame(3, in_ms=5, content="c20"))
    [pv] = previews(rig)
    assert pv.frame_id == 3 and (decode_png(pv.png) == 20).all()


def test_previews_during_a_timeline_show_keep_every_tick_on_time(rig, monkeypatch, tmp_path):
    costly_previews(monkeypatch, rig, 3.0)
    files = harness._still_asset(tmp_path)
    p = rig.presenter
    p.handle("asset", files)
    p.handle("show", harness._timeline_update(files, rig.rig_now() + 60 * MS))   # 10 ticks a second
    harness.first_frame_decoded(p)
    for i in range(12):
        p.handle("preview", i + 1)
        p.timeline_step()
    assert len(rig.swaps) == 12 and rig.drops == []
    assert all(s.swap_rig_ns == s.pts_ns for s in rig.swaps)
    made = previews(rig)
    assert 2 <= len(made) <= 4 and all(pv.frame_id >= 500 for pv in made[1:])
