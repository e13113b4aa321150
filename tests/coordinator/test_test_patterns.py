"""Test patterns, pixel by pixel, against references built another way (index arithmetic on
coordinate grids instead of slicing), and the layout's health and identify data they go with."""
from __future__ import annotations

import math

import numpy as np
import pytest

from coordinator import test_patterns as tp
from coordinator.api import BlendStatus, NodeState, NodeStatus, RefusedPeer, RigStatus
from coordinator.console.health import health_view
from coordinator.identify import identify_cards, identify_marks, slot_colour
from coordinator.late_window import LateWindow
from coordinator.unposed import unposed_warning

SIZES = [(64, 36), (1920, 1080), (37, 23)]


def _lines_ref(size, *, step=None, centre=False):
    """Which pixels are lit, from coordinate grids: (h, w) bool."""
    w, h = size
    t = max(1, round(min(w, h) / 540))
    x = np.arange(w)[None, :]
    y = np.arange(h)[:, None]
    if step is not None:
        cols = (x % step < t) | (x >= w - t)
        rows = (y % step < t) | (y >= h - t)
    else:
        cx, cy = w // 2 - t // 2, h // 2 - t // 2
        cols = ((x >= cx) & (x < cx + t)) | (x < t) | (x >= w - t)
        rows = ((y >= cy) & (y < cy + t)) | (y < t) | (y >= h - t)
    return np.broadcast_to(cols, (h, w)) | np.broadcast_to(rows, (h, w))


