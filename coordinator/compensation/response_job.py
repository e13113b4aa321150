"""The ``response`` job: each projector's luminance response, its inverse LUT, the rig's
brightness match and a linearity check.

Everything after this stage works in linear luminance (docs/architecture.md, "The physics"): each node
applies ``gain`` then its inverse-response LUT, so the camera sees ``c = L p + b`` for the one
content image ``p`` every projector shows (``b``: the rig's black level).

Per projector, the others black, grey levels are shown by that projector alone (projector
space, LUT off). The default ``patches`` mode shows a white frame, then frames of grey patches
(``rows x cols`` levels at once, each level at ``repeats`` positions); a patch's normalised
response is ``mean(capture - black) / mean(white - black)`` over the camera pixels it covers
(the pose and the table -> camera mapping place it, :mod:`~imaging.compensation.patches`),
which cancels the projector's fall-off across the table. ``full`` mode shows one uniform grey
level per capture. A monotone curve is fitted per channel
(:func:`~imaging.compensation.response.fit_response`), its inverse LUT stored and pushed,
then one uniform gain is chosen so the rig matches a reference brightness, and the rig's light
after the LUTs is checked to be a straight line of the requested level.

Responses are stored per projector (``compensation/responses/<slot>.json``), so an
interrupted run resumes where it stopped; ``force`` measures again.
"""
from __future__ import annotations

import time
import zlib
from dataclasses import dataclass

import numpy as np

from imaging.compensation.errors import CompensationError
from imaging.compensation.geometry import inscribed_region
from coordinator.compensation.jobkit import content_size, rig_geometry, rounded
from coordinator.compensation.options import ResponseOptions
from imaging.compensation.patches import camera_patch_labels, patch_labels, patch_layouts, patch_response
from imaging.compensation.response import (
    FittedResponse,
    brightness_scale,
    capture_means,
    fit_response,
    grey_levels,
    inverse_lut,
    response_mask,
    verify_linearity,
)
from coordinator.compensation.store import (
    load_stored_response,
    response_fingerprint,
    response_path,
    save_response,
    write_result,
)
from coordinator.jobs import JobContext, JobError
from coordinator.jobs.results import Figures, JobResult
from protos.wording import count

__all__ = ["OPTIONS", "run", "ResponseResult", "SlotResponse"]

OPTIONS = ResponseOptions


@dataclass(frozen=True, kw_only=True)
class SlotResponse(JobResult):
    """One projector's fitted response: per channel its gamma, black and peak (camera units), the patches
    it was fitted from (patches mode), its captures, and whether an earlier run measured it."""

    gamma: list[float]
    black: list[float | None]
    peak: list[float | None]
    patches: int | None
    captures: int | None
    resumed: bool


@dataclass(frozen=True, kw_only=True)
class ResponseResult(JobResult):
    """The ``response`` job's result (also ``compensation/response.json``): per projector its fitted
    response, those that failed and why, the brightness match and the linearity check."""

    mode: str
    captures: int
    wall_s: float
    slots: dict[str, SlotResponse]
    failed: dict[str, str]
    brightness: Figures
    linearity: Figures


def _fingerprint(ctx: JobContext, slot: str, opts: ResponseOptions, H: np.ndarray | None) -> str:
    return response_fingerprint(ctx.rig, slot, mode=opts.mode, levels=opts.levels, grid=opts.grid,
                                repeats=opts.repeats, seed=opts.seed, camera_spec=ctx.camera_spec(opts.camera),
                                camera=opts.camera, frames=opts.frames, homography=H)


