"""Stage 3, sequential: the paper's method, the reference. Per projector, white and black
references and the Gray-code patterns; decoded camera pixels give table <-> projector
correspondences and a robust homography the projector's pose.

:func:`gray_captures`, :func:`decode_all` and :func:`seen_check` serve the 3D stage
(:mod:`.mesh`) too.
"""
from __future__ import annotations

import math

import numpy as np

from imaging.calibration import graycode, planar
from coordinator.calibration.runs import slot_doc
from coordinator.calibration.stages.loops import one_by_one
from coordinator.calibration.stages.state import SATURATED, Abort, CameraSetup, State, full
from coordinator.jobs import JobError
from coordinator.memory_budget import MemoryBudgetError, ensure_fits
from coordinator.rig import HomographyPose
from protos.spaces import content_to_table

MIN_LIT_PIXELS = 50         # fewer lit camera pixels than this: the projector is not seen


async def gray_captures(st: State, slot: str) -> tuple[list[np.ndarray], list[np.ndarray], list[list[np.ndarray]]]:
    """White and black references (per camera) and the captures of every Gray-code pattern of ``slot``."""
    size = st.sizes[slot]
    layout = graycode.gray_layout(size)
    total = layout.count + 2
    st.ctx.progress("gray codes", slot, 0, total, "white reference")
    white = await st.shoot({slot: full(size, 255)}, require=[slot])
    st.ctx.progress("gray codes", slot, 1, total, "black reference")
    black = await st.shoot({slot: full(size, 0)}, require=[slot])
    for i, (w, b) in enumerate(zip(white, black)):
        contrast = graycode.luminance(w) - graycode.luminance(b)
        sat = _saturated_fraction(w, contrast, st.opts.min_contrast)
        if sat > st.opts.max_saturated:
            raise Abort(f"camera {i} over-exposed ({100 * sat:.0f} % of the pixels {slot} lights are saturated): "
                        "lower the exposure")
    # every pattern's capture is kept for the decode (float32 per camera), which adds about 100 bytes a pixel
    need = layout.count * sum(w.nbytes for w in white) + 100 * sum(w.shape[0] * w.shape[1] for w in white)
    try:
        ensure_fits(need, what=f"the {layout.count} Gray-code captures of {slot} from {len(white)} camera(s) of "
                    f"{white[0].shape[1]}x{white[0].shape[0]}", hint="use a lower camera resolution or the multiplexed mode")
    except MemoryBudgetError as exc:
        raise Abort(str(exc)) from None
    caps: list[list[np.ndarray]] = []
    for k, p in enumerate(graycode.gray_patterns(size)):
        caps.append(await st.shoot({slot: p}, require=[slot]))
        st.ctx.progress("gray codes", slot, k + 2, total, "gray codes")
    return white, black, caps


def _saturated_fraction(white: np.ndarray, contrast: np.ndarray, min_contrast: float) -> float:
    sat = white.max(axis=2) >= SATURATED
    region = (contrast > min_contrast) | sat
    n = int(region.sum())
    return float(sat[region].sum()) / n if n else 0.0


def decode_all(white, black, caps, size: tuple[int, int], min_contrast: float) -> list[graycode.GrayDecode]:
    """One decode per camera."""
    layout = graycode.gray_layout(size)
    return [graycode.decode_gray([c[i] for c in caps], white=white[i], black=black[i], layout=layout,
                                 min_contrast=min_contrast) for i in range(len(white))]


def seen_check(slot: str, decodes: list[graycode.GrayDecode], count: int, min_pixels: int, min_contrast: float) -> None:
    """Refuse a projector the cameras do not see, or see too little of, saying which."""
    lit = sum(int(d.lit.sum()) for d in decodes)
    if lit < MIN_LIT_PIXELS or count == 0:
        peak = max(float(np.percentile(d.contrast, 99.9)) for d in decodes)
        raise JobError(f"projector {slot} not seen by the camera (its white reference raises no camera pixel by more "
                       f"than {100 * max(peak, 0):.1f} % of full scale): check that it is on, shows the patterns and is "
                       "aimed at the surface the camera sees")
    if count < min_pixels:
        contrast = np.concatenate([d.contrast[d.lit] for d in decodes])
        if float(np.percentile(contrast, 95)) < 2.5 * min_contrast:
            raise JobError(f"too few decoded pixels for {slot} ({count} < {min_pixels}): its light reaches the camera "
                           f"at only {100 * float(np.percentile(contrast, 95)):.1f} % of full scale; the camera is "
                           "under-exposed for one projector: raise the exposure")
        raise JobError(f"too few decoded pixels for {slot} ({count} < {min_pixels}): is most of its image off the "
                       "surface or blocked?")


def fit_planar(decodes, setup: CameraSetup, slot: str, min_pixels: int, min_contrast: float):
    """Table mm -> projector px homography from every camera's decoded pixels; the residuals at
    the per-projector-pixel centroids and the number of decoded pixels."""
    txy, proj, agg_t, agg_p = [], [], [], []
    for i, d in enumerate(decodes):
        if i not in setup.table_to_camera:
            continue
        cam, pj = d.correspondences()
        inv = np.linalg.inv(setup.table_to_camera[i])
        txy.append(planar.apply_homography(inv, cam))
        proj.append(pj)
        cm, pm = planar.pixel_centroids(cam, pj)
        agg_t.append(planar.apply_homography(inv, cm))
        agg_p.append(pm)
    txy, proj = np.vstack(txy), np.vstack(proj)
    seen_check(slot, decodes, len(txy), min_pixels, min_contrast)
    fit = planar.fit_homography(txy, proj, threshold=1.5)
    at, ap = np.vstack(agg_t), np.vstack(agg_p)
    r = np.linalg.norm(planar.apply_homography(fit.H, at) - ap, axis=1)
    r = r[r <= 1.5]
    return fit, r, len(txy)


async def sequential(st: State) -> None:
    """Calibrate ``st.todo`` one after another on the table."""
    ctx, opts = st.ctx, st.opts
    H_c2t = content_to_table(st.content_size, opts.table_mm)

    async def measure(slot: str):
        white, black, caps = await gray_captures(st, slot)
        decodes = await ctx.compute(decode_all, white, black, caps, st.sizes[slot], opts.min_contrast)
        return await ctx.compute(fit_planar, decodes, st.setup, slot, opts.min_pixels, opts.min_contrast)

    def pose_of(slot: str, measured, before: int) -> tuple[HomographyPose, dict]:
        fit, r, count = measured
        pose = planar.normalise(fit.H @ H_c2t)
        doc = slot_doc(st.run, slot, opts, rms=float(np.sqrt(np.mean(r ** 2))) if len(r) else math.nan,
                       mx=float(r.max()) if len(r) else math.nan, points=len(r), raw_rms=fit.rms,
                       decoded=count, inliers=fit.count, captures=st.shots - before)
        return HomographyPose(pose), doc

    await one_by_one(st, measure, pose_of)
