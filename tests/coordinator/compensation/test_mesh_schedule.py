"""The dot schedule of a mesh rig's light transport and the texture's edge padding, against brute force."""
from __future__ import annotations

import numpy as np
from scipy.spatial.distance import cdist

from imaging.compensation.mesh_geometry import TexelGrid, dot_conflicts, schedule_dots
from coordinator.compensation.mesh_rig import reaching_texels
from imaging.compensation.texture_space import TexelMap, padded, padding_index


def _positions(w: int, h: int, rng) -> np.ndarray:
    """Camera positions of a w x h texture in two charts: a regular lattice (2.5 px per texel) whose right
    half is folded back over the left half's edge, the way a uv seam puts far texels side by side."""
    xs, ys = np.meshgrid(np.arange(w), np.arange(h))
    X = np.where(xs < w // 2, xs * 2.5, (w - 1 - xs) * 2.5 + (w // 2) * 2.5 + 1.3)
    Y = ys * 2.5 + np.where(xs < w // 2, 0.0, 1.1)
    pos = np.stack([X, Y], -1).reshape(-1, 2) + rng.normal(0, 0.3, (w * h, 2))
    return np.rint(pos).astype(np.int64)


def test_schedule_separates_every_windows_and_lights_each_seen_texel_once():
    rng = np.random.default_rng(5)
    w, h, radius, guard = 24, 16, 2, 1
    base = _positions(w, h, rng)
    seen = rng.random(w * h) < 0.9
    sched = schedule_dots(base, seen, (h, w), radius, guard=guard)
    lit = np.concatenate([sched.dots(k) for k in range(len(sched))])
    assert sorted(lit.tolist()) == np.flatnonzero(seen).tolist()          # each seen texel once, nothing else
    assert np.array_equal(sched.lit, seen)
    for k in range(len(sched)):                                          # brute force: no two windows meet
        d = sched.dots(k)
        dist = cdist(base[d], base[d], metric="chebyshev")
        np.fill_diagonal(dist, np.inf)
        assert dist.min() > 2 * radius + guard
        img = sched.pattern(k, value=255, dtype=np.uint8)
        assert img.shape == (h, w) and np.flatnonzero(img.ravel() == 255).tolist() == sorted(d.tolist())
    # the plain grid it starts from would leave dots whose windows meet (the fold) ...
    grid = TexelGrid(w, h, *sched.spacing)
    assert dot_conflicts(grid, base, seen, radius, guard=guard).any()
    # ... and the schedule costs a few patterns more than that grid, far fewer than a grid without conflicts
    assert len(grid) < len(sched) <= len(grid) + 12


def test_padding_copies_the_nearest_chart_texel_within_reach():
    rng = np.random.default_rng(1)
    on = np.zeros((20, 30), bool)
    on[3:9, 4:12] = True
    on[12:18, 15:27] = rng.random((6, 12)) < 0.95
    idx = padding_index(on, reach=2.0)
    ys, xs = np.nonzero(on)
    src = np.column_stack([ys, xs])
    for t in range(on.size):
        y, x = divmod(t, on.shape[1])
        d = np.hypot(src[:, 0] - y, src[:, 1] - x)
        if on[y, x] or d.min() > 2.0:
            assert idx[t] == t
        else:
            assert on.ravel()[idx[t]] and np.isclose(np.hypot(*np.subtract(divmod(int(idx[t]), 30), (y, x))), d.min())
    img = rng.random((20, 30, 3)).astype(np.float32)
    out = padded(img, idx)
    assert np.array_equal(out[on], img[on]) and np.array_equal(out.reshape(-1, 3), img.reshape(-1, 3)[idx])


def test_one_schedule_separates_the_windows_in_every_camera():
    rng = np.random.default_rng(7)
    w, h, radius, guard = 24, 16, 2, 1
    bases = np.stack([_positions(w, h, rng), _positions(w, h, rng)[::-1].copy()])   # the second camera: reversed
    seens = np.stack([rng.random(w * h) < 0.6, rng.random(w * h) < 0.6])
    sched = schedule_dots(bases, seens, (h, w), radius, guard=guard)
    assert np.array_equal(sched.lit, seens.any(axis=0))                 # each texel some camera sees, once
    for k in range(len(sched)):
        d = sched.dots(k)
        for base, seen in zip(bases, seens):                           # brute force, in each camera that sees them
            dd = d[seen[d]]
            if len(dd) > 1:
                dist = cdist(base[dd], base[dd], metric="chebyshev")
                np.fill_diagonal(dist, np.inf)
                assert dist.min() > 2 * radius + guard
    # one camera's schedule alone would crowd the other's windows
    alone = schedule_dots(bases[0], seens.any(axis=0), (h, w), radius, guard=guard)
    crowded = False
    for k in range(len(alone)):
        d = alone.dots(k)
        d = d[seens[1][d]]
        if len(d) > 1:
            dist = cdist(bases[1][d], bases[1][d], metric="chebyshev")
            np.fill_diagonal(dist, np.inf)
            crowded |= bool(dist.min() <= 2 * radius + guard)
    assert crowded
    # a single camera as a (1, n) stack is the same schedule as without the stack
    one = schedule_dots(bases[:1], seens[:1], (h, w), radius, guard=guard)
    assert np.array_equal(one.colour, schedule_dots(bases[0], seens[0], (h, w), radius, guard=guard).colour)


def test_dots_no_camera_window_lies_near_may_share_a_pattern_but_never_a_window():
    """Camera 1 sees the texture at a grazing angle (its texels squeezed together), has windows for a few texels
    and receives the light of all: dots within reach of each other there may share a pattern when neither has a
    window in camera 1 (nothing of their light is recorded there), never when one has; the schedule is leaner
    for it."""
    rng = np.random.default_rng(11)
    w, h, radius, guard = 24, 16, 2, 1
    squeezed = np.rint(_positions(w, h, rng)[::-1] * np.array([0.4, 1.0])).astype(np.int64)
    bases = np.stack([_positions(w, h, rng), squeezed])
    windows = np.stack([rng.random(w * h) < 0.8, rng.random(w * h) < 0.1])
    present = np.stack([windows[0], np.ones(w * h, bool)])
    sched = schedule_dots(bases, windows, (h, w), radius, guard=guard, present=present)
    lit = windows.any(axis=0)
    assert np.array_equal(sched.lit, lit)
    sharing = 0
    for k in range(len(sched)):
        d = sched.dots(k)
        for base, win, reach in zip(bases, windows, present):      # brute force, camera by camera
            dd = d[reach[d]]
            if len(dd) < 2:
                continue
            dist = cdist(base[dd], base[dd], metric="chebyshev")
            np.fill_diagonal(dist, np.inf)
            i, j = np.nonzero(dist <= 2 * radius + guard)
            assert not (win[dd[i]] | win[dd[j]]).any()            # no dot within reach of a window
            sharing += len(i)
    assert sharing > 0
    # every dot whose light reaches a camera kept clear of every other there, as if each had a window: more
    strict = schedule_dots(bases, present & lit, (h, w), radius, guard=guard)
    assert np.array_equal(strict.lit, lit) and len(sched) < len(strict)


def test_a_texels_light_reaches_a_camera_where_it_or_a_neighbour_is_seen():
    """Brute force: a texel on the mesh with a camera position reaches the camera when it or one of its 8
    neighbours in the texture is seen (the node's bilinear lookup spreads its light over their span)."""
    rng = np.random.default_rng(4)
    w, h = 14, 9
    on = rng.random(w * h) < 0.85
    visible = on & (rng.random(w * h) < 0.2)
    pos = np.where(on[:, None], rng.random((w * h, 2)) * 50, np.nan)
    pos[3] = np.nan                                              # on the mesh but behind the camera
    texels = TexelMap(pos, visible, np.where(visible, 0.5, 0).astype(np.float32), on)
    got = reaching_texels(texels, (w, h))
    vis = visible.reshape(h, w)
    for t in range(w * h):
        y, x = divmod(t, w)
        near = vis[max(0, y - 1):y + 2, max(0, x - 1):x + 2].any()
        assert got[t] == (near and on[t] and np.isfinite(pos[t]).all()), t
    assert (got & ~visible).any() and got[visible & np.isfinite(pos).all(axis=1)].all()