@pytest.mark.parametrize("size", SIZES)
def test_grid_lines_fall_where_the_pitch_says(size):
    w, h = size
    img = tp.test_pattern("grid", size)
    assert img.shape == (h, w, 3) and img.dtype == np.uint8
    step = max(4, min(w, h) // 8)
    lit = _lines_ref(size, step=step)
    np.testing.assert_array_equal(img.any(axis=2), lit)
    assert np.all(img[lit] == 255) and np.all(img[~lit] == 0)
    if size == (1920, 1080):    # 2-pixel lines every 135 pixels at 1080p
        assert tp.grid_step(size) == 135 and tp.line_width(size) == 2
        assert img[500, 135:137].all() and not img[500, 137].any() and not img[500, 134].any()


@pytest.mark.parametrize("size", SIZES)
def test_crosshair_is_a_centre_cross_inside_a_border(size):
    img = tp.test_pattern("crosshair", size, colour=(10, 200, 30))
    lit = _lines_ref(size)
    assert np.all(img[lit] == (10, 200, 30)) and np.all(img[~lit] == 0)


@pytest.mark.parametrize("size", SIZES)
def test_colour_bars_in_their_order(size):
    w, h = size
    img = tp.test_pattern("bars", size)
    colours = [(255, 255, 255), (255, 255, 0), (0, 255, 255), (0, 255, 0),
               (255, 0, 255), (255, 0, 0), (0, 0, 255), (0, 0, 0)]
    starts = [i * w // 8 for i in range(8)]          # bar i starts at column i*w//8
    bar = np.searchsorted(starts, np.arange(w), side="right") - 1
    np.testing.assert_array_equal(img[h // 2], np.array(colours, np.uint8)[bar])
    assert np.all(img == img[:1])                   # the same in every row


def test_white_label_and_refusals():
    assert np.all(tp.test_pattern("white", (40, 30)) == 255)
    assert np.all(tp.test_pattern("white", (40, 30), colour=(1, 2, 3)) == (1, 2, 3))
    plain = tp.test_pattern("grid", (320, 180))
    labelled = tp.test_pattern("grid", (320, 180), label="r1c2")
    changed = np.argwhere((plain != labelled).any(axis=2))
    assert len(changed) > 200                       # the name is written ...
    assert changed[:, 0].max() < 180 // 2           # ... in the upper part of the frame
    with pytest.raises(ValueError, match="choose one of white, grid, crosshair, bars"):
        tp.test_pattern("zebra", (64, 36))
    with pytest.raises(ValueError, match="at least 8x8"):
        tp.test_pattern("grid", (4, 36))
    with pytest.raises(ValueError, match="colour"):
        tp.test_pattern("white", (64, 36), colour=(300, 0, 0))


def test_identify_gives_each_slot_its_number_and_a_distinct_colour():
    slots = [f"r{r}c{c}" for r in range(1, 6) for c in range(1, 6)]
    marks = identify_marks(slots)
    assert [marks[s]["number"] for s in slots] == list(range(1, 26))
    assert len({marks[s]["colour"] for s in slots}) == 25
    # neighbours in the rig's order differ in hue by the golden angle: far apart on the wheel
    hues = [np.angle(complex(*_hue_vec(slot_colour(i)))) for i in range(25)]
    gaps = [abs((hues[i + 1] - hues[i] + np.pi) % (2 * np.pi) - np.pi) for i in range(24)]
    assert min(gaps) > 1.5
    cards = identify_cards({"a": (160, 90), "b": (160, 90)})
    assert cards["a"].shape == (90, 160, 3) and not np.array_equal(cards["a"], cards["b"])
    assert tuple(cards["a"][45, 5]) == slot_colour(0) and tuple(cards["b"][45, 5]) == slot_colour(1)


def _hue_vec(rgb):
    r, g, b = (c / 255 for c in rgb)
    return (r - (g + b) / 2, (g - b) * math.sqrt(3) / 2)


def test_late_window_counts_only_recent_misses():
    lw = LateWindow(window_s=10.0, every_s=1.0)
    assert lw.observe(0.0, {"a": 5, "b": 0}) == (0.0, {})     # the first look: nothing known to be recent
    for t in range(1, 12):
        span, missed = lw.observe(float(t), {"a": 5, "b": 0})
    assert span >= 10.0 and missed == {}            # five misses long ago are no alarm now
    span, missed = lw.observe(12.0, {"a": 7, "b": 1})
    assert missed == {"a": 2, "b": 1}
    assert lw.observe(12.5, {"a": 1, "b": 1})[1] == {"a": 1, "b": 1}   # a rejoined node counts from 0


def test_health_view_names_what_needs_the_operator():
    now = 1_000_000.0
    nodes = (NodeStatus("r1c1", state=NodeState.LIVE, clock_rtt_ms=0.4, clock_drift_ppm=3.1, pose_kind="homography"),
             NodeStatus("r1c2", state=NodeState.LOST, last_seen_age_ms=12_000, pose_kind="homography"),
             NodeStatus("r1c3", state=NodeState.LIVE, clock_rtt_ms=0.0, pose_kind="none",
                        assets_wanted=2, assets_ready=1, asset_bytes_have=50, asset_bytes_total=200),
             NodeStatus("r1c4"))
    st = RigStatus(rig_id="x", rig_name="x", nodes=nodes, late_recent=(("r1c1", 4),), late_window_s=60.0,
                   refusals=(RefusedPeer("ipv4:10.0.0.9:1", "r9c9", "slot 'r9c9' is not in this rig", age_s=30.0),),
                   blend=BlendStatus(state="failover", lost=("r1c2",), covered=True, since=now - 12,
                                     message="r1c2 lost 12 s ago: 3 projectors cover its footprint"),
                   unposed_warning=unposed_warning(["r1c3"]))
    h = health_view(st, now=now)
    assert h["level"] == "alarm" and h["counts"] == {"slots": 4, "live": 2, "joined": 0, "lost": 1, "expected": 1,
                                                     "unposed": 2}
    by_kind = {a["kind"]: a for a in h["alarms"]}
    assert by_kind["lost"]["since"] == now - 12 and by_kind["lost"]["slots"] == ["r1c2"]
    assert h["alarms"][0]["level"] == "alarm"       # the worst first
    assert "4 frames missed" in by_kind["late"]["text"] and "last minute" in by_kind["late"]["text"]
    assert by_kind["clock"]["slots"] == ["r1c3"]
    assert "r1c3 1/2 (25 %)" in by_kind["assets"]["text"]
    assert "r1c4" in by_kind["missing"]["text"] and "1 projector never connected" in by_kind["missing"]["text"]
    assert "1 refusal in the last 5 min" in by_kind["refusals"]["text"]
    assert "3 projectors cover its footprint" in by_kind["failover"]["text"]
    assert h["unposed_warning"].startswith("1 slot has no pose and shows black: r1c3")
    calm = health_view(RigStatus(rig_id="x", rig_name="x", nodes=(nodes[0],), showing="show grey card"), now=now)
    assert calm["level"] == "ok" and calm["alarms"] == []
    solo = health_view(RigStatus(rig_id="x", rig_name="x", nodes=(nodes[0],), showing="solo r1c1: show grey card"))
    assert solo["level"] == "warn" and solo["alarms"][0]["kind"] == "solo"
