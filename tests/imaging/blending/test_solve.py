"""compute_blend on synthetic planar rigs whose light is known exactly: the forward model (each
node's maps sampled as the node samples them, imaging.blending.predict) must give the target, even
and seamless; the target obeys its bounds; headroom, lost projectors and lamp gains behave; bad
input is refused in one line."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from imaging.blending.contributions import Contributions, luma
from imaging.blending.envelope import chamfer_distance
from imaging.blending.errors import BlendError
from imaging.blending.metrics import seam_step, uniformity
from imaging.blending.predict import predict
from imaging.blending.solve import compute_blend, map_size
from imaging.blending.synthetic import rectangle_rig, tiled_rects, wall_rects

CAM = (320, 240)
WHITES = [(1.0, 1.0, 1.0), (1.12, 1.0, 0.88), (0.9, 1.02, 1.1)]


def wall(**kw) -> Contributions:
    return rectangle_rig(wall_rects(3, 0.2, CAM), camera_size=CAM, projector_size=(320, 200), peaks=[1.0, 0.82, 1.15],
                         whites=WHITES, **kw)


def table(seed: int = 1) -> Contributions:
    rng = np.random.default_rng(seed)
    return rectangle_rig(tiled_rects(5, 5, CAM, seed=seed), camera_size=CAM, surface=(30, 30, 290, 210),
                         peaks=list(rng.uniform(0.85, 1.15, 25)), whites=[tuple(rng.uniform(0.85, 1.15, 3)) for _ in range(25)])


def lit(c: Contributions, maps, **kw) -> np.ndarray:
    return predict(c, maps, 1.0, **kw) - predict(c, maps, 0.0, **kw)


@pytest.mark.parametrize("headroom", [0.0, None])
def test_a_three_projector_wall_becomes_even_and_seamless(headroom):
    c = wall()
    sol = compute_blend(c, headroom=headroom, map_scale=4)
    before, after = lit(c, {}), lit(c, sol.maps)
    assert uniformity(before, sol.target, sol.covered) > 0.3
    assert uniformity(after, sol.target, sol.covered) < 0.01
    for ch in range(3):
        assert uniformity(after, sol.target, sol.covered, channel=ch) < 0.01
    assert seam_step(before, c, sol.covered, target=sol.target) > 0.3
    assert seam_step(after, c, sol.covered, target=sol.target) < 0.01
    # the light is the target itself, not only proportional to it
    m = sol.covered & (luma(sol.target) > 0)
    assert abs(np.median(luma(after)[m] / luma(sol.target)[m]) - 1) < 0.005
    # the black floor is even too: beta lifts it where fewer projectors reach
    black = luma(predict(c, sol.maps, 0.0))
    b0 = luma(predict(c, {}, 0.0))
    assert np.ptp(b0[m]) / np.median(b0[m]) > 0.5
    # (but for a line of map texels along each frame edge: a projector's own black steps there, and the maps
    # are too coarse to step with it)
    edges = np.zeros(m.shape, bool)
    for s in c.slots:
        fp = c.footprint(s)
        edges |= ndimage.binary_dilation(fp & ~ndimage.binary_erosion(fp), iterations=2)
    away = m & ~edges
    assert np.percentile(np.abs(black[away] / sol.black_target[away] - 1), 99) < 0.01
    # one common white point: the target's chromaticity is the same everywhere
    chroma = sol.target[m] / luma(sol.target)[m][:, None]
    assert np.allclose(chroma, sol.white_point, atol=1e-5)
    assert sol.uncovered["p0"] > 0.5 and sol.uncovered["p1"] < sol.uncovered["p0"]


def test_maps_have_the_node_grid_and_range():
    c = wall()
    sol = compute_blend(c, map_scale=3)
    for s, (alpha, beta) in sol.maps.items():
        mw, mh = map_size(c.projector_size[s], 3)
        assert alpha.shape == (mh, mw, 3) and beta.shape == (mh, mw)
        assert alpha.dtype == np.float32 and beta.dtype == np.float32
        assert 0.0 <= alpha.min() and alpha.max() <= 1.0 and 0.0 <= beta.min() and beta.max() <= 1.0
    assert (mw, mh) == (107, 67)


def test_the_target_is_smooth_under_what_every_point_reaches_and_not_the_darkest_point():
    c = wall()
    sol = compute_blend(c, headroom=0.0, smoothness=1.0)
    L = luma(sol.target)
    slope = sol.info["slope_per_px"]
    inside = sol.covered
    logL = np.where(inside, np.log(np.where(inside, L, 1.0)), np.nan)
    for dy, dx in ((0, 1), (1, 0), (1, 1)):
        a, b = logL[dy:, dx:], logL[:logL.shape[0] - dy, :logL.shape[1] - dx]
        ok = np.isfinite(a) & np.isfinite(b)
        assert np.all(np.abs(a - b)[ok] <= slope * chamfer_distance(dx, dy) + 1e-6)
    # no projector is asked for more than it has (the maps are not clipped: the light meets the target)
    after = lit(c, sol.maps)
    assert np.percentile(np.abs(luma(after)[inside] / L[inside] - 1), 99) < 0.01


def test_where_more_projectors_overlap_the_target_rises_above_the_darkest_point():
    c = rectangle_rig([(10, 10, 190, 150), (130, 10, 310, 150), (10, 90, 190, 230), (130, 90, 310, 230)],
                      camera_size=CAM, projector_size=(320, 200))
    sol = compute_blend(c, headroom=0.0)
    L, reach = luma(sol.target), luma(lit(c, {}))
    m = sol.covered
    assert L[m].mean() > 1.2 * reach[m].min()           # "the darkest pixel everywhere" would be reach.min()
    assert uniformity(lit(c, sol.maps), sol.target, m) < 0.01


def test_a_twenty_five_projector_table_and_the_headroom_that_covers_a_loss():
    c = table()
    auto = compute_blend(c, headroom=None)
    none = compute_blend(c, headroom=0.0)
    fixed = compute_blend(c, headroom=0.3)
    assert uniformity(lit(c, auto.maps), auto.target, auto.covered) < 0.01
    assert none.brightness_cost == 0.0 and none.headroom == 0.0
    # auto: about 1/25 of the light is held back, and costs about that
    assert 0.03 < auto.brightness_cost < 0.1 and 0.02 < auto.headroom < 0.1
    assert fixed.headroom == 0.3 and 0.28 < fixed.brightness_cost < 0.32
    # losing the centre projector: re-blended from the same measurement, the light stays the old target
    lost = compute_blend(c, headroom=None, lost=["p12"])
    assert "p12" not in lost.maps and lost.lost == ("p12",)
    after = lit(c, lost.maps, lost=("p12",))
    m = auto.covered
    assert np.percentile(np.abs(luma(after)[m] / luma(auto.target)[m] - 1), 99) < 0.01
    # without headroom the same loss darkens its footprint
    lost0 = compute_blend(c, headroom=0.0, lost=["p12"])
    dark = luma(lit(c, lost0.maps, lost=("p12",)))
    assert np.percentile(dark[m] / luma(none.target)[m], 1) < 0.97


def test_a_dimmed_lamp_is_re_blended_from_its_measured_gain():
    c = table(seed=2)
    auto = compute_blend(c)
    dim = compute_blend(c, lamp_gains={"p7": 0.5})
    after = lit(c, dim.maps, gains={"p7": 0.5})
    m = auto.covered
    assert np.percentile(np.abs(luma(after)[m] / luma(auto.target)[m] - 1), 99) < 0.01
    unchanged = lit(c, auto.maps, gains={"p7": 0.5})
    assert np.percentile(np.abs(luma(unchanged)[m] / luma(auto.target)[m] - 1), 99) > 0.01


@pytest.mark.parametrize("headroom", [-0.1, 0.95, math.nan, "lots", True])
def test_a_headroom_outside_0_to_0_9_is_refused_in_one_line(headroom):
    with pytest.raises(BlendError, match="headroom must be 'auto' or a number in 0..0.9") as info:
        compute_blend(wall(), headroom=headroom)
    assert "\n" not in str(info.value)


def test_auto_is_the_default_and_bad_requests_are_refused():
    c = wall()
    assert compute_blend(c, headroom="auto").headroom == compute_blend(c).headroom
    with pytest.raises(BlendError, match="no projector left"):
        compute_blend(c, lost=c.slots)
    with pytest.raises(BlendError, match="not in the measured contributions"):
        compute_blend(c, lost=["nope"])
    with pytest.raises(BlendError, match="lamp gain for p0"):
        compute_blend(c, lamp_gains={"p0": -1.0})
    with pytest.raises(BlendError, match="map_scale"):
        compute_blend(c, map_scale=0)
