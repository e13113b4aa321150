"""Stage 3, multiplexed (planar): every projector at once, so the captures do not grow with
their number. Coded dots give each projector a coarse pose; an interleaved lattice of dots
planned through the coarse poses then gives the final one
(:mod:`imaging.calibration.multiplex`)."""
from __future__ import annotations

import math

import numpy as np

from imaging.calibration import multiplex, planar
from imaging.calibration.errors import CalibrationError
from coordinator.calibration.runs import save_slot, slot_doc
from coordinator.calibration.stages.loops import coarse_fits, coded_dot_rounds, refuse_unfound
from coordinator.calibration.stages.state import SATURATED, Abort, State
from coordinator.jobs import JobError
from coordinator.rig import HomographyPose
from protos.spaces import content_to_table
from protos.wording import count

MIN_COARSE_DOTS = 6         # stage 1: fewest decoded dots for a coarse pose
MIN_LATTICE_DOTS = 12       # stage 2: fewest measured dots for the final pose
LATTICE_DOTS_WANTED = 40    # stage 2: add rounds when a projector would get fewer dots than this


async def multiplexed(st: State) -> None:
    """Calibrate ``st.todo`` all at once on the table (in the first camera with a table mapping)."""
    cam = min(st.setup.table_to_camera)       # the lattice is planned and measured in one camera
    coarse, seen = await _coded_dots(st, cam)
    ok = [s for s in st.todo if s in coarse]
    if ok:
        await _lattice(st, cam, ok, coarse, seen)
    if st.failed and not st.opts.keep_going:
        raise JobError("; ".join(st.failed.values()))


async def _coded_dots(st: State, cam: int) -> tuple[dict[str, np.ndarray], dict[str, int]]:
    """Coarse table -> projector homographies; a retry round for projectors short of dots."""
    ctx, opts = st.ctx, st.opts
    H_cam_to_table = np.linalg.inv(st.setup.table_to_camera[cam])
    k_cam = st.cameras.index(cam)
    coarse: dict[str, np.ndarray] = {}
    seen: dict[str, int] = {s: 0 for s in st.todo}

    async def decide(plan: multiplex.CodedDots, shots: list[list[np.ndarray]], pending: list[str]) -> list[str]:
        caps = [c[k_cam] for c in shots]
        dec = await ctx.compute(multiplex.decode_coded_dots, caps, st.dark[k_cam], plan)
        ctx.log(f"coded dots: {dec.blobs} blobs, {dec.collisions} overlapping, {dec.unknown} unknown codes")
        check_dot_saturation(caps, dec, cam, opts.max_saturated)
        for s in pending:
            seen[s] += dec.matches[s].count

        async def fit(s: str) -> np.ndarray | None:
            m = dec.matches[s]
            if m.count < MIN_COARSE_DOTS:
                return None
            got = planar.fit_homography(planar.apply_homography(H_cam_to_table, m.camera), m.projector, threshold=2.0)
            return got.H if got.count >= MIN_COARSE_DOTS else None

        return await coarse_fits(pending, fit, coarse)

    pending = await coded_dot_rounds(st, decide)
    refuse_unfound(st, pending, seen, aimed_at="table",
                   too_few=lambda s: f"too few dots decoded for {s} ({seen[s]} < {MIN_COARSE_DOTS}): is most of its "
                                     "image off the table or blocked?")
    return coarse, seen


async def _lattice(st: State, cam: int, ok: list[str], coarse: dict[str, np.ndarray], seen: dict[str, int]) -> None:
    """Measure an interleaved lattice through the coarse poses; fit and save each projector's pose."""
    ctx, opts = st.ctx, st.opts
    H_t2c = st.setup.table_to_camera[cam]
    H_cam_to_table = np.linalg.inv(H_t2c)
    k_cam = st.cameras.index(cam)
    sizes = {s: st.sizes[s] for s in ok}
    lattice = multiplex.plan_lattice(coarse, H_t2c, sizes=sizes, camera_size=st.setup.sizes[cam],
                                     table_mm=opts.table_mm, rounds=opts.rounds)
    per_slot = int(np.median([sum(len(r.centres[s]) for r in lattice.rounds) for s in ok]))
    if per_slot < LATTICE_DOTS_WANTED and opts.rounds < 16:
        # more projectors than one lattice holds at this camera resolution: add rounds (the only growth with N)
        need = min(16, math.ceil(opts.rounds * LATTICE_DOTS_WANTED / max(per_slot, 1)))
        if need > opts.rounds:
            ctx.log(f"lattice: {per_slot} dots per projector in {opts.rounds} rounds; using {need} rounds")
            lattice = multiplex.plan_lattice(coarse, H_t2c, sizes=sizes, camera_size=st.setup.sizes[cam],
                                             table_mm=opts.table_mm, rounds=need)
    found: dict[str, list[multiplex.DotMatches]] = {s: [] for s in ok}
    start = st.shots
    for r in range(len(lattice.rounds)):
        ctx.progress("lattice", "", r, len(lattice.rounds), f"{count(len(ok), 'projector')} at once")
        cap = (await st.shoot(lattice.frames(r), require=ok))[k_cam]
        ms = await ctx.compute(multiplex.measure_lattice, cap, st.dark[k_cam], lattice, r)
        for s in ok:
            found[s].append(ms[s])
    ctx.progress("lattice", "", len(lattice.rounds), len(lattice.rounds), "fitting")
    H_c2t = content_to_table(st.content_size, opts.table_mm)
    for n, s in enumerate(ok):
        camxy = np.vstack([m.camera for m in found[s]])
        proj = np.vstack([m.projector for m in found[s]])
        if len(camxy) < MIN_LATTICE_DOTS:
            st.failed[s] = (f"too few lattice dots measured for {s} ({len(camxy)} < {MIN_LATTICE_DOTS}): is most of "
                            "its image off the table?")
            ctx.log(st.failed[s])
            continue
        try:
            fit = planar.fit_homography(planar.apply_homography(H_cam_to_table, camxy), proj, threshold=1.0)
        except CalibrationError as exc:
            st.failed[s] = f"{s}: {exc}"
            continue
        pose = planar.normalise(fit.H @ H_c2t)
        doc = slot_doc(st.run, s, opts, rms=fit.rms, mx=fit.max, points=fit.count, coarse_dots=int(seen[s]),
                       captures=st.shots - start)
        save_slot(ctx, s, HomographyPose(pose), doc)
        st.results[s] = doc
        ctx.progress("projectors", s, n + 1, len(ok), f"calibrated, reprojection error {fit.rms:.3f} px", value=fit.rms)


def check_dot_saturation(caps: list[np.ndarray], dec: multiplex.CodedDecode, camera: int, max_saturated: float) -> None:
    found = [m.camera for m in dec.matches.values() if m.count]
    if not found:
        return
    pts = np.vstack(found)
    peak = np.max(np.stack([c.max(axis=2) for c in caps]), axis=0)
    ix = np.clip(np.rint(pts[:, 0]).astype(int), 0, peak.shape[1] - 1)
    iy = np.clip(np.rint(pts[:, 1]).astype(int), 0, peak.shape[0] - 1)
    sat = float(np.mean(peak[iy, ix] >= SATURATED))
    if sat > max(max_saturated, 0.2):
        raise Abort(f"camera {camera} over-exposed ({100 * sat:.0f} % of the dots saturate it): lower the exposure")

