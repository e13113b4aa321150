"""A table's light transport: ``L`` measured from dot-grid captures, and the baseline's ``L_i``.

``S*S`` dot-grid captures with every projector showing the same content pattern through its
pose (plus one black capture) give the summed light transport ``L`` (camera pixels x content
pixels), stored in ``compensation/transport.npz``. A camera that can change its exposure per
capture takes the dots longer than the white, as far as the first pattern allows (two more
captures: that pattern at the camera's exposure, and the black at the longer one;
:func:`~imaging.compensation.exposure.dot_exposure`), and ``L``'s noise falls as much. The
PSF radius follows the geometry (:func:`~imaging.compensation.geometry.psf_radius`) and the
spacing is the smallest that keeps the dots' windows apart
(:func:`~imaging.compensation.geometry.choose_spacing`); a measured ``L`` whose windows cut
light is reported
(:func:`~imaging.compensation.geometry.edge_energy`). With ``baseline``, each projector's
``L_i`` is measured too, one projector at a time (``N*S*S`` captures), for the conventional
method only.

A stored ``L`` is reused while the rig is as it was measured (poses, LUTs, gains, content
size, camera, table mapping) and its dot grid matches whatever radius, spacing or frames the
caller sets; ``force`` measures again. The mesh's counterpart is
:mod:`coordinator.compensation.mesh_transport`; both are reached through a
:class:`~coordinator.compensation.surface.Surface`.
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from coordinator.compensation.baselines import BaselineFigures, BaselineScan, lit_baselines, measure_baselines
from coordinator.compensation.capture_feed import dot_captures, transport_while_capturing, warn_cut_windows
from coordinator.compensation.jobkit import (
    baseline_exposure,
    content_size,
    rig_geometry,
    stored_transport,
)
from coordinator.compensation.memory_check import check_baseline, check_measure
from coordinator.compensation.options import TransportOptions
from coordinator.compensation.store import (
    StoredTransport,
    baseline_fingerprint,
    rig_state_fingerprint,
    save_measured_transport,
    stored_baselines,
    transport_fingerprint,
)
from coordinator.jobs import JobContext, JobError
from imaging.compensation.errors import CompensationError
from imaging.compensation.exposure import dot_exposure
from imaging.compensation.geometry import choose_spacing, edge_energy, psf_radius
from imaging.compensation.transport import DotGrid
from protos.spaces import warp_content

__all__ = ["ensure_transport", "ensure_baseline"]


async def ensure_transport(ctx: JobContext, opts: TransportOptions, slots: list[str], *,
                           measure: bool = True) -> StoredTransport:
    """The stored ``L`` when its fingerprint matches (and not ``force``), else a new measurement
    (``measure=False``: a :class:`JobError` instead)."""
    rig = ctx.rig
    H, cal_size = rig_geometry(ctx, opts.camera)
    cw, ch = content_size(ctx)
    radius = opts.radius
    if radius is None:
        radius = psf_radius(H, [rig.slot(s).pose.matrix for s in slots], (cw, ch))
    state = rig_state_fingerprint(rig, slots, H, opts.camera)
    fp = transport_fingerprint(state, radius, opts.spacing, opts.frame_count)
    found = stored_transport(ctx, state, opts.given, H, slots, force=opts.force, measure=measure)
    if found is not None:
        return found
    spec = ctx.camera_spec(opts.camera)
    t0 = time.monotonic()
    c0 = ctx.captures
    frames = opts.frame_count
    ctx.progress("transport", "", 0, 1, "every projector black")
    await ctx.show_content(np.zeros((ch, cw), np.uint8), settle_s=opts.settle_s)
    black = await ctx.capture(opts.camera, frames=frames)
    cam = black.shape[:2]
    if cal_size != (0, 0) and tuple(cal_size) != (cam[1], cam[0]):
        raise JobError(f"camera {opts.camera} delivers {cam[1]}x{cam[0]} images but was calibrated at "
                       f"{cal_size[0]}x{cal_size[1]}: calibrate again")
    check_measure((cw, ch), cam, radius)  # the camera's size is known now; nothing large is held yet
    spacing = opts.spacing
    if spacing is None:
        try:
            spacing = choose_spacing(H, (ch, cw), cam, radius, guard=1)
        except CompensationError as exc:
            raise JobError(str(exc)) from exc
    grid = DotGrid(cw, ch, spacing)
    ctx.log(f"light transport: {len(grid)} dot patterns (spacing {spacing}, radius {radius}, "
            f"{frames} frame(s) each), every projector at once")

    async def show_pattern(k: int) -> None:
        await ctx.show_content(grid.pattern(k, value=255, dtype=np.uint8), settle_s=opts.settle_s)

    async def capture(e: float | None, n: int) -> np.ndarray:
        return await ctx.capture(opts.camera, frames=n, exposure=e)

    # the dots light a few content pixels apart: captured longer than the white, as far as the first pattern allows
    dots = await dot_exposure(capture, show_first=lambda: show_pattern(0),
                              show_black=lambda: ctx.show_content(np.zeros((ch, cw), np.uint8), settle_s=opts.settle_s),
                              black=black, exposure=None, frames=frames, log=ctx.log,
                              adjustable=ctx.supports_exposure(opts.camera))

    L = await transport_while_capturing(ctx, dot_captures(ctx, len(grid), show_pattern, dots, capture, frames), black,
                                        grid=grid, homography=H, radius=radius)
    dots.report(len(grid), ctx.log)
    seconds = time.monotonic() - t0
    edge = await ctx.compute(edge_energy, L, H, (ch, cw), cam, radius)
    warn_cut_windows(ctx.log, edge, radius)
    meta = {"fingerprint": fp, "rig_state": state, "radius": radius, "spacing": spacing, "frames": frames,
            "captures": ctx.captures - c0, "patterns": len(grid), "content_size": [cw, ch],
            "camera_size": [cam[1], cam[0]], "content_to_camera": np.asarray(H).tolist(), "camera": opts.camera,
            "camera_spec": spec, "slots": sorted(slots), "measured_at": time.time(),
            "date": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "seconds": round(seconds, 3), "nnz": int(L.nnz),
            "black_file": f"black-{fp}.npy", "edge_energy": round(edge, 5), "dot_gain": round(dots.gain, 4),
            "patterns_captured_again": len(dots.again)}
    await ctx.compute(save_measured_transport, rig, L, meta, black)
    return StoredTransport(L, meta, black, H, cam, slots, False)


async def ensure_baseline(ctx: JobContext, tr: StoredTransport,
                          opts: TransportOptions) -> tuple[dict[str, sp.csr_matrix], BaselineFigures]:
    """The per-projector ``L_i`` (baseline only): stored ones with a matching fingerprint, the rest measured
    one projector at a time; projectors that add no light are left out. Returns them and their figures."""
    rig = ctx.rig
    exposure = baseline_exposure(ctx, opts)
    frames = opts.baseline_frame_count
    fp = baseline_fingerprint(tr.meta["fingerprint"], frames, opts.baseline_exposure)
    cw, ch = content_size(ctx)
    grid = DotGrid(cw, ch, int(tr.meta["spacing"]))
    radius = int(tr.meta["radius"])
    check_baseline((cw, ch), tr.camera_shape, radius, len(tr.slots))  # stored or measured, every L_i is held
    out, todo = stored_baselines(rig, tr.slots, fp, tr.L.shape)
    t0 = time.monotonic()
    c0 = ctx.captures
    if todo:
        async def frame(s: str, k: int) -> np.ndarray:
            st = rig.slot(s)
            return await ctx.compute(warp_content, grid.pattern(k, value=255, dtype=np.uint8), st.pose.matrix,
                                     (st.width, st.height), lut=st.lut, gain=st.gain)

        async def capture() -> np.ndarray:
            return await ctx.capture(opts.camera, frames=frames, exposure=exposure)

        scan = BaselineScan(len(grid), frame, capture, {"grid": grid, "homography": tr.H, "radius": radius})
        await measure_baselines(ctx, tr, opts, scan, fingerprint=fp, todo=todo, out=out)
    return lit_baselines(ctx, tr, opts, out, todo=todo, captures=ctx.captures - c0, seconds=time.monotonic() - t0,
                         captures_per_projector=len(grid) * frames, unlit="powered off?")
