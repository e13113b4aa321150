"""The ``blend`` job: each projector's light measured through the camera, and the per-pixel alpha
(gain) and beta (black offset) maps that make the rig's summed light even.

Run after ``calibrate`` (poses: where each projector's pixels land) and ``response`` (inverse LUTs:
the blend works in linear light). The slots' blends are cleared while it measures and put back if
it fails. Captures, in order:

1. a flat white through the LUTs with no blend (``before``, at the camera's exposure);
2. black, and the multiplexed blobs (:mod:`imaging.blending.sample_plan`): every projector at
   once, each on sites of its own, so the count barely grows with the number of projectors. They
   are taken at a longer exposure when the camera can (one projector's blob is a small share of
   the rig's white) and scaled back;
3. the same flat white with the new blend (``after``).

Between 2 and 3 it fits each projector's contribution (:mod:`imaging.blending.fit`), computes the
blend (:func:`imaging.blending.solve.compute_blend`), stores both (:mod:`coordinator.blend_store`:
the maps, the figures and the before/after ratio pictures; the contributions for failover) and
sets every slot's maps, which the nodes apply from their next frame. A projector's gain (the
response job's brightness match) multiplies what the blend asks of it, so the contributions are
stored with it folded in.

The contributions live on a grid over the camera image. On a planar rig (a table, a wall) each
projector's pixels are placed on it through its homography. A mesh rig (``experimental_mesh``)
places them through the 3D poses (:mod:`imaging.blending.mesh`: the camera's view of the mesh
rasterised at the grid's size, each grid point's surface point projected through each
projector's 3x4 pose, a shadow-map test for what it reaches), and models each projector's light
as its lamp's smooth light in its own pixels times the geometric factor of the irradiance
(``cos(incidence) / distance^2``, from the mesh's interpolated normals, copies of a vertex pooled),
which changes as fast as the surface bends, times the share of each grid cell that the pixels its
node draws light (a node draws only pixels whose centre sees the mesh: along a projector's own
silhouette, the crown of a bust for a projector grazing it, the staircase of its pixels reaches far
over the surface). The blobs are read with that factor divided out pixel by pixel, inside each
disc's drawn pixels only (:mod:`imaging.blending.mesh_samples`), the flat white then holds the
modelled lights' sum at every point, and the maps are fitted jointly by least squares against the
target (:mod:`imaging.blending.mesh_maps`), through each grid cell's footprint in each projector's
pixels (a grazed cell spans several), since a texel of a projector's map may light two surfaces far
apart; ``map_scale`` "auto" makes them as fine as the grid resolves. On the room's bust, where 3 to 6
projectors reach, the light's p99 non-uniformity goes from 0.36 to 0.027 (issue 37's target: 0.03;
``shadowless bench uniformity --only bust``, and ``--diagnose DIR`` for the model against the room).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import cv2
import numpy as np

from coordinator.blending.geometry_check import slot_digests
from coordinator.blend_store import StoredBlend, save_blend, save_contributions
from coordinator.blending.blend_options import BlendOptions
from coordinator.compensation.jobkit import content_size, rig_geometry
from coordinator.jobs import JobContext, JobError
from coordinator.jobs.results import JobResult
from coordinator.rig import HomographyPose
from imaging.blending.contributions import Contributions, apply_homography_grid, grid_shape, grid_to_camera
from imaging.blending.errors import BlendError
from imaging.blending.fit import fit_contributions
from imaging.blending.mesh import MeshPlacement, mesh_placement
from imaging.blending.mesh_maps import map_scale_for
from imaging.blending.mesh_samples import match_flat_white, read_capture_shaded
from imaging.blending.metrics import ratio_image, seam_step, to_grid, uniformity
from imaging.blending.predict import predict
from imaging.blending.sample_plan import plan_samples
from imaging.blending.samples import Samples, blob_exposure, read_capture
from imaging.blending.solve import compute_blend
from protos.blend import BlendMaps

__all__ = ["OPTIONS", "run", "BlendResult"]

OPTIONS = BlendOptions

#: grid pixels across the camera's longer side when grid_scale is not given
GRID_TARGET = 400
#: the maps' downscale on a planar rig, and the coarsest on a mesh rig, when map_scale is "auto"
DEFAULT_MAP_SCALE = 4
#: the uniformity figures average blocks of 1/BLOCKS of the grid's longer side
BLOCKS = 40


@dataclass(frozen=True, kw_only=True)
class BlendResult(JobResult):
    """The ``blend`` job's result (its figures are also the stored blend's ``info``)."""

    slots: list[str]
    headroom: float
    headroom_mode: str
    brightness_cost: float
    uniformity_before: float | None
    uniformity_after: float | None
    uniformity_predicted: float | None
    colour_after: list[float | None]
    seam_before: float | None
    seam_after: float | None
    captures: int
    blob_captures: int
    blob_exposure: float
    samples: dict[str, int]
    uncovered: dict[str, float]
    white_point: list[float]
    black_fraction: list[float]
    grid: list[int]
    map_scale: int
    compute_s: float
    wall_s: float
    blend_id: str
    created_at: float


def _r(v: float | None, nd: int = 5) -> float | None:
    return None if v is None or not math.isfinite(float(v)) else round(float(v), nd)


def _surface(H: np.ndarray, content: tuple[int, int], camera: tuple[int, int], scale: int) -> np.ndarray:
    """``(h, w) bool``: the grid pixels inside the content's rectangle (the surface), less one pixel."""
    cw, ch = content
    shape = grid_shape(camera, scale)
    corners = np.array([[-0.5, -0.5], [cw - 0.5, -0.5], [cw - 0.5, ch - 0.5], [-0.5, ch - 0.5]])
    cam = apply_homography_grid(H, corners)
    grid = (cam + 0.5) * np.array([shape[1] / camera[0], shape[0] / camera[1]]) - 0.5
    mask = np.zeros(shape, np.uint8)
    cv2.fillPoly(mask, [np.round(grid * 16).astype(np.int32)], 1, shift=4)
    return cv2.erode(mask, np.ones((3, 3), np.uint8)).astype(bool)


