"""The compensate job's picture shows the gain where it is visible (issue 38 point 7): a crop where the
blur costs most, enlarged, and |captured - target| of every result on one colour scale, all from the
float images the scores come from. Built from made-up captures whose answers are known; the room's
jobs draw it from their captures (tests/coordinator/compensation/test_job_room.py, test_mesh_jobs.py)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from imaging.calibration.heatmap_figure import NO_DATA_BGR
from imaging.compensation.quality import quality
from imaging.compensation.quality_figure import CROP_BGR, compensation_figure, detail_window, enlargement, error_scale


def blurred_results(h: int, w: int, channels: int = 3, seed: int = 2):
    """A target and its captures: ``none`` blurred, ``ours`` half way back (float32, (h, w, channels))."""
    rng = np.random.default_rng(seed)
    target = cv2.GaussianBlur(rng.uniform(0, 1, (h, w, 3)).astype(np.float32), (0, 0), 3)
    if channels == 1:
        target = target.mean(axis=2, keepdims=True)
    none = cv2.GaussianBlur(target, (0, 0), 2).reshape(target.shape)
    return target, none, 0.5 * (target + none)


def scores_of(target, captures):
    return {k: quality(target, c).as_dict() for k, c in captures.items()}


def test_the_crop_goes_where_the_blur_costs_most():
    rng = np.random.default_rng(1)
    target = rng.uniform(0.2, 0.8, (278, 555, 3)).astype(np.float32)
    seen = target + rng.normal(0, 0.005, target.shape).astype(np.float32)
    seen[200:240, 400:450] += 0.2                   # the detail the blur ruins
    x0, y0, x1, y1 = detail_window(target, seen, (60, 50))
    assert (x1 - x0, y1 - y0) == (60, 50)
    assert x0 <= 400 and x1 >= 450 and y0 <= 200 and y1 >= 240, (x0, y0, x1, y1)
    edge = target.copy()
    edge[:, -5:] += 0.5                             # at the border: the window stays inside the image
    x0, y0, x1, y1 = detail_window(target, edge, (60, 50))
    assert x1 == 555 and 0 <= y0 and y1 <= 278


def test_the_error_scale_is_a_round_number_above_most_errors():
    assert error_scale(np.full((10, 10), 0.07)) == pytest.approx(0.1)
    assert error_scale(np.full((10, 10), 0.011)) == pytest.approx(0.02)
    assert error_scale(np.zeros((4, 4))) == 0.01
    assert error_scale(np.full((4, 4), np.nan)) == 0.01      # nothing scored


def test_the_picture_shows_crop_and_difference_from_the_float_images():
    h, w = 278, 555
    target, none, ours = blurred_results(h, w)
    captures = {"none": none, "ours": ours}
    scores = scores_of(target, captures)
    picture, shown = compensation_figure(target, captures, scores, title=["a title"], origin=(46, 107))
    assert picture.dtype == np.uint8 and picture.ndim == 3 and picture.shape[2] == 3
    x0, y0, x1, y1 = shown["window"]
    assert shown["window_camera_px"] == [46 + x0, 107 + y0, 46 + x1, 107 + y1]
    assert (x1 - x0, y1 - y0) == (w // 4, h // 3) and 0 <= x0 and x1 <= w and 0 <= y0 and y1 <= h
    assert (x0, y0, x1, y1) == detail_window(target, none, (w // 4, h // 3))
    # the mean errors are the float images' (not an 8-bit copy's), and order as the scores do
    for k, c in captures.items():
        assert shown["mean_error"][k] == pytest.approx(float(np.abs(np.clip(c, 0, 1) - target).mean()), abs=1e-5)
    assert shown["mean_error"]["ours"] < shown["mean_error"]["none"] and scores["ours"]["psnr"] > scores["none"]["psnr"]
    assert shown["full_scale"] == error_scale(np.abs(none - target).mean(axis=2))
    assert shown["enlarged"] == 1 and shown["zoom"] == 4
    # three full tiles side by side, three crops enlarged 4 times, two differences and a bar
    assert picture.shape[1] >= 3 * w and picture.shape[0] >= 2 * h + 4 * (h // 3)
    # the crop is outlined on the three full tiles and the two differences (about 3 px wide), and only
    # there: the enlarged crops are cut from unmarked pictures
    outlined = int(np.all(picture == CROP_BGR, axis=2).sum())
    assert 5 * 2 * ((x1 - x0) + (y1 - y0)) < outlined < 5 * 8 * ((x1 - x0) + (y1 - y0)), outlined


def test_the_baseline_gets_its_own_tiles_and_small_tiles_are_enlarged():
    h, w = 60, 100
    target, none, ours = blurred_results(h, w, channels=1)     # a grey image: (h, w, 1) tiles
    base = np.clip(none + 0.02, 0, 1)
    captures = {"none": none, "baseline": base, "ours": ours}
    with_base, shown = compensation_figure(target, captures, scores_of(target, captures))
    assert shown["enlarged"] == enlargement(h) == 4 and shown["zoom"] == 16
    assert set(shown["mean_error"]) == {"none", "baseline", "ours"} and "window_camera_px" not in shown
    without, _ = compensation_figure(target, {"none": none, "ours": ours}, {})     # no scores: captions without
    assert with_base.shape[1] >= without.shape[1] + 4 * w                           # one more enlarged tile a row
    with pytest.raises(ValueError, match="none"):
        compensation_figure(target, {"ours": ours}, {})
    with pytest.raises(ValueError, match="capture"):
        compensation_figure(target, {"none": none[:-1], "ours": ours}, {})


def test_pixels_outside_the_scored_surface_are_grey_and_left_out():
    """A mesh's tiles: the visible surface inside, 0 elsewhere in every tile."""
    h, w = 240, 320
    target, none, ours = blurred_results(h, w)
    yy, xx = np.mgrid[:h, :w]
    inside = (yy - 120) ** 2 + ((xx - 120) / 1.2) ** 2 < 100 ** 2
    none = none.copy()
    none[~inside] = 0.9               # what a capture might show there: ignored
    captures = {"none": none, "ours": ours}
    picture, shown = compensation_figure(target, captures, {}, mask=inside)
    x0, y0, x1, y1 = shown["window"]
    assert inside[y0:y1, x0:x1].mean() > 0.5, shown["window"]   # not where the unscored pixels differ
    n = inside.sum()                  # a twelfth of the scored pixels, 3:2
    assert (x1 - x0, y1 - y0) == (int(np.sqrt(n * 1.5 / 12)), int(np.sqrt(n / 1.5 / 12)))
    want = np.abs(none - target).mean(axis=2)[inside].mean()
    assert shown["mean_error"]["none"] == pytest.approx(want, abs=1e-5)
    assert shown["full_scale"] <= 0.2
    assert np.all(picture == NO_DATA_BGR, axis=2).sum() >= 2 * (~inside).sum() * 0.9     # both differences
    with pytest.raises(ValueError, match="mask"):
        compensation_figure(target, captures, {}, mask=inside[:-1])


def test_a_tall_picture_of_stacked_cameras_gets_a_detail_not_a_strip():
    """Several cameras' views one under the other (a mesh rig's evaluation): the crop stays 3:2."""
    target, none, ours = blurred_results(3 * 200, 180)
    picture, shown = compensation_figure(target, {"none": none, "ours": ours}, {})
    x0, y0, x1, y1 = shown["window"]
    assert (x1 - x0) > (y1 - y0) and (y1 - y0) < 200 and shown["zoom"] == 4

