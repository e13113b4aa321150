"""Contributions: exact round trip through the arrays the blend store keeps, one-line refusals of
incomplete or inconsistent stores, and the variants failover uses; the uniformity and seam metrics on
images whose answer is known."""
from __future__ import annotations

import numpy as np
import pytest

from imaging.blending.contributions import Contributions
from imaging.blending.errors import BlendError
from imaging.blending.metrics import seam_step, uniformity
from imaging.blending.synthetic import rectangle_rig, wall_rects

CAM = (160, 120)


def rig() -> Contributions:
    return rectangle_rig(wall_rects(2, 0.3, CAM), camera_size=CAM, scale=2, projector_size=(80, 50),
                         peaks=[1.0, 0.7], whites=[(1, 1, 1), (1.1, 1.0, 0.9)], names=["left", "r.1"])


def test_arrays_round_trip_exactly():
    c = rig()
    arrays, meta = c.to_arrays()
    assert sorted(arrays) == sorted(["white.left", "black.left", "camera_to_projector.left",
                                     "white.r.1", "black.r.1", "camera_to_projector.r.1"])
    import json
    back = Contributions.from_arrays({k: v.copy() for k, v in arrays.items()}, json.loads(json.dumps(meta)))
    assert back.slots == c.slots and back.camera_size == c.camera_size and back.scale == c.scale
    for s in c.slots:
        assert np.array_equal(back.white[s], c.white[s]) and np.array_equal(back.black[s], c.black[s])
        assert np.array_equal(back.camera_to_projector[s], c.camera_to_projector[s])
        assert back.projector_size[s] == c.projector_size[s]


def test_a_damaged_store_is_refused_in_one_line():
    arrays, meta = rig().to_arrays()
    missing = dict(arrays)
    del missing["black.r.1"]
    with pytest.raises(BlendError, match="incomplete") as info:
        Contributions.from_arrays(missing, meta)
    assert "\n" not in str(info.value)
    bad = dict(arrays)
    bad["white.left"] = np.full((3, 3, 3), np.nan, np.float32)
    with pytest.raises(BlendError, match=r"inconsistent: white\[left\] must be"):
        Contributions.from_arrays(bad, meta)
    nan = dict(arrays)
    nan["white.left"] = arrays["white.left"].copy()
    nan["white.left"][0, 0, 0] = np.nan
    with pytest.raises(BlendError, match="finite"):
        Contributions.from_arrays(nan, meta)
    with pytest.raises(BlendError, match="incomplete"):
        Contributions.from_arrays(arrays, {k: v for k, v in meta.items() if k != "scale"})


def test_variants_drop_slots_and_scale_a_lamp():
    c = rig()
    assert c.without(["left"]).slots == ["r.1"]
    dim = c.with_gains({"r.1": 0.5})
    assert np.allclose(dim.white["r.1"], 0.5 * c.white["r.1"]) and np.allclose(dim.black["r.1"], 0.5 * c.black["r.1"])
    assert np.array_equal(dim.white["left"], c.white["left"])
    with pytest.raises(BlendError, match="no such projector"):
        c.with_gains({"x": 1.0})
    with pytest.raises(ValueError, match="same slots"):
        Contributions(CAM, 2, {"a": c.white["left"]}, {}, {}, {})


def test_uniformity_is_the_p99_of_the_deviation_from_a_scaled_target():
    rng = np.random.default_rng(0)
    target = np.ones((60, 80, 3), np.float32)
    covered = np.zeros((60, 80), bool)
    covered[5:55, 5:75] = True
    assert uniformity(2.5 * target, target, covered) == pytest.approx(0.0, abs=1e-6)   # a constant factor is even
    image = target.copy()
    image[40:, :] *= 1.1                   # 30 % of the area 10 % brighter than the median
    u = uniformity(image, target, covered, block=1)
    assert u == pytest.approx(0.1, rel=1e-4)
    noisy = target * (1 + rng.normal(0, 0.01, target.shape)).astype(np.float32)
    assert uniformity(noisy, target, covered, block=8) < uniformity(noisy, target, covered, block=1)
    # a full-resolution capture is averaged to the target's grid
    assert uniformity(np.repeat(np.repeat(image, 2, 0), 2, 1), target, covered, block=1) == pytest.approx(u)


def test_seam_step_finds_a_step_at_a_footprint_edge_and_not_a_smooth_ramp():
    c = rig()
    h, w = c.shape
    covered = np.ones((h, w), bool)
    left_edge = np.argmax(c.footprint("r.1")[h // 2])       # where r.1's frame starts
    image = np.ones((h, w, 3), np.float32)
    image[:, left_edge:] *= 1.05
    assert seam_step(image, c, covered) == pytest.approx(0.05, abs=0.005)
    ramp = np.linspace(1.0, 1.15, w, dtype=np.float32)[None, :, None] * np.ones((h, w, 3), np.float32)
    assert seam_step(ramp, c, covered) < 0.02
    assert seam_step(ramp, c, covered, target=ramp) == pytest.approx(0.0, abs=1e-6)