async def run(ctx: JobContext, opts: ResponseOptions) -> ResponseResult:
    """Measure the responses still missing, push their LUTs, match brightness, check linearity."""
    t0 = time.monotonic()
    rig = ctx.rig
    ctx.camera_spec(opts.camera)
    slots = ctx.select_slots(opts.slots, need_pose=opts.mode == "patches", planar=opts.mode == "patches")
    H = rig_geometry(ctx, opts.camera)[0] if opts.mode == "patches" else None
    levels = grey_levels(opts.levels)
    responses: dict[str, FittedResponse] = {}
    docs: dict[str, dict] = {}
    failed: dict[str, str] = {}
    todo = []
    for s in slots:
        stored = None if opts.force else load_stored_response(response_path(rig, s), _fingerprint(ctx, s, opts, H))
        if stored is not None and rig.slot(s).lut is not None:
            responses[s], docs[s] = stored[0], {**stored[1], "resumed": True}
        else:
            todo.append(s)
    ctx.log(f"luminance response: {len(todo)} of {count(len(slots), 'projector')} to measure ({opts.mode} mode)"
            + (f"; {len(slots) - len(todo)} kept from an earlier run" if len(todo) < len(slots) else ""))
    black = None
    if todo:
        ctx.progress("response", "", 0, len(todo), "every projector black")
        await ctx.show({s: None for s in slots}, settle_s=opts.settle_s, require=[])
        black = await ctx.capture(opts.camera, frames=opts.frames)
    for n, s in enumerate(todo):
        before = ctx.captures
        try:
            resp, extra = await _measure_one(ctx, s, opts, levels, black, H)
        except (CompensationError, JobError) as exc:
            if not opts.keep_going:
                raise JobError(f"{s}: {exc}") from exc
            failed[s] = str(exc)
            ctx.log(f"{s}: {exc}")
            continue
        lut = await ctx.compute(inverse_lut, resp, opts.lut_entries)
        ctx.set_slot(s, lut=lut, source="response")
        doc = {"slot": s, "fingerprint": _fingerprint(ctx, s, opts, H), "mode": opts.mode,
               "captures": ctx.captures - before, "measured_at": time.time(), "lut_entries": opts.lut_entries, **extra}
        responses[s], docs[s] = resp, save_response(rig, s, resp, doc)
        gamma = float(np.mean(resp.gamma))
        ctx.progress("response", s, n + 1, len(todo), f"fitted, gamma {gamma:.2f}", value=gamma)
    if not responses:
        raise JobError("no projector's response could be measured: " + "; ".join(failed.values()))
    match = await _brightness(ctx, responses, opts)
    linearity = await _verify(ctx, opts, H)
    summary = ResponseResult(
        mode=opts.mode, captures=ctx.captures, wall_s=round(time.monotonic() - t0, 3),
        slots={s: SlotResponse(gamma=[round(float(g), 4) for g in responses[s].gamma],
                               black=[rounded(float(b), 6) for b in responses[s].black],
                               peak=[rounded(float(p), 6) for p in responses[s].peak],
                               patches=docs[s].get("patches"), captures=docs[s].get("captures"),
                               resumed=bool(docs[s].get("resumed"))) for s in slots if s in responses},
        failed=failed, brightness=match, linearity=linearity,
    )
    write_result(rig, "response.json", summary.to_wire())
    if failed:
        raise JobError(f"measured {len(responses)} of {count(len(slots), 'projector')} (saved; run again to retry the others); "
                       + "; ".join(failed.values()))
    return summary


async def _show_alone(ctx: JobContext, slot: str, frame: np.ndarray, opts: ResponseOptions) -> np.ndarray:
    """``frame`` on ``slot`` (projector space, LUT off), every other projector black; the averaged capture."""
    await ctx.show({slot: frame}, settle_s=opts.settle_s, require=[slot])
    return await ctx.capture(opts.camera, frames=opts.frames)


