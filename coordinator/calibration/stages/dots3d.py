"""Stage 3, multiplexed on a mesh (3D): every projector at once, so the captures do not grow
with their number. Coded dots decoded in every posed camera and lifted onto the surface give
each projector a coarse 3x4 pose; a lattice of dots planned on the surface through the coarse
poses (so that no two overlap on the object) gives the final one
(:mod:`imaging.calibration.multiplex3d`)."""
from __future__ import annotations

import numpy as np

from imaging.calibration import multiplex, threed
from imaging.calibration.alignment import plan_surface_lattice
from imaging.calibration.errors import CalibrationError
from imaging.calibration.multiplex3d import fit_pose, lift
from coordinator.calibration.runs import save_slot, slot_doc
from coordinator.calibration.stages.dots import check_dot_saturation
from coordinator.calibration.stages.loops import coarse_fits, coded_dot_rounds, refuse_unfound
from coordinator.calibration.stages.state import State
from coordinator.jobs import JobError
from coordinator.rig import ProjectionPose
from protos.wording import plural

MIN_COARSE_DOTS = 6         # stage 1: fewest lifted dots for a coarse pose (7 degrees of freedom with a fixed principal point)
MIN_LATTICE_DOTS = 20       # stage 2: fewest measured dots for the final pose
OBJECT_DOTS_WANTED = 24     # stage 2: add rounds while a projector would get fewer dots on the object than this
ON_OBJECT_MM = 5.0          # a site this far above the table is on the object
MAX_ROUNDS = 16
COARSE_DOTS = 256           # stage 1: dots per projector while the code space holds them (the planar mode's 48
                            # leave too few on the object; 2**bits / N caps them for larger rigs)


