"""A mesh rig's compensation picture shows each camera's view of the object cut to the object, not the
black between one camera's view and the next (helper F's request 5: three stacked views made a
1084 x 2906 px picture, mostly black). Only the layout changes: every scored pixel is shown once with
its value, so the picture's mean errors and colour scale, like the job's scores, do not depend on it.
Built from made-up stacked views whose objects are known; the bust's job draws it from its captures
(tests/coordinator/compensation/test_mesh_jobs.py)."""
from __future__ import annotations

import numpy as np
import pytest

from imaging.compensation.quality_figure import BLOCK_MARGIN, compensation_figure, packed_views


def stacked_views(objects: list[tuple[int, int, int, int]], h: int = 240, w: int = 320, seed: int = 4):
    """Views ``h`` x ``w`` stacked one under the other, view k scoring the ellipse ``objects[k]``
    (cy, cx, ry, rx); the target and a noisy capture of it, (len * h, w, 3) float32, and the region."""
    yy, xx = np.mgrid[:h, :w]
    region = np.vstack([((yy - cy) / ry) ** 2 + ((xx - cx) / rx) ** 2 <= 1 for cy, cx, ry, rx in objects])
    rng = np.random.default_rng(seed)
    target = np.where(region[:, :, None], rng.uniform(0.2, 0.8, region.shape + (3,)), 0).astype(np.float32)
    seen = np.clip(target + rng.normal(0, 0.02, target.shape), 0, 1).astype(np.float32)
    return target, seen, region


def longest_unscored_run(scored: np.ndarray) -> int:
    """The longest run of ``scored`` ((n,) bool) False in a row."""
    best = run = 0
    for s in scored:
        run = 0 if s else run + 1
        best = max(best, run)
    return best


def oblong(picture: np.ndarray) -> float:
    """How far from square a picture is: its longer side over its shorter."""
    return max(picture.shape[:2]) / min(picture.shape[:2])


# small objects far apart in tall views (the bust seen from three sides), and wide ones (a flat object)
@pytest.mark.parametrize("objects, h, w", [
    ([(60, 100, 40, 30), (150, 200, 70, 40), (120, 160, 80, 45)], 240, 320),
    ([(40, 150, 15, 120), (50, 160, 20, 130)], 100, 320),
])
def test_each_view_is_cut_to_its_object_and_no_pixel_moves_a_score(objects, h, w):
    target, seen, region = stacked_views(objects, h, w)
    tiles = packed_views([target, seen], region, len(objects), across=3)
    t, s = tiles
    assert t.shape == s.shape and t.dtype == np.float32 and t.shape[2] == 3
    scored = np.any(t != 0, axis=2)
    assert scored.sum() == region.sum()              # every scored pixel once (none is exactly 0 here)
    # no black band between (or round) the views wider than the margins of two neighbours
    assert longest_unscored_run(scored.any(axis=1)) <= 2 * BLOCK_MARGIN
    assert longest_unscored_run(scored.any(axis=0)) <= 2 * BLOCK_MARGIN or t.shape[0] > t.shape[1]
    assert t.size < target.size / 2                  # at least half the picture was black between views
    # the same values: the sorted scored pixels of each image are those of the stacked views
    for before, after in [(target, t), (seen, s)]:
        assert np.array_equal(np.sort(before[region], axis=0), np.sort(after[scored], axis=0))


def test_the_picture_s_figures_do_not_depend_on_the_layout():
    target, seen, region = stacked_views([(60, 100, 40, 30), (150, 200, 70, 40), (120, 160, 80, 45)])
    scores = {"none": {"psnr": 30.0, "ssim": 0.9}}
    old, stacked = compensation_figure(target, {"none": seen}, scores, mask=region)
    t, s = packed_views([target, seen], region, 3, across=2)
    picture, packed = compensation_figure(t, {"none": s}, scores, mask=np.any(t != 0, axis=2) | np.any(s != 0, axis=2))
    assert packed["mean_error"] == stacked["mean_error"]
    assert packed["full_scale"] == stacked["full_scale"]
    # squarer than the stacked views' picture
    assert oblong(picture) < oblong(old), (picture.shape, old.shape)


def test_one_camera_s_view_is_cut_to_its_object_with_the_margin():
    target, seen, region = stacked_views([(120, 160, 50, 60)])
    t, = packed_views([target], region, 1, across=3)
    assert t.shape[:2] == (101 + 2 * BLOCK_MARGIN, 121 + 2 * BLOCK_MARGIN)


def test_views_that_do_not_divide_the_rows_are_refused():
    target, _, region = stacked_views([(60, 100, 40, 30), (150, 200, 70, 40)])
    with pytest.raises(ValueError, match="stacked views"):
        packed_views([target], region, 7, across=2)     # 480 rows