def _check(ctx: JobContext, opts: BlendOptions) -> list[str]:
    """The slots to blend; refusals (no pose, planar and 3D poses mixed, no LUT) before anything is shown."""
    rig = ctx.rig
    ctx.camera_spec(opts.camera)
    slots = ctx.select_slots(opts.slots, need_pose=True)
    mesh = [s for s in slots if not isinstance(rig.slot(s).pose, HomographyPose)]
    if mesh and len(mesh) < len(slots):
        raise JobError(f"projector(s) {', '.join(mesh)} have a 3D pose and the others a planar one: blend a table "
                       "rig's or a mesh rig's projectors, not both at once (--slots)")
    if mesh and not opts.experimental_mesh:
        raise JobError(f"projector(s) {', '.join(mesh)} have a 3D pose: the blend measures planar rigs (a table, a "
                       "wall); a mesh rig's blend is experimental (experimental_mesh, --experimental-mesh)")
    no_lut = [s for s in slots if rig.slot(s).lut is None]
    if no_lut:
        raise JobError(f"projector(s) {', '.join(no_lut)} have no inverse-response LUT: the blend works in linear "
                       "light; run `shadowless response` first")
    return slots


def option_defaults(rig) -> tuple[dict, str]:
    """rig.toml's ``[blend] headroom`` is the blend's headroom when a request sets none ("auto" when absent)."""
    h = rig.config.blend.headroom
    return ({} if h is None else {"headroom": h}), f"{rig.path / 'rig.toml'} [blend]"


async def run(ctx: JobContext, opts: BlendOptions) -> BlendResult:
    """Clear the blends, measure, compute, store, set the new blends and verify (see the module docstring)."""
    slots = _check(ctx, opts)
    rig = ctx.rig
    old = {s: rig.slot(s).blend for s in rig.slots if rig.slot(s).blend is not None}
    for s in old:
        ctx.set_slot(s, blend=None, blend_at_ns=0, source="blend")
    if old:
        ctx.log(f"blend: cleared the blend of {len(old)} projector(s) while measuring")
    try:
        return await _run(ctx, opts, slots)
    except BaseException:
        for s in rig.slots:
            want = old.get(s)
            if rig.slot(s).blend is not want:
                ctx.set_slot(s, blend=want, blend_at_ns=0, source="blend")
        if old:
            ctx.log("blend: failed; the earlier blend is back on the projectors")
        raise