def usable_surfaces(setup, table_mm: tuple[float, float] | None) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per posed camera: the world point of every pixel, (H, W, 3) float64, and the pixels whose points
    may be used, (H, W) bool (on the mesh, or on the table when ``table_mm`` is given; away from
    silhouettes and depth steps)."""
    out = {}
    with threed.SurfaceCaster(setup.mesh, table_mm=table_mm) as caster:
        for i, dev in setup.devices.items():
            pts, kind = caster.cast(dev)
            out[i] = (pts, (kind != 0) & ~threed.edge_mask(pts, kind))
    return out


def cast_projectors(setup, table_mm: tuple[float, float] | None, devices: dict[str, threed.Pinhole]) -> dict[str, np.ndarray]:
    """Per projector: the world point each of its pixels lights through ``devices`` (its coarse pose)."""
    with threed.SurfaceCaster(setup.mesh, table_mm=table_mm) as caster:
        return {s: caster.cast(d)[0] for s, d in devices.items()}


async def multiplexed_3d(st: State) -> None:
    """Calibrate ``st.todo`` all at once on the mesh (the lattice in the first posed camera)."""
    ctx, opts, setup = st.ctx, st.opts, st.setup
    table = opts.table_mm if opts.use_table else None
    try:
        surfaces = await ctx.compute(usable_surfaces, setup, table)
    except CalibrationError as exc:
        raise JobError(str(exc)) from exc
    coarse, seen = await _coded_dots(st, surfaces)
    ok = [s for s in st.todo if s in coarse]
    if ok:
        await _lattice(st, ok, coarse, seen, surfaces)
    if st.failed and not opts.keep_going:
        raise JobError("; ".join(st.failed.values()))


async def _coded_dots(st: State, surfaces) -> tuple[dict[str, threed.Pinhole], dict[str, int]]:
    """Coarse poses from the coded dots lifted onto the surface; a retry round for projectors short of dots."""
    ctx, opts = st.ctx, st.opts
    coarse: dict[str, threed.Pinhole] = {}
    seen: dict[str, int] = {s: 0 for s in st.todo}
    # lifted dots of every attempt: a retry adds to what the first one found
    X: dict[str, list[np.ndarray]] = {s: [] for s in st.todo}
    x: dict[str, list[np.ndarray]] = {s: [] for s in st.todo}

    async def decide(plan: multiplex.CodedDots, caps: list[list[np.ndarray]], pending: list[str]) -> list[str]:
        for i in surfaces:
            k_cam = st.cameras.index(i)
            mine = [c[k_cam] for c in caps]
            dec = await ctx.compute(multiplex.decode_coded_dots, mine, st.dark[k_cam], plan)
            ctx.log(f"coded dots, camera {i}: {dec.blobs} blobs, {dec.collisions} overlapping, {dec.unknown} unknown codes")
            check_dot_saturation(mine, dec, i, opts.max_saturated)
            pts, usable = surfaces[i]
            for s in pending:
                m = dec.matches[s]
                seen[s] += m.count
                W = lift(st.setup.devices[i], pts, usable, m.camera) if m.count else np.zeros((0, 3))
                good = np.isfinite(W).all(axis=1)
                X[s].append(W[good])
                x[s].append(m.projector[good])

        async def fit(s: str) -> threed.Pinhole | None:
            Xs, xs = np.vstack(X[s]), np.vstack(x[s])
            if len(Xs) < MIN_COARSE_DOTS:
                return None
            got, _ = await ctx.compute(fit_pose, Xs, xs, st.sizes[s], threshold=2.0, seed=opts.seed)
            return got.device if got.count >= MIN_COARSE_DOTS else None

        return await coarse_fits(pending, fit, coarse)

    pending = await coded_dot_rounds(st, decide, max_dots=COARSE_DOTS)
    refuse_unfound(st, pending, seen, aimed_at="object",
                   too_few=lambda s: f"too few dots on the surface for {s} ({sum(map(len, X[s]))} of {seen[s]} decoded "
                                     f"dots on the mesh{' or the table' if opts.use_table else ''}, need "
                                     f"{MIN_COARSE_DOTS} that agree with one projection): is most of its image off the "
                                     "object or blocked, or the mesh registration off?")
    return coarse, seen


def _plan(st: State, devices: dict[str, threed.Pinhole], surfaces, cam: int, rounds: int, dot_px: int) -> multiplex.Lattice:
    """The surface lattice of ``rounds`` rounds in camera ``cam`` through ``devices`` (the poses so far)."""
    table = st.opts.table_mm if st.opts.use_table else None
    proj_pts = cast_projectors(st.setup, table, devices)
    pts, usable = surfaces[cam]
    return plan_surface_lattice(devices, st.setup.devices[cam], pts, usable, proj_pts, rounds=rounds, dot_px=dot_px)


def _on_object(lattice: multiplex.Lattice, rounds: range) -> int:
    """Median over the projectors of their dots in ``rounds`` whose sites are on the object (above the table)."""
    return int(np.median([sum(int(np.sum(lattice.rounds[r].sites[s][:, 2] > ON_OBJECT_MM)) for r in rounds)
                          for s in lattice.slots]))


def _fit(st: State, s: str, found: list[tuple[np.ndarray, np.ndarray]]):
    """The projector's pose from its lifted lattice dots: (DeviceFit, free) or None when too few."""
    X = np.vstack([f[0] for f in found])
    x = np.vstack([f[1] for f in found])
    if len(X) < MIN_LATTICE_DOTS:
        return None
    return fit_pose(X, x, st.sizes[s], threshold=1.0, seed=st.opts.seed)


async def _planned(st: State, devices: dict[str, threed.Pinhole], surfaces, cam: int, rounds: int,
                   dot_px: int) -> multiplex.Lattice:
    try:
        return await st.ctx.compute(_plan, st, devices, surfaces, cam, rounds, dot_px)
    except (CalibrationError, ValueError) as exc:
        raise JobError(f"cannot plan the lattice on the surface: {exc}") from exc