async def _measure_one(ctx: JobContext, slot: str, opts: ResponseOptions, levels: np.ndarray, black: np.ndarray,
                       H: np.ndarray | None) -> tuple[FittedResponse, dict]:
    size = ctx.projector_size(slot)
    w, h = size

    def full(v: float) -> np.ndarray:
        return np.full((h, w), int(round(255 * v)), np.uint8)

    if opts.mode == "full":
        caps = []
        for k, v in enumerate(levels):
            ctx.progress("grey levels", slot, k, len(levels))
            caps.append(black if v == 0 else await _show_alone(ctx, slot, full(v), opts))
        white = caps[-1]
        mask = await ctx.compute(response_mask, white, black)
        measured = await ctx.compute(capture_means, caps, mask=mask)
        return fit_response(levels, measured, channels=3), {"mask_pixels": int(mask.sum())}
    white = await _show_alone(ctx, slot, full(1.0), opts)
    interior = levels[(levels > 0) & (levels < 1)]
    # the frame is all patches; the bands along patch edges (where blur mixes two levels) are not measured
    shown = patch_labels(size, opts.grid, border=0)
    labels = patch_labels(size, opts.grid, border=max(3, min(w, h) // 40))
    patches = opts.grid[0] * opts.grid[1]
    layouts = patch_layouts(interior, patches, opts.repeats, opts.seed + zlib.crc32(slot.encode()))
    caps = []
    for j, layout in enumerate(layouts):
        ctx.progress("grey patches", slot, j, len(layouts))
        caps.append(await _show_alone(ctx, slot, np.rint(layout[shown] * 255).astype(np.uint8), opts))
    pose = ctx.rig.slot(slot).pose.matrix

    def reduce() -> tuple[FittedResponse, dict]:
        mask = response_mask(white, black)
        cam_labels = camera_patch_labels(labels, np.asarray(H, np.float64) @ np.linalg.inv(pose), white.shape[:2])
        lv, rho = patch_response(caps, layouts, white=white, black=black, camera_labels=cam_labels, valid=mask)
        base = capture_means([black, white], mask=mask)  # (2, C): black and white means over the lit area
        peak = base[1] - base[0]
        meas_levels = np.concatenate([[0.0], lv, [1.0]])
        measured = np.vstack([base[0], base[0] + rho * peak, base[1]])
        if len(np.unique(meas_levels)) < 3:
            raise CompensationError("too few grey patches landed in the camera image")
        return fit_response(meas_levels, measured, channels=3), {"patches": int(len(lv)), "mask_pixels": int(mask.sum())}

    return await ctx.compute(reduce)


async def _brightness(ctx: JobContext, responses: dict[str, FittedResponse], opts: ResponseOptions) -> dict:
    """One uniform gain for the rig (reference: a slot's white or a luminance); pushes the gains."""
    rig_slots = [s for s in responses if s != opts.reference]
    ref = opts.reference
    if isinstance(ref, str):
        if ref in responses:
            reference = responses[ref]
        else:
            stored = load_stored_response(response_path(ctx.rig, ref), None)
            if stored is None:
                raise JobError(f"reference {ref!r}: no measured response (measure it first, e.g. "
                               f"`shadowless response --slots {ref}`)")
            reference = stored[0]
        kind = f"slot {ref}"
    elif ref is not None:
        reference = float(ref)
        kind = "luminance"
    else:
        # no reference: report the headroom over the dimmest projector's white, change nothing
        dimmest = min(rig_slots, key=lambda s: float(np.mean(responses[s].peak)))
        reference, kind = responses[dimmest], f"none (headroom over the dimmest projector, {dimmest})"
    match = brightness_scale([responses[s] for s in rig_slots], reference)
    gain = 1.0 if ref is None else match.gain
    if gain > 1.0:
        ctx.log(f"the rig cannot reach the reference brightness ({kind}): it is {match.headroom:.3f} x as bright; "
                "gains left at 1")
        gain = 1.0
    for s in rig_slots:
        if abs(ctx.rig.slot(s).gain - gain) > 1e-9:
            ctx.set_slot(s, gain=gain, source="response")
    ctx.progress("brightness", "", 1, 1, f"gain {gain:.4f}, headroom {match.headroom:.3f} x", value=gain)
    return {"reference": kind, "gain": round(gain, 6), "headroom": round(match.headroom, 4),
            "reachable": match.reachable, "channel_headroom": [round(float(v), 4) for v in match.channel_headroom],
            "rig_white": [rounded(float(v), 6) for v in match.rig_peak],
            "reference_white": [rounded(float(v), 6) for v in match.reference_peak]}


async def _verify(ctx: JobContext, opts: ResponseOptions, H: np.ndarray | None) -> dict:
    """Show linear levels through every LUT; fit a straight line to the rig's light."""
    cw, ch = content_size(ctx)
    ys = np.linspace(0.0, 1.0, opts.verify_levels)
    caps = []
    for k, y in enumerate(ys):
        ctx.progress("linearity", "", k, len(ys), f"level {y:.3f}")
        await ctx.show_content(np.full((ch, cw), y, np.float32), settle_s=opts.settle_s)
        caps.append(await ctx.capture(opts.camera, frames=opts.frames))
    ctx.progress("linearity", "", len(ys), len(ys))

    def check() -> dict:
        if H is not None:
            rows, cols = inscribed_region(H, (cw, ch), caps[0].shape[:2], margin=4)
            mask = np.zeros(caps[0].shape[:2], bool)
            mask[rows, cols] = True
            mask &= response_mask(caps[-1], caps[0])
        else:
            mask = response_mask(caps[-1], caps[0])
        measured = capture_means(caps, mask=mask)
        lin = verify_linearity(ys, measured, tolerance=opts.tolerance)
        return {"linear": lin.linear, "max_error": round(lin.max_error, 5), "rms_error": round(lin.rms_error, 5),
                "tolerance": lin.tolerance, "slope": [round(float(v), 6) for v in lin.slope],
                "intercept": [round(float(v), 6) for v in lin.intercept], "levels": [round(float(y), 4) for y in ys]}

    out = await ctx.compute(check)
    if not out["linear"]:
        ctx.log(f"warning: the rig's light after the LUTs deviates from a straight line by {100 * out['max_error']:.2f} % "
                f"(tolerance {100 * opts.tolerance:.2f} %)")
    return out
