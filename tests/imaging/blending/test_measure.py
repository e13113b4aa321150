"""The blend's measurement on synthetic rigs with known light: the multiplexed blob plan (blobs of two
projectors never meet in the camera; the capture count barely grows with N), reading its captures and
fitting each projector's light, against a brute-force renderer of what the camera sees."""
from __future__ import annotations

import numpy as np
import pytest

from imaging.blending.contributions import Contributions, apply_homography_grid, grid_to_camera, luma
from imaging.blending.errors import BlendError
from imaging.blending.fit import fit_contributions, poly_basis
from imaging.blending.sample_plan import plan_samples
from imaging.blending.samples import Samples, blob_exposure, read_capture
from imaging.blending.synthetic import projector_light, rectangle_rig, tiled_rects, wall_rects

CAM = (320, 240)


def render(truth: Contributions, frames: dict[str, np.ndarray | None], *, noise: float = 0.0, seed: int = 0) -> np.ndarray:
    """What the camera sees, pixel by pixel at full resolution: each projector's frame value at the camera
    pixel's projector coordinates (nearest pixel) times its light there, plus its black."""
    W, H = CAM
    pts = grid_to_camera(CAM, (H, W))
    out = np.zeros((H, W, 3), np.float64)
    for s in truth.slots:
        M = truth.camera_to_projector[s]
        pw, ph = truth.projector_size[s]
        u = apply_homography_grid(M, pts)
        light = projector_light(u, (pw, ph), peak=PEAKS.get(s, 1.0), falloff=0.3, hotspot=0.1)
        ix, iy = np.rint(u[..., 0]).astype(int), np.rint(u[..., 1]).astype(int)
        inside = (ix >= 0) & (ix < pw) & (iy >= 0) & (iy < ph)
        f = frames.get(s)
        value = np.zeros((H, W))
        if f is not None:
            value[inside] = f[iy[inside], ix[inside]] / 255.0
        out += light * (value[..., None] + 0.003)     # black: 0.3 % of its white
    if noise:
        out += np.random.default_rng(seed).normal(0.0, noise, out.shape)
    return out.astype(np.float32)


PEAKS: dict[str, float] = {}


def rig(rects, peaks) -> Contributions:
    PEAKS.clear()
    PEAKS.update({f"p{k}": p for k, p in enumerate(peaks)})
    return rectangle_rig(rects, camera_size=CAM, scale=1, projector_size=(160, 100), peaks=peaks, falloff=0.3,
                         hotspot=0.1)


def test_blobs_of_two_projectors_never_meet_in_the_camera():
    truth = rig(tiled_rects(3, 3, CAM), [1.0] * 9)
    plan = plan_samples(CAM, truth.camera_to_projector, truth.projector_size, samples=30)
    for k in range(plan.captures):
        frames = plan.frames(k)
        owner = np.full(CAM[::-1], -1)
        for i, s in enumerate(plan.slots):
            lit = render_mask(truth, s, frames[s])
            assert not np.any(lit & (owner >= 0)), f"capture {k}: {s}'s blobs meet another projector's"
            owner[lit] = i
    counts = plan.counts()
    assert min(counts.values()) >= 30


def render_mask(truth: Contributions, slot: str, frame: np.ndarray) -> np.ndarray:
    """Camera pixels where ``slot``'s frame is lit (nearest projector pixel), dilated by one pixel."""
    W, H = CAM
    u = apply_homography_grid(truth.camera_to_projector[slot], grid_to_camera(CAM, (H, W)))
    pw, ph = truth.projector_size[slot]
    ix, iy = np.rint(u[..., 0]).astype(int), np.rint(u[..., 1]).astype(int)
    inside = (ix >= 0) & (ix < pw) & (iy >= 0) & (iy < ph)
    lit = np.zeros((H, W), bool)
    lit[inside] = frame[iy[inside], ix[inside]] > 0
    grown = lit.copy()
    grown[1:] |= lit[:-1]
    grown[:-1] |= lit[1:]
    grown[:, 1:] |= lit[:, :-1]
    grown[:, :-1] |= lit[:, 1:]
    return grown


def test_the_capture_count_barely_grows_with_the_number_of_projectors():
    one = rig(tiled_rects(1, 1, CAM), [1.0])
    many = rig(tiled_rects(5, 5, CAM), [1.0] * 25)
    p1 = plan_samples(CAM, one.camera_to_projector, one.projector_size)
    p25 = plan_samples(CAM, many.camera_to_projector, many.projector_size)
    assert p1.captures == 1
    # with the black capture and the two flat whites the job adds to both: at most twice as many
    assert 3 + p25.captures <= 2 * (3 + p1.captures)
    assert min(p25.counts().values()) >= 48


