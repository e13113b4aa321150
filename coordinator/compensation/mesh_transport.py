"""A mesh rig's light transport: ``L`` in texture space, every projector at once.

Each node renders the dot pattern as the mesh's texture through its own 3x4 pose, so every
projector lights the same surface dots; ``sx * sy`` patterns (plus a few extra patterns for dots
that would crowd in a camera, and four captures: the white that sets the exposure, the black, and
the first pattern and the black that set the dots' longer one, :mod:`imaging.compensation.exposure`)
whatever the number of projectors (:class:`~imaging.compensation.mesh_geometry.TexelGrid`). Several
cameras (``camera_indices``) measure together, each capturing every pattern, as one camera whose
image is theirs stacked (:mod:`coordinator.compensation.mesh_cameras`). Each
dot's window is centred where the camera sees its texel
(:func:`~imaging.compensation.texture_space.texel_camera_map`); dots that would crowd in a
camera move to extra patterns (:mod:`imaging.compensation.mesh_geometry`), and texels no camera
sees, or whose light is too wide for a window, get no column and are reported. The windows reach
:data:`TAIL_FACTOR` times the PSF's core radius (from the geometry) unless ``radius`` is given: the
core's entries are each texel's own, the tail's the mean over its neighbours
(:mod:`imaging.compensation.psf_tails`), so ``L 1`` holds the defocus's spill without the
clipped noise of a single capture. Stored, reused and refused as the table's ``L``
(:mod:`coordinator.compensation.planar_transport`), with the cameras' projections and the mesh in
its fingerprint. With ``baseline`` each projector's ``L_i`` is measured one at a time: the
coordinator renders the texture through that projector's pose (:func:`~coordinator.compensation.
texture_space.mesh_warp`, the node's mesh shader in numpy) and shows it on that projector alone.
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from coordinator.compensation.baselines import BaselineFigures, BaselineScan, lit_baselines, measure_baselines
from coordinator.compensation.capture_feed import dot_captures, transport_while_capturing, warn_cut_windows
from coordinator.compensation.memory_check import check_measure, check_stored
from imaging.compensation.errors import CompensationError
from imaging.compensation.exposure import dot_exposure, exposure_for_white
from imaging.compensation.geometry import psf_radius_at_scales
from coordinator.compensation.jobkit import (
    baseline_exposure,
    content_size,
    rounded,
    stored_transport,
)
from coordinator.compensation.mesh_cameras import (
    camera_blocks,
    camera_summary,
    stacked_ring_energy,
    stacked_row_weights,
    stacked_windows,
)
from imaging.compensation.mesh_geometry import (
    measured_texels,
    schedule_dots,
    texel_extent,
    texel_transport_from_captures,
    view_scales,
)
from coordinator.compensation.mesh_rig import MeshCameras, mesh_cameras
from coordinator.compensation.options import TransportOptions
from coordinator.compensation.store import (
    StoredTransport,
    baseline_fingerprint,
    rig_state_fingerprint,
    save_measured_transport,
    stored_baselines,
    transport_fingerprint,
)
from imaging.compensation.texture_space import mesh_warp
from coordinator.jobs import JobContext, JobError

__all__ = ["ensure_mesh_transport", "ensure_mesh_baseline", "load_geometry", "texel_summary",
           "solve_weights", "stored_cameras", "capture_cameras"]


#: default window radius over the PSF's core radius from the geometry: the outer part holds the lens's
#: defocus tail, measured as the mean over neighbouring texels (:mod:`imaging.compensation.psf_tails`)
TAIL_FACTOR = 2


async def load_geometry(ctx: JobContext, slots: list[str], cameras: tuple[int, ...], *,
                        projectors: bool = False) -> MeshCameras:
    """The rig's mesh geometry seen by ``cameras`` (:func:`~coordinator.compensation.mesh_rig.mesh_cameras`) off
    the loop."""
    try:
        return await ctx.compute(mesh_cameras, ctx.rig, slots, list(cameras), projectors=projectors)
    except CompensationError as exc:
        raise JobError(str(exc)) from exc


def stored_cameras(tr: StoredTransport) -> tuple[int, ...]:
    """The cameras a stored ``L`` was measured with, in the order of its stacked rows."""
    return tuple(int(c) for c in tr.meta.get("cameras", [tr.meta["camera"]]))


async def capture_cameras(ctx: JobContext, cameras: tuple[int, ...], *, frames: int,
                          exposure: float | None = None) -> np.ndarray:
    """One capture of the pattern shown from each of ``cameras``, stacked top to bottom: ``(K Hc, Wc, C)``."""
    shots = [await ctx.capture(c, frames=frames, **({"exposure": exposure} if exposure is not None else {}))
             for c in cameras]
    if len({s.shape for s in shots}) != 1:
        raise JobError("the cameras measured together deliver different image sizes ("
                       + ", ".join(f"camera {c}: {s.shape[1]}x{s.shape[0]}" for c, s in zip(cameras, shots)) + ")")
    return shots[0] if len(shots) == 1 else np.concatenate(shots, axis=0)


def solve_weights(cams: MeshCameras, tr: StoredTransport) -> np.ndarray:
    """:func:`~coordinator.compensation.mesh_cameras.stacked_row_weights` of a measured mesh rig:
    ``(K Hc, Wc) float32``."""
    return stacked_row_weights(cams, tr.L, radius=int(tr.meta.get("core", tr.meta["radius"])))


def texel_summary(tr: StoredTransport, cams: MeshCameras) -> dict:
    """How much of the texture the measurement covers: texels on the mesh, seen by a camera, in ``L``; per
    camera, and how many cameras see each texel (:func:`~coordinator.compensation.mesh_cameras.camera_summary`)."""
    on = int(np.count_nonzero(cams.on_mesh))
    measured = int(np.count_nonzero(measured_texels(tr.L)))
    seen = int(np.count_nonzero(cams.visible))
    return {"texels": int(cams.on_mesh.size), "on_mesh": on, "seen": seen, "measured": measured,
            "left_out": seen - measured, "unseen": on - seen,
            "unseen_share": rounded(1 - seen / on if on else 1.0, 4),
            "measured_share": rounded(measured / on if on else 0.0, 4), **camera_summary(cams, tr.L)}


async def ensure_mesh_transport(ctx: JobContext, opts: TransportOptions, slots: list[str], *,
                                measure: bool = True) -> tuple[StoredTransport, MeshCameras]:
    """The stored ``L`` of the mesh rig when its fingerprint matches (and not ``force``), else a new
    measurement (``measure=False``: a :class:`JobError` instead); and the rig's geometry in its cameras."""
    rig = ctx.rig
    cameras = opts.camera_list
    cams = await load_geometry(ctx, slots, cameras, projectors=True)
    cw, ch = content_size(ctx)
    extents = [texel_extent(g.texels.position, (ch, cw)) for g in cams.parts]
    # camera px per texel: the reach of a texel's light (it spans its neighbours') for 90 % of the texels
    # a camera sees, so they fit their window; the few larger ones are left out (below); the largest
    # radius the cameras need, as every window has one size: the core of the PSF, kept per texel
    core = 0
    for g, extent in zip(cams.parts, extents):
        _, p = view_scales(g.view, list(g.projectors.values()))
        seen_extent = extent[g.texels.visible]
        c = float(np.percentile(seen_extent, 90)) if seen_extent.size else 1.0
        core = max(core, psf_radius_at_scales(max(c, 0.5), p))
    # the windows reach TAIL_FACTOR times as far by default: the lens's defocus spreads light past the core,
    # and that tail, averaged over neighbouring texels (psf_tails), is part of the rig's white
    radius = opts.radius if opts.radius is not None else TAIL_FACTOR * core
    core = min(core, radius)
    tails = core if core < radius else None
    one = len(cameras) == 1
    key = cams.key()
    state = rig_state_fingerprint(rig, slots, key, cameras[0] if one else cameras)
    fp = transport_fingerprint(state, radius, opts.spacing, opts.frame_count, core=tails)
    P = cams.parts[0].P if one else np.vstack([g.P for g in cams.parts])
    found = stored_transport(ctx, state, opts.given, P, slots, force=opts.force, measure=measure, surface="mesh")
    if found is not None:
        return found, cams
    specs = [ctx.camera_spec(c) for c in cameras]
    t0 = time.monotonic()
    c0 = ctx.captures
    frames = opts.frame_count
    ctx.progress("transport", "", 0, 1, "every projector white: the camera's exposure")
    await ctx.show_content(cams.pad(np.full((ch, cw), 255, np.uint8)), settle_s=opts.settle_s)
    exposure, white_peak = await exposure_for_white(
        lambda e: capture_cameras(ctx, cameras, frames=1, exposure=e),
        adjustable=all(ctx.supports_exposure(c) for c in cameras), log=ctx.log)
    white_exposure = exposure if exposure < 1.0 else None       # None: the camera's own
    ctx.progress("transport", "", 0, 1, "every projector black")
    await ctx.show_content(np.zeros((ch, cw), np.uint8), settle_s=opts.settle_s)
    black = await capture_cameras(ctx, cameras, frames=frames, exposure=white_exposure)
    cam = black.shape[:2]
    if cam != cams.camera_shape:
        what = f"camera {cameras[0]} delivers" if one else "the cameras deliver"
        raise JobError(f"{what} {cam[1]}x{cam[0] // len(cameras)} images but "
                       f"{'was' if one else 'were'} calibrated at {cams.part_shape[1]}x{cams.part_shape[0]}: "
                       "calibrate again")
    check_measure((cw, ch), cam, radius, cameras=len(cameras))  # the cameras' size is known; nothing large is held
    # per camera: the texels it sees whose bilinear hat alone is not wider than the window
    seen = [g.texels.visible & (np.nan_to_num(e, nan=np.inf) <= radius) for g, e in zip(cams.parts, extents)]
    large = cams.visible & ~np.logical_or.reduce(seen)
    positions = [g.texels.position for g in cams.parts]
    # the dots lit for one camera whose light reaches another (at a grazing angle there) stay clear of its windows
    present = [r | s for r, s in zip(cams.reaching, seen)]
    base, _, _ = stacked_windows(positions, present, cams.part_shape, radius)
    try:
        grid = await ctx.compute(schedule_dots, base, np.stack(seen), (ch, cw), radius, spacing=opts.spacing,
                                 present=np.stack(present))
    except CompensationError as exc:
        raise JobError(str(exc)) from exc
    lit = [grid.lit & s for s in seen]
    base, rows, valid = stacked_windows(positions, lit, cams.part_shape, radius)
    who = "the camera sees" if one else f"the {len(cameras)} cameras {', '.join(map(str, cameras))} see"
    ctx.log(f"light transport on the mesh: {len(grid)} dot patterns (from a {grid.spacing[0]}x{grid.spacing[1]} grid, "
            f"radius {radius}, {frames} frame(s) each), every projector at once{'' if one else ', every camera each'}; "
            f"{who} {int(cams.visible.sum())} texels, {int(large.sum())} of them too large for the windows")

    # the dots light a few texels apart: captured longer than the white, as far as the first pattern allows
    async def show_pattern(k: int) -> None:
        await ctx.show_content(cams.pad(grid.pattern(k, value=255, dtype=np.uint8)), settle_s=opts.settle_s)

    async def capture(e: float | None, n: int) -> np.ndarray:
        return await capture_cameras(ctx, cameras, frames=n, exposure=e)

    dots = await dot_exposure(capture, show_first=lambda: show_pattern(0),
                              show_black=lambda: ctx.show_content(np.zeros((ch, cw), np.uint8), settle_s=opts.settle_s),
                              black=black, exposure=white_exposure, frames=frames, log=ctx.log,
                              adjustable=len(grid) > 0 and all(ctx.supports_exposure(c) for c in cameras))

    L = await transport_while_capturing(ctx, dot_captures(ctx, len(grid), show_pattern, dots, capture, frames), black,
                                        recover=texel_transport_from_captures, grid=grid, rows=rows, valid=valid,
                                        core=tails, radius=radius)
    dots.report(len(grid), ctx.log)
    seconds = time.monotonic() - t0
    edge = await ctx.compute(stacked_ring_energy, L, base, cams.part_shape, radius)
    warn_cut_windows(ctx.log, edge, radius)
    spacing = grid.spacing[0] if grid.spacing[0] == grid.spacing[1] else grid.spacing
    projection = np.asarray(P).tolist() if one else [np.asarray(g.P).tolist() for g in cams.parts]
    meta = {"fingerprint": fp, "rig_state": state, "surface": "mesh", "radius": radius, "core": core,
            "tails_averaged": tails is not None, "spacing": spacing,
            "frames": frames, "captures": ctx.captures - c0, "patterns": len(grid), "content_size": [cw, ch],
            "camera_size": [cam[1], cam[0]], "camera_projection": projection, "camera": cameras[0],
            "cameras": list(cameras), "camera_spec": specs[0] if one else specs,
            "mesh_id": cams.mesh.mesh_id, "slots": sorted(slots), "measured_at": time.time(),
            "date": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "seconds": round(seconds, 3), "nnz": int(L.nnz),
            "black_file": f"black-{fp}.npy", "edge_energy": round(edge, 5),
            "texels_seen": int(cams.visible.sum()), "texels_too_large": int(large.sum()),
            "texels_lit": int(grid.lit.sum()), "exposure": exposure, "white_peak": round(white_peak, 4),
            "dot_gain": round(dots.gain, 4), "patterns_captured_again": len(dots.again)}
    await ctx.compute(save_measured_transport, rig, L, meta, black)
    return StoredTransport(L, meta, black, P, cam, slots, False), cams


