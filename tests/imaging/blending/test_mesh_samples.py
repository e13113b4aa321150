"""Blob readings on a mesh take the surface's shading out pixel by pixel and read only inside the disc; the
flat white holds the modelled lights' sum."""
from __future__ import annotations

import numpy as np

from imaging.blending.mesh_samples import match_flat_white, read_capture_shaded
from imaging.blending.sample_plan import SamplePlan
from imaging.blending.samples import Samples, read_capture


def test_a_blob_reads_the_lamps_light_under_a_fast_changing_shading():
    H, W = 60, 80
    gy, gx = np.mgrid[0:H, 0:W].astype(np.float64)
    xy = np.stack([0.5 * gx + 3.0, 0.8 * gy + 2.0], axis=-1).astype(np.float32)     # a slanted surface: anisotropic
    xy[:, 70:] = np.nan                                                            # not lit there

    def lamp(u):
        return 0.5 + 0.3 * np.exp(-((u[..., 0] - 20) ** 2 + (u[..., 1] - 25) ** 2) / 400.0)

    shading = (0.6 + 0.35 * np.sin(gx / 1.3) * np.cos(gy / 2.1)).astype(np.float32)
    sites = np.array([[20.0, 20.0], [45.0, 30.0], [30.0, 45.0]])
    centres = np.stack([0.5 * sites[:, 0] + 3.0, 0.8 * sites[:, 1] + 2.0], axis=-1)
    prad = np.full(3, 3.0)                                   # 6 camera pixels across x, 3.75 along y: an ellipse
    disc = np.zeros((H, W), bool)
    for c in centres:
        disc |= np.hypot(xy[..., 0] - c[0], xy[..., 1] - c[1]) <= 3.0
    light = np.where(disc, lamp(np.nan_to_num(xy)) * shading, 0.0)
    black = np.full((H, W, 3), 0.01, np.float32)
    capture = (black + light[..., None] * np.array([1.0, 0.9, 0.8])).astype(np.float32)
    plan = SamplePlan(sites=sites, radius=5.0, owner=np.zeros((1, 3), np.int32), slots=["p"],
                      projector_xy={"p": centres}, projector_radius={"p": prad}, projector_size={"p": (60, 60)},
                      candidates=np.ones(3, np.int32))
    mine = Samples()
    assert read_capture_shaded(capture, black, plan, 0, mine, {"p": xy}, {"p": shading}) == 3
    _, values = mine.arrays("p")
    want = lamp(centres)[:, None] * np.array([1.0, 0.9, 0.8])
    assert np.allclose(values, want, rtol=0.03), (values, want)
    # the planar reading of the same blobs, divided by the shading at the site, is far off
    planar = Samples()
    read_capture(capture, black, plan, 0, planar)
    _, pv = planar.arrays("p")
    at = shading[sites[:, 1].astype(int), sites[:, 0].astype(int)]
    assert np.max(np.abs(pv / at[:, None] / want - 1.0)) > 0.1


def test_the_flat_white_scales_the_lights_together_to_its_sum():
    rng = np.random.default_rng(0)
    white = {s: rng.uniform(0.1, 1.0, (10, 12, 3)).astype(np.float32) for s in ("a", "b")}
    surface = np.zeros((10, 12), bool)
    surface[2:8, 3:9] = True
    flat = 1.1 * (white["a"] + white["b"])
    flat[4, 4] *= 9.0                                                           # beyond the limits: clamped
    out = match_flat_white(white, flat, surface)
    total = out["a"] + out["b"]
    inside = surface.copy()
    inside[4, 4] = False
    assert np.allclose(total[inside], flat[inside], rtol=1e-5)
    assert np.allclose(out["a"][4, 4] / white["a"][4, 4], 2.0)
    assert np.allclose(out["a"] / white["a"], out["b"] / white["b"])            # the same factor for every light
    assert np.array_equal(out["a"][~surface], white["a"][~surface])
