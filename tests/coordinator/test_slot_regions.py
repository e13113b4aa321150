"""Per-slot regions of a show: the masks against a pixel-by-pixel reference, the refusals, sharing
one masked copy between slots, and the regions' round trip through the Show message."""
from __future__ import annotations

import numpy as np
import pytest

from coordinator.api import Space
from coordinator.rig import Content
from coordinator.wire.image_parts import regions_from_request, show_request_parts
from coordinator.slot_regions import check_regions, mask_image, masked_contents
from protos import control_pb2


def test_mask_keeps_exactly_the_union_of_the_rectangles():
    rng = np.random.default_rng(3)
    img = rng.integers(1, 65535, (23, 31, 3), dtype=np.uint16)
    rects = [(0, 0, 10, 23), (7, 5, 12, 4), (30, 22, 1, 1)]
    got = mask_image(img, rects)
    assert got.dtype == img.dtype and got.shape == img.shape
    for y in range(img.shape[0]):          # brute force: is the pixel inside any rectangle?
        for x in range(img.shape[1]):
            inside = any(rx <= x < rx + rw and ry <= y < ry + rh for rx, ry, rw, rh in rects)
            np.testing.assert_array_equal(got[y, x], img[y, x] if inside else 0)


def test_bad_regions_are_refused_by_name():
    slots = ["r0c0", "r0c1"]
    with pytest.raises(ValueError, match=r"'r9c9', which is not a slot of this rig \(slots: r0c0, r0c1\)"):
        check_regions({"r9c9": []}, (40, 20), slots)
    with pytest.raises(ValueError, match="r0c0: region x=30 y=0 20x20 is empty or leaves the 40x20 content"):
        check_regions({"r0c0": [(30, 0, 20, 20)]}, (40, 20), slots)
    with pytest.raises(ValueError, match="empty"):
        check_regions({"r0c0": [(0, 0, 0, 5)]}, (40, 20), slots)
    with pytest.raises(ValueError, match="4 integers"):
        check_regions({"r0c0": [(0, 0, 5)]}, (40, 20), slots)
    assert check_regions({"r0c0": [(0, 0, 40, 20)], "r0c1": []}, (40, 20), slots) == {"r0c0": ((0, 0, 40, 20),),
                                                                                        "r0c1": ()}


def test_slots_with_the_same_rectangles_share_one_masked_copy():
    c = Content(np.full((4, 8, 1), 200, np.uint8), name="card")
    left, right = (0, 0, 4, 4), (4, 0, 4, 4)
    out = masked_contents(c, {"a": (left,), "b": (left,), "c": (right, left), "d": (left, right), "e": ()})
    assert out["a"] is out["b"] and out["c"] is out["d"] and out["e"] is None
    assert out["a"].image[:, :4].min() == 200 and out["a"].image[:, 4:].max() == 0
    np.testing.assert_array_equal(out["c"].image, c.image)
    assert out["a"].content_id != c.content_id and out["a"].name == "card (regions)"


def test_regions_survive_the_show_message_including_a_slot_without_any():
    regions = {"r0c0": [(0, 0, 60, 60)], "r0c1": [(0, 0, 60, 60), (60, 0, 60, 60)], "r0c2": []}
    first, *_ = show_request_parts(np.zeros((4, 4, 3), np.uint8), name="x", persist=False, space=Space.CONTENT,
                                   apply_lut=True, slot_regions=regions)
    back = control_pb2.ShowRequest.FromString(first.SerializeToString())
    assert regions_from_request(back) == regions
    assert regions_from_request(control_pb2.ShowRequest()) == {}