async def _measure(st: State, lattice: multiplex.Lattice, count: int, *, done: int, total: int, surfaces, cam: int,
                   found: dict[str, list[tuple[np.ndarray, np.ndarray]]]) -> None:
    """Show and capture the first ``count`` rounds of ``lattice`` (``done`` of ``total`` lattice captures
    taken before them); add each projector's lifted dots to ``found``."""
    ctx, k_cam = st.ctx, st.cameras.index(cam)
    pts, usable = surfaces[cam]
    ok = list(lattice.slots)
    for r in range(count):
        ctx.progress("lattice", "", done + r, total, f"{len(ok)} {plural(len(ok), 'projector')} at once")
        cap = (await st.shoot(lattice.frames(r), require=ok))[k_cam]
        ms = await ctx.compute(multiplex.measure_lattice, cap, st.dark[k_cam], lattice, r)
        for s in ok:
            X = lift(st.setup.devices[cam], pts, usable, ms[s].camera)
            good = np.isfinite(X).all(axis=1)
            found[s].append((X[good], ms[s].projector[good]))


async def _lattice(st: State, ok: list[str], coarse: dict[str, threed.Pinhole], seen: dict[str, int], surfaces) -> None:
    """Measure a lattice on the surface in two passes (the second planned through the poses the first
    gave, with finer dots); fit and save each projector's pose."""
    ctx, opts, setup = st.ctx, st.opts, st.setup
    cam = min(surfaces)
    devices = {s: coarse[s] for s in ok}
    found: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {s: [] for s in ok}
    start = st.shots
    # pass 1: dots 3 px wide on a lattice whose step tolerates a coarse pose a few pixels off
    first = max(1, opts.rounds // 2)
    lattice = await _planned(st, devices, surfaces, cam, first, 3)
    have = _on_object(lattice, range(first))
    await _measure(st, lattice, first, done=0, total=opts.rounds, surfaces=surfaces, cam=cam, found=found)
    for s in ok:
        try:
            got = await ctx.compute(_fit, st, s, found[s])
        except CalibrationError:
            got = None
        if got is not None:
            devices[s] = got[0].device
    # pass 2: single-pixel dots on a denser lattice, planned through the better poses; more rounds while a
    # projector would get too few dots on the object (the only growth with N, bounded by MAX_ROUNDS)
    lattice = await _planned(st, devices, surfaces, cam, MAX_ROUNDS - first, 1)
    second = opts.rounds - first
    while first + second < MAX_ROUNDS and have + _on_object(lattice, range(second)) < OBJECT_DOTS_WANTED:
        second += 1
    if first + second > opts.rounds:
        ctx.log(f"lattice: {first + second} rounds (not {opts.rounds}) so that each projector gets "
                f"{have + _on_object(lattice, range(second))} dots on the object")
    await _measure(st, lattice, second, done=first, total=first + second, surfaces=surfaces, cam=cam, found=found)
    total = first + second
    ctx.progress("lattice", "", total, total, "fitting")
    for n, s in enumerate(ok):
        count = sum(len(f[0]) for f in found[s])
        try:
            got = await ctx.compute(_fit, st, s, found[s])
            if got is None:
                st.failed[s] = (f"too few lattice dots measured on the surface for {s} ({count} < {MIN_LATTICE_DOTS}): "
                                "is most of its image off the object, or the mesh registration off?")
                ctx.log(st.failed[s])
                continue
            fit, free = got
            near, far = threed.depth_range(fit.device.P, setup.rig_mesh.vertices)
        except CalibrationError as exc:
            st.failed[s] = f"{s}: {exc}"
            ctx.log(st.failed[s])
            continue
        if not free:
            ctx.log(f"{s}: its dots hardly leave one plane; principal point fixed at the image centre")
        P = fit.device.P / np.linalg.norm(fit.device.P[2, :3])
        pose = ProjectionPose(P, setup.rig_mesh, near_mm=near, far_mm=far)
        doc = slot_doc(st.run, s, opts, rms=fit.rms, mx=fit.max, points=fit.count, coarse_dots=int(seen[s]),
                       lattice_dots=count, captures=st.shots - start, camera=cam, free_intrinsics=free,
                       K=fit.device.K.tolist(), center_mm=fit.device.center.tolist())
        save_slot(ctx, s, pose, doc)
        st.results[s] = doc
        ctx.progress("projectors", s, n + 1, len(ok), f"calibrated, reprojection error {fit.rms:.3f} px", value=fit.rms)
