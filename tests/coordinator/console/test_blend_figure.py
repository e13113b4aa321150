"""The blend's before/after figure, read back from its pixels: the colour map against its closed form,
the colour bar's rows against the values they stand for, each panel's blocks against the ratio they
were drawn from, points no projector reaches in their own colour, and the span chosen from the data."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from coordinator.console.blend_figure import (NOT_COVERED, SPANS, choose_span, colourise, diverging_lut,
                                              figure_png, ratio_figure)

LOW, MID, HIGH = np.array([59, 76, 192]), np.array([221, 221, 221]), np.array([180, 4, 38])


def levels_of(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) uint8 colours -> the map's nearest level (..., ) and the distance to it."""
    lut = diverging_lut().astype(np.int64)
    d = ((rgb.astype(np.int64)[..., None, :] - lut) ** 2).sum(-1)
    return np.argmin(d, axis=-1), np.sqrt(d.min(axis=-1))


def test_the_colour_map_is_blue_grey_red_and_linear_on_each_half():
    lut = diverging_lut()
    assert lut.shape == (256, 3) and lut.dtype == np.uint8
    assert (lut[0] == LOW).all() and (lut[255] == HIGH).all()
    for i in (0, 60, 127, 128, 200, 255):                   # the closed form of each half
        t = i / 255
        ref = LOW + (MID - LOW) * 2 * t if t < 0.5 else MID + (HIGH - MID) * (2 * t - 1)
        assert np.abs(lut[i].astype(float) - ref).max() <= 0.5 + 1e-9, (i, lut[i], ref)
    assert len({tuple(c) for c in lut}) > 240                 # distinct enough to be read back


def test_colourise_maps_values_to_levels_and_the_uncovered_to_dark_grey():
    span = 0.1
    r = np.array([[0.5, 0.9, 0.95, 1.0], [1.05, 1.1, 2.0, np.nan]], np.float32)
    out = colourise(r, span)
    lut = diverging_lut()
    expect = [0, 0, round(255 * 0.25), round(255 * 0.5), round(255 * 0.75), 255, 255]
    for (i, j), level in zip(np.ndindex(2, 4), expect):   # a level exactly between two may round either way
        assert any((out[i, j] == lut[k]).all() for k in (level - 1, level, level + 1) if 0 <= k < 256), \
            (i, j, out[i, j], level)
    assert (out[0, 0] == lut[0]).all() and (out[1, 2] == lut[255]).all()      # beyond the span: its ends
    assert tuple(out[1, 3]) == NOT_COVERED
    with pytest.raises(ValueError, match=r"\(h, w\)"):
        colourise(np.ones((2, 2, 3)), span)
    with pytest.raises(ValueError, match="positive"):
        colourise(np.ones((2, 2)), 0.0)


def test_the_span_is_the_smallest_that_holds_the_p99_deviation():
    rng = np.random.default_rng(1)
    small = 1 + rng.uniform(-0.015, 0.015, (50, 50))
    assert choose_span([small]) == 0.02
    assert choose_span([small, 1 + rng.uniform(-0.08, 0.08, (50, 50))]) == 0.1   # shared by both panels
    assert choose_span([np.full((4, 4), np.nan)]) == 0.1                          # nothing to go by
    assert choose_span([np.full((4, 4), 9.0)]) == SPANS[-1]


def test_the_figure_reads_back_as_the_ratios_it_was_drawn_from():
    rng = np.random.default_rng(7)
    before = rng.uniform(0.8, 1.2, (4, 8)).astype(np.float32)     # blocks of known values
    before[0, 0] = np.nan
    after = (1 + rng.uniform(-0.01, 0.01, (4, 8))).astype(np.float32)
    png, layout = figure_png({"before": before, "after": after})
    fig = cv2.cvtColor(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    assert [fig.shape[1], fig.shape[0]] == layout["size"]
    span = layout["span"]
    assert span == choose_span([before, after]) == 0.2 and layout["range"] == [0.8, 1.2]

    # the colour bar: row y stands for 1 + span - 2 span y / (rows - 1), every row on the map
    x0, y0, x1, y1 = layout["colorbar"]
    rows = y1 - y0
    lv, dist = levels_of(fig[y0:y1, (x0 + x1) // 2])
    assert dist.max() <= 1.0
    expected = np.rint(255 * (1 - np.arange(rows) / (rows - 1)))
    assert np.abs(lv - expected).max() <= 1, np.abs(lv - expected).max()
    assert [t[0] for t in layout["ticks"]] == [1.2, 1.1, 1.0, 0.9, 0.8]
    assert layout["ticks"][0][1] == y0 and layout["ticks"][-1][1] == y1 - 1

    # each panel: the centre of every block is its ratio's colour (dark grey where no projector reaches)
    for name, ratio in (("before", before), ("after", after)):
        px0, py0, px1, py1 = layout["panels"][name]
        h, w = ratio.shape
        assert (px1 - px0) / (py1 - py0) == pytest.approx(w / h, rel=0.02)
        for i, j in np.ndindex(h, w):
            x = px0 + int((j + 0.5) * (px1 - px0) / w)
            y = py0 + int((i + 0.5) * (py1 - py0) / h)
            if not np.isfinite(ratio[i, j]):
                assert tuple(fig[y, x]) == NOT_COVERED
                continue
            level, d = levels_of(fig[y, x])
            value = 1 - span + 2 * span * level / 255
            assert d <= 1.0 and abs(value - ratio[i, j]) <= 2 * span / 255 + 1e-6, (name, i, j, value, ratio[i, j])


def test_one_picture_is_enough_and_none_is_refused():
    fig, layout = ratio_figure({"after": np.ones((30, 40), np.float32)}, span=0.05)
    assert list(layout["panels"]) == ["after"] and layout["range"] == [0.95, 1.05]
    assert fig.dtype == np.uint8 and fig.shape[2] == 3
    with pytest.raises(ValueError, match="no ratio picture"):
        ratio_figure({"elsewhere": np.ones((3, 3))})
    with pytest.raises(ValueError, match="non-empty"):
        ratio_figure({"before": np.ones((0, 3))})