async def _mesh_placement(ctx: JobContext, opts: BlendOptions, slots: list[str], cam: tuple[int, int], scale: int
                          ) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, np.ndarray], MeshPlacement]:
    """A mesh rig: the surface on the grid (where the camera sees the mesh), each slot's projector coordinates
    there and the geometric factor of its light there (:func:`imaging.blending.fit.fit_contributions`'
    ``shading``), from the camera's and the projectors' 3D poses and the mesh (:mod:`imaging.blending.mesh`);
    and the same on a grid twice as fine, which the blobs are read on (:mod:`imaging.blending.mesh_samples`)."""
    from coordinator.compensation.mesh_rig import camera_projection, rig_mesh
    from imaging.compensation.errors import CompensationError

    rig = ctx.rig
    try:
        P, size = camera_projection(rig.path, opts.camera)
        mesh = rig_mesh(rig, slots)
    except CompensationError as exc:
        raise JobError(str(exc)) from exc
    if tuple(size) != tuple(cam):
        raise JobError(f"camera {opts.camera} delivers {cam[0]}x{cam[1]} images but was calibrated at "
                       f"{size[0]}x{size[1]}: calibrate again")
    shape = grid_shape(cam, scale)
    poses = {s: (rig.slot(s).pose.matrix, ctx.projector_size(s), rig.slot(s).pose.near_mm, rig.slot(s).pose.far_mm)
             for s in slots}
    try:
        placed = await ctx.compute(mesh_placement, mesh.vertices, mesh.faces, P, cam, shape, poses)
        fine = await ctx.compute(mesh_placement, mesh.vertices, mesh.faces, P, cam,
                                 grid_shape(cam, max(1, scale // 2)), poses)
    except BlendError as exc:
        raise JobError(str(exc)) from exc
    surface = cv2.erode(placed.surface.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    return surface, placed.xy, placed.shading, fine


async def _white(ctx: JobContext, opts: BlendOptions, shape: tuple[int, int]) -> np.ndarray:
    cw, ch = shape
    await ctx.show_content(np.ones((ch, cw), np.float32), apply_lut=True, settle_s=opts.settle_s)
    return await ctx.capture(opts.camera, frames=opts.frames)


async def _run(ctx: JobContext, opts: BlendOptions, slots: list[str]) -> BlendResult:
    t0 = time.monotonic()
    c0 = ctx.captures
    rig = ctx.rig
    content = content_size(ctx)
    if isinstance(rig.slot(slots[0]).pose, HomographyPose):
        rig_geometry(ctx, opts.camera)          # refused before anything is shown when the table mapping is missing

    ctx.progress("white", "", 0, 1, "flat white, no blend")
    before = await _white(ctx, opts, content)
    cam = (before.shape[1], before.shape[0])
    ctx.progress("white", "", 1, 1, "flat white, no blend")
    scale = opts.grid_scale or max(1, int(math.ceil(max(cam) / GRID_TARGET)))
    shading = fine = None
    if isinstance(rig.slot(slots[0]).pose, HomographyPose):
        H, cal_size = rig_geometry(ctx, opts.camera)
        if cal_size != (0, 0) and tuple(cal_size) != cam:
            raise JobError(f"camera {opts.camera} delivers {cam[0]}x{cam[1]} images but was calibrated at "
                           f"{cal_size[0]}x{cal_size[1]}: calibrate again")
        surface = _surface(H, content, cam, scale)
        Hinv = np.linalg.inv(H)
        c2p = {}
        for s in slots:
            m = rig.slot(s).pose.matrix @ Hinv
            c2p[s] = m / m[2, 2]
    else:
        surface, c2p, shading, fine = await _mesh_placement(ctx, opts, slots, cam, scale)
    sizes = {s: ctx.projector_size(s) for s in slots}
    try:
        plan = await ctx.compute(plan_samples, cam, c2p, sizes, surface=surface, radius=opts.blob_radius,
                                 spacing=opts.blob_spacing, samples=opts.samples)
    except BlendError as exc:
        raise JobError(str(exc)) from exc
    exposure = 1.0
    if ctx.supports_exposure(opts.camera):
        exposure = await ctx.compute(blob_exposure, before, plan, longest=opts.max_exposure)
    e = None if exposure == 1.0 else exposure
    counts = plan.counts()
    ctx.log(f"blend: {len(plan.sites)} blob sites, {plan.captures} capture(s) sample {len(slots)} projector(s) "
            f"({min(counts.values())}..{max(counts.values())} samples each), blob radius {plan.radius:.1f} px, "
            f"exposure x{exposure:.2f}")

    ctx.progress("blobs", "", 0, plan.captures + 1, "black")
    await ctx.show({s: None for s in slots}, settle_s=opts.settle_s, require=[])
    black = await ctx.capture(opts.camera, frames=opts.frames, exposure=e) / np.float32(exposure)
    samples = Samples()
    for k in range(plan.captures):
        frames = await ctx.compute(plan.frames, k)
        await ctx.show(frames, settle_s=opts.settle_s)
        cap = await ctx.capture(opts.camera, frames=opts.frames, exposure=e) / np.float32(exposure)
        if fine is None:
            read = await ctx.compute(read_capture, cap, black, plan, k, samples)
        else:
            read = await ctx.compute(read_capture_shaded, cap, black, plan, k, samples, fine.xy, fine.shading)
        ctx.progress("blobs", "", k + 2, plan.captures + 1, f"{read} blobs read", value=float(read))
    blob_captures = ctx.captures - c0 - opts.frames

    tc = time.monotonic()
    try:
        measured, fit_figs = await ctx.compute(fit_contributions, plan, samples, black, c2p, scale=scale,
                                               surface=surface, degree=opts.degree, shading=shading,
                                               shaded=fine is not None)
    except BlendError as exc:
        raise JobError(str(exc)) from exc
    if fine is not None:     # a mesh: the flat white measured the lights' sum at every point; hold the model to it
        flat = to_grid(before - black, measured.shape)
        measured = Contributions(measured.camera_size, measured.scale, match_flat_white(measured.white, flat, surface),
                                 dict(measured.black), dict(measured.camera_to_projector),
                                 dict(measured.projector_size), measured.projector_xy)
    gains = {s: float(rig.slot(s).gain) for s in slots}
    contributions = Contributions(measured.camera_size, measured.scale,
                                  {s: measured.white[s] * np.float32(gains[s]) for s in slots},
                                  dict(measured.black), dict(measured.camera_to_projector), dict(measured.projector_size),
                                  measured.projector_xy)
    headroom = None if opts.headroom == "auto" else float(opts.headroom)
    map_scale = opts.map_scale
    if map_scale == "auto":
        map_scale = DEFAULT_MAP_SCALE if fine is None else map_scale_for(c2p, coarsest=DEFAULT_MAP_SCALE)
        ctx.log(f"blend: maps at 1/{map_scale} of each projector's resolution")
    try:
        sol = await ctx.compute(compute_blend, contributions, headroom=headroom, map_scale=map_scale,
                                smoothness=opts.smoothness, ramp=opts.ramp)
    except BlendError as exc:
        raise JobError(str(exc)) from exc
    compute_s = time.monotonic() - tc
    ctx.progress("blend", "", 1, 1, f"headroom {sol.headroom:.0%}, brightness cost {sol.brightness_cost:.0%}",
                 value=sol.brightness_cost)
    maps = {s: BlendMaps(a, b) for s, (a, b) in sol.maps.items()}
    # what a viewer should see of a flat white: the target on the even black floor (both on the grid)
    seen = sol.target + sol.black_target[..., None] * sol.white_point[None, None, :]
    predicted = await ctx.compute(lambda: predict(contributions, sol.maps, 1.0))

    # set the blend on the projectors, then see it
    for s in slots:
        ctx.set_slot(s, blend=maps[s], blend_at_ns=0, source="blend")
    ctx.progress("white", "", 0, 1, "flat white, blended")
    after = await _white(ctx, opts, content)
    ctx.progress("white", "", 1, 1, "flat white, blended")

    def figures() -> dict:
        shape = sol.target.shape[:2]
        k = max(3, int(round(max(shape) / BLOCKS)))  # block means: the rig's evenness, not the camera's noise
        # the captures as they are, black included, against the target on its black floor: what is seen
        lit_before, lit_after = to_grid(before, shape), to_grid(after, shape)
        rb, _ = ratio_image(lit_before, seen, sol.covered, block=k)
        ra, _ = ratio_image(lit_after, seen, sol.covered, block=k)
        return {
            "before": uniformity(lit_before, seen, sol.covered, block=k),
            "after": uniformity(lit_after, seen, sol.covered, block=k),
            "predicted": uniformity(predicted, seen, sol.covered, block=k),
            "colour": [uniformity(lit_after, seen, sol.covered, block=k, channel=c) for c in range(3)],
            "seam_before": seam_step(lit_before, contributions, sol.covered, block=k, target=seen),
            "seam_after": seam_step(lit_after, contributions, sol.covered, block=k, target=seen),
            "pictures": {"before": np.nan_to_num(rb, nan=0.0).astype(np.float32),
                         "after": np.nan_to_num(ra, nan=0.0).astype(np.float32)},
        }

    fig = await ctx.compute(figures)
    created = time.time()
    blend_id = _blend_id(maps)
    result = BlendResult(
        slots=list(slots), headroom=_r(sol.headroom, 4), headroom_mode=str(opts.headroom),
        brightness_cost=_r(sol.brightness_cost, 4), uniformity_before=_r(fig["before"]),
        uniformity_after=_r(fig["after"]), uniformity_predicted=_r(fig["predicted"]),
        colour_after=[_r(v) for v in fig["colour"]], seam_before=_r(fig["seam_before"]),
        seam_after=_r(fig["seam_after"]), captures=ctx.captures - c0, blob_captures=blob_captures,
        blob_exposure=_r(exposure, 3), samples={s: int(v["samples"]) for s, v in fit_figs["slots"].items()},
        uncovered={s: _r(v, 4) for s, v in sol.uncovered.items()},
        white_point=[_r(float(v), 4) for v in sol.white_point], black_fraction=fit_figs["black_fraction"],
        grid=[int(sol.target.shape[1]), int(sol.target.shape[0])], map_scale=map_scale,
        compute_s=_r(compute_s, 3), wall_s=_r(time.monotonic() - t0, 3), blend_id=blend_id, created_at=created)
    info = {**result.to_wire(), "smoothness": opts.smoothness, "ramp": opts.ramp, "fit": fit_figs["slots"],
            "camera": opts.camera, "gains_folded": gains, "slot_digests": slot_digests(rig, slots)}
    arrays, meta = contributions.to_arrays()
    meta = {**meta, "gains_folded": gains, "measured_at": created}
    try:
        await ctx.compute(save_contributions, rig.path, arrays, meta)
        await ctx.compute(save_blend, rig.path, StoredBlend(maps=maps, info=info, pictures=fig["pictures"]))
    except Exception as exc:  # the store's errors are one line each
        raise JobError(f"the blend could not be stored: {exc}") from exc
    ctx.log(f"blend: non-uniformity {100 * fig['before']:.1f} % -> {100 * fig['after']:.1f} % "
            f"(predicted {100 * fig['predicted']:.1f} %), seam {100 * fig['seam_before']:.1f} % -> "
            f"{100 * fig['seam_after']:.1f} %, headroom {sol.headroom:.3f} costs {100 * sol.brightness_cost:.1f} % "
            f"of the brightness; {ctx.captures - c0} captures")
    return result


def _blend_id(maps: dict[str, BlendMaps]) -> str:
    import hashlib

    h = hashlib.blake2b(digest_size=8)
    for s in sorted(maps):
        h.update(s.encode())
        h.update(maps[s].blend_id.encode())
    return h.hexdigest()