@pytest.mark.parametrize("layout,smoothing", [("wall", None), ("table", None), ("table", 1e-4)])
def test_fitted_light_matches_the_truth(layout, smoothing):
    if layout == "wall":
        truth = rig(wall_rects(3, 0.2, CAM), [1.0, 0.8, 1.15])
    else:
        truth = rig(tiled_rects(3, 3, CAM, seed=4), list(np.linspace(0.85, 1.15, 9)))
    plan = plan_samples(CAM, truth.camera_to_projector, truth.projector_size)
    black = render(truth, {}, noise=0.0005, seed=99)
    samples = Samples()
    for k in range(plan.captures):
        read = read_capture(render(truth, plan.frames(k), noise=0.0005, seed=k), black, plan, k, samples)
        assert read == int((plan.owner[k] >= 0).sum())
    fitted, figures = fit_contributions(plan, samples, black, truth.camera_to_projector, scale=2, smoothing=smoothing)
    assert fitted.shape == (120, 160)
    for s in truth.slots:
        # the truth on the fitted grid
        u = fitted.projector_coords(s)
        want = projector_light(u, truth.projector_size[s], peak=PEAKS[s], falloff=0.3, hotspot=0.1)
        m = luma(want) > 0
        assert np.array_equal(m, fitted.footprint(s))
        # within 1 % where blobs reach (a disc's radius inside the frame), within 5 % out to the frame's edge,
        # where the smooth model extrapolates
        inner = m & (u[..., 0] > 8) & (u[..., 0] < 151) & (u[..., 1] > 8) & (u[..., 1] < 91)
        err = np.abs(fitted.white[s] / np.where(m[..., None], want, 1) - 1)
        assert np.percentile(err[inner], 99) < 0.01, (s, np.percentile(err[inner], 99))
        assert np.percentile(err[m], 99) < 0.05, (s, np.percentile(err[m], 99))
        assert figures["slots"][s]["samples"] >= 40
    # the black shares: 0.3 % of each projector's light
    assert np.allclose(figures["black_fraction"], 0.003, rtol=0.1)


def test_blob_exposure_brings_one_projector_s_share_up_to_the_level():
    truth = rig(tiled_rects(5, 5, CAM), [1.0] * 25)
    plan = plan_samples(CAM, truth.camera_to_projector, truth.projector_size)
    white = render(truth, {s: np.full((100, 160), 255, np.uint8) for s in truth.slots}) / 25 * 0.8
    e = blob_exposure(white, plan, level=0.6, longest=64)
    blob = render(truth, plan.frames(0)) / 25 * 0.8 * e
    assert 0.2 < blob.max() < 0.75              # a margin for projectors brighter than their neighbours
    assert blob_exposure(white, plan, longest=4.0) == 4.0


def test_a_projector_the_camera_does_not_see_is_refused_by_name():
    truth = rig(wall_rects(2, 0.2, CAM), [1.0, 1.0])
    plan = plan_samples(CAM, truth.camera_to_projector, truth.projector_size)
    black = render(truth, {})
    samples = Samples()
    for k in range(plan.captures):
        frames = plan.frames(k)
        frames["p1"] = np.zeros_like(frames["p1"])          # p1's lamp is off
        read_capture(render(truth, frames), black, plan, k, samples)
    with pytest.raises(BlendError, match="projector p1: only 0 usable blob samples"):
        fit_contributions(plan, samples, black, truth.camera_to_projector, scale=2)


def test_plan_refusals():
    truth = rig(wall_rects(2, 0.2, CAM), [1.0, 1.0])
    with pytest.raises(BlendError, match="never touch"):
        plan_samples(CAM, truth.camera_to_projector, truth.projector_size, radius=6, spacing=10)
    far = {s: np.array([[1, 0, 5000.0], [0, 1, 5000.0], [0, 0, 1]]) for s in truth.slots}
    with pytest.raises(BlendError, match="no blob site"):
        plan_samples(CAM, far, truth.projector_size)


def test_poly_basis_is_every_monomial_up_to_the_degree():
    a, b = np.array([2.0]), np.array([3.0])
    assert poly_basis(a, b, 2).tolist() == [[1.0, 2.0, 3.0, 4.0, 6.0, 9.0]]