async def ensure_mesh_baseline(ctx: JobContext, tr: StoredTransport,
                               opts: TransportOptions) -> tuple[dict[str, sp.csr_matrix], BaselineFigures]:
    """The per-projector ``L_i`` on the mesh (baseline only), as
    :func:`coordinator.compensation.planar_transport.ensure_baseline`: stored ones reused, the rest measured one
    projector at a time, each shown the texture pattern through its own pose by the coordinator."""
    rig = ctx.rig
    measured_at = float(tr.meta.get("exposure", 1.0))        # L's captures' exposure: the L_i's units too
    exposure = (baseline_exposure(ctx, opts) or 1.0) * measured_at
    exposure = exposure if exposure != 1.0 else None
    frames = opts.baseline_frame_count
    fp = baseline_fingerprint(tr.meta["fingerprint"], frames, opts.baseline_exposure)
    cw, ch = content_size(ctx)
    radius = int(tr.meta["radius"])
    tails = int(tr.meta["core"]) if tr.meta.get("tails_averaged") else None
    check_stored(tr.L, what=f"{len(tr.slots)} per-projector baseline transports", baselines=len(tr.slots), solve=False)
    out, todo = stored_baselines(rig, tr.slots, fp, tr.L.shape)
    t0 = time.monotonic()
    c0 = ctx.captures
    if todo:
        cameras = stored_cameras(tr)
        cams = await load_geometry(ctx, tr.slots, cameras, projectors=True)
        use = [measured_texels(b) for b in camera_blocks(tr.L, len(cameras))]
        positions = [g.texels.position for g in cams.parts]
        # any schedule that separates the measured texels' windows will do: the stored grid's, recoloured
        present = [r | u for r, u in zip(cams.reaching, use)]
        base, _, _ = stacked_windows(positions, present, cams.part_shape, radius)
        grid = await ctx.compute(schedule_dots, base, np.stack(use), (ch, cw), radius, spacing=tr.meta["spacing"],
                                 present=np.stack(present))
        _, rows, valid = stacked_windows(positions, use, cams.part_shape, radius)

        async def frame(s: str, k: int) -> np.ndarray:
            st = rig.slot(s)
            return await ctx.compute(mesh_warp, cams.pad(grid.pattern(k, value=255, dtype=np.uint8)),
                                     cams.projectors[s], lut=st.lut, gain=st.gain)

        async def capture() -> np.ndarray:
            return await capture_cameras(ctx, cameras, frames=frames, exposure=exposure)

        scan = BaselineScan(len(grid), frame, capture,
                            {"recover": texel_transport_from_captures, "grid": grid, "rows": rows, "valid": valid,
                             "core": tails, "radius": radius})
        await measure_baselines(ctx, tr, opts, scan, fingerprint=fp, todo=todo, out=out)
    return lit_baselines(ctx, tr, opts, out, todo=todo, captures=ctx.captures - c0, seconds=time.monotonic() - t0,
                         captures_per_projector=(len(grid) * frames) if todo else None,
                         unlit="powered off, or it does not see the surface the camera sees")
