"""The ``compensate`` job: one bounded least-squares solve for an image, stored and shown.

``p' = argmin ||L p - c'||^2 + lam ||p - p0||^2, 0 <= p <= 1``
(:class:`~imaging.compensation.ridge.RidgeProblem`; ``p0`` the uncompensated image, the
small ridge keeps the measured ``L``'s noise out of the result) over the stored light
transport (measured first when none is valid, :func:`~.transport_job.ensure_transport`). The
result becomes the rig's content (float32) and is shown on every node. With ``evaluate``, the
result without compensation, with ours and (``baseline``) with the per-projector method are
captured and scored against the target (PSNR/SSIM) and put side by side in
``compensation/quality.png``.

On a mesh rig the content is the mesh's texture and the solve runs in texture space, weighted
by how well the camera sees each part of the surface: :mod:`coordinator.compensation.mesh_compensate`.

Spaces: ``L`` maps ``content`` pixels to ``camera`` pixels; the target is the content as the
camera would see it on a blur-free rig
(:func:`~imaging.compensation.geometry.camera_target`), scaled to a level the rig reaches.
"""
from __future__ import annotations

import time
from dataclasses import replace

import cv2
import numpy as np
import scipy.sparse as sp

from imaging.compensation.errors import CompensationError
from imaging.compensation.geometry import (
    camera_target,
    inscribed_region,
    row_white,
    target_level,
)
from coordinator.compensation.image_param import load_image_param, prepare_image
from coordinator.compensation.jobkit import content_size, rounded, surface_of, throttled
from coordinator.compensation.memory_check import check_solve
from coordinator.compensation.mesh_compensate import run_mesh_compensate
from coordinator.compensation.options import MESH_REGULARIZATION, REGULARIZATION, CompensateOptions
from imaging.compensation.quality import quality, side_by_side
from imaging.compensation.ridge import RidgeProblem, best_scale
from imaging.compensation.solver import SolveResult, solve
from coordinator.compensation.store import (
    SUBDIR,
    StoredTransport,
    compensation_dir,
    transport_summary,
    write_result,
)
from coordinator.compensation.transport_job import (
    baseline_exposure,
    ensure_baseline,
    ensure_transport,
)
from coordinator.jobs import JobContext, JobError
from protos.store import atomic_write_bytes
from protos.spaces import warp_content

__all__ = ["OPTIONS", "run"]

OPTIONS = CompensateOptions


#: the name a compensated image is shown under (see :func:`run`)
COMPENSATED_PREFIX = "compensated "


def shown_content(ctx: JobContext) -> tuple[np.ndarray, str]:
    """The image the rig shows (``(H, W, C)``, its dtype), for a job given no image: what an operator
    shows from the console is what they compensate next. Not an already compensated one."""
    content = ctx.rig.content
    if content is None:
        raise CompensationError("give an image (the `image` parameter or `image_path`), or show one first: "
                                "with no image the rig's content is compensated, and the rig has none")
    if content.name.startswith(COMPENSATED_PREFIX):
        raise CompensationError(f"the rig shows {content.name!r}, already compensated: show the original again "
                                "first, or give the image")
    return content.image, content.name or content.content_id[:12]


async def run(ctx: JobContext, opts: CompensateOptions) -> dict:
    """Solve for the image, store the figures; with ``persist`` show the result as the rig's content."""
    t0 = time.monotonic()
    try:
        if opts.image is None and not opts.image_path:
            image, name = shown_content(ctx)
        else:
            image, name = load_image_param(opts.image, opts.image_path)
    except CompensationError as exc:
        raise JobError(str(exc)) from exc
    slots = ctx.select_slots(opts.slots, need_pose=True)
    mesh = surface_of(ctx, slots) == "mesh"
    if opts.regularization is None:
        opts = replace(opts, regularization=MESH_REGULARIZATION if mesh else REGULARIZATION)
    if mesh:
        return await run_mesh_compensate(ctx, opts, slots, image, name, t0, shown_as=f"{COMPENSATED_PREFIX}{name}")
    if opts.camera_indices is not None:
        raise JobError("camera_indices (several cameras measuring L together) is for a mesh rig; a table's L is "
                       "measured with one camera (camera, --camera-index)")
    if opts.baseline:
        baseline_exposure(ctx, opts)  # refused before any capture
    tr = await ensure_transport(ctx, opts, slots, measure=opts.measure)
    cw, ch = content_size(ctx)
    # before the solve's operators are built, with the baseline's L_i it will hold beside them
    check_solve((cw, ch), tr.camera_shape, int(tr.meta["radius"]), baselines=len(tr.slots) if opts.baseline else 0)
    content = prepare_image(image, (cw, ch), srgb=opts.srgb)
    T = camera_target(content, tr.H, tr.camera_shape)
    region = inscribed_region(tr.H, (cw, ch), tr.camera_shape, margin=int(tr.meta["radius"]) + 2)
    white = row_white(tr.L, tr.camera_shape)
    s = target_level(white, region, opts.level)
    level_note = "rig white"
    base_L: dict[str, sp.csr_matrix] = {}
    base_summary = None
    if opts.baseline:
        base_L, base_summary = await ensure_baseline(ctx, tr, opts)
        if not base_L:
            raise JobError("baseline: no projector adds light to the camera image")
        # the conventional method asks every projector for c'/N: the target must be within each one's reach
        s_base = opts.level * len(base_L) * min(target_level(row_white(Li, tr.camera_shape), region, 1.0)
                                                for Li in base_L.values())
        if s_base < s:
            s, level_note = s_base, "dimmest projector's share x N (so the baseline can reach it)"
    if s <= 0:
        raise JobError("the rig adds no light inside the content area: check the light-transport measurement")
    target = np.ascontiguousarray(T * np.float32(s))
    mu = opts.regularization
    problem = await ctx.compute(RidgeProblem, tr.L, mu)
    flat = content.reshape(-1, content.shape[2])
    alpha = best_scale(await ctx.compute(problem.data.matvec, flat), target.reshape(-1, target.shape[2]))
    none = np.clip(content * np.float32(alpha), 0, 1).astype(np.float32)
    ctx.progress("solve", "", 0, opts.max_iter, "objective")
    progress = throttled(lambda k, f: ctx.progress("solve", "", k, opts.max_iter, "objective", f))
    res = await ctx.compute(solve, problem.op, problem.target(target, none), x0=none, content_shape=(ch, cw),
                            max_iter=opts.max_iter, tol=opts.tol, est_tol=opts.est_tol, method=opts.method,
                            progress=progress)
    ctx.progress("solve", "", res.iterations, res.iterations, res.reason, res.objective)
    x = np.clip(res.x, 0, 1).astype(np.float32).reshape(ch, cw, -1)
    data_objective = await ctx.compute(problem.data_objective, x, target)
    initial_objective = await ctx.compute(problem.data_objective, none, target)
    result = {
        "image": name, "content_size": [cw, ch], "channels": int(x.shape[2]), "target_level": round(s, 6),
        "target_level_from": level_note, "level": opts.level, "none_scale": round(alpha, 6),
        "solve": {"method": opts.method, "iterations": res.iterations, "reason": res.reason,
                  "converged": res.converged, "objective": data_objective, "initial_objective": initial_objective,
                  "penalised_objective": res.objective, "regularization": mu, "gap": rounded(res.gap, 6),
                  "seconds": round(res.seconds, 3), "lipschitz": res.lipschitz},
        "transport": transport_summary(tr),
        "saturated_fraction": {"low": round(float(np.mean(x <= 1e-4)), 5),
                               "high": round(float(np.mean(x >= 1 - 1e-4)), 5)},
    }
    base_res = None
    if opts.baseline:
        names = sorted(base_L)
        t_b = time.monotonic()
        results = await ctx.compute(_solve_baseline, ctx, base_L, names, target, content, opts)
        base_res = dict(zip(names, results))
        result["baseline"] = {**(base_summary or {}), "solve_seconds": round(time.monotonic() - t_b, 3),
                              "iterations": sum(r.iterations for r in results),
                              "solve_seconds_sum": round(sum(r.seconds for r in results), 3)}
        result["baseline_over_ours_seconds"] = round(result["baseline"]["solve_seconds_sum"] / max(res.seconds, 1e-9), 2)
    if opts.evaluate:
        result["quality"] = await _evaluate(ctx, tr, content, none, x, base_res, T, s, region, opts, name)
    result["wall_s"] = round(time.monotonic() - t0, 3)
    write_result(ctx.rig, "result.json", result)
    if opts.persist:
        ctx.show_still(np.ascontiguousarray(x), name=f"{COMPENSATED_PREFIX}{name}", persist=True)
        result["content"] = "shown on every projector and stored as the rig's content"
    return result


def _solve_baseline(ctx: JobContext, base_L: dict[str, sp.csr_matrix], names: list[str], target: np.ndarray,
                    content: np.ndarray, opts: CompensateOptions) -> list[SolveResult]:
    """The conventional method, as ours: each projector's own ridge problem for ``c'/N``, from its own
    uncompensated start (runs on a worker thread)."""
    ch, cw = content.shape[:2]
    share = target / np.float32(len(names))
    flat = content.reshape(-1, content.shape[2])
    out = []
    for i, k in enumerate(names):
        p = RidgeProblem(base_L[k], opts.regularization)
        a = best_scale(p.data.matvec(flat), share.reshape(-1, share.shape[2]))
        start = np.clip(content * np.float32(a), 0, 1)
        out.append(solve(p.op, p.target(share, start), x0=start, content_shape=(ch, cw), max_iter=opts.max_iter,
                         tol=opts.tol, est_tol=opts.est_tol, method=opts.method))
        ctx.progress("baseline solve", k, i + 1, len(names), f"{out[-1].iterations} iterations")
    return out


def _score(target: np.ndarray, capture: np.ndarray, black: np.ndarray, s: float,
           region: tuple[slice, slice]) -> tuple[dict, np.ndarray]:
    """PSNR/SSIM of a capture (black removed, divided by the target level) against the target, in ``region``."""
    seen = (np.asarray(capture, np.float32) - black) / np.float32(s)
    if target.shape[2] == 1:
        seen = seen.mean(axis=2, keepdims=True)
    t, c = target[region], seen[region]
    return quality(t, c).as_dict(), c


async def _evaluate(ctx: JobContext, tr: StoredTransport, content: np.ndarray, none: np.ndarray, ours: np.ndarray,
                    base_res: dict[str, SolveResult] | None, T: np.ndarray, s: float, region: tuple[slice, slice],
                    opts: CompensateOptions, name: str) -> dict:
    """Capture none / baseline / ours; PSNR, SSIM and the side-by-side picture."""
    rig = ctx.rig
    camera = int(tr.meta["camera"])
    frames = opts.eval_frames
    steps = 3 if base_res else 2

    async def seen(image: np.ndarray) -> np.ndarray:
        await ctx.show_content(image, settle_s=opts.settle_s)
        return await ctx.capture(camera, frames=frames)

    ctx.progress("evaluate", "", 0, steps, "without compensation")
    black = await seen(np.zeros(content.shape[:2], np.float32))
    scores: dict[str, dict] = {}
    tiles: dict[str, np.ndarray] = {}
    scores["none"], tiles["none"] = _score(T, await seen(none), black, s, region)
    if base_res is not None:
        ctx.progress("evaluate", "", 1, steps, "baseline")
        frames_by_slot = {}
        for k, r in base_res.items():
            st = rig.slot(k)
            x = np.asarray(r.x, np.float32).reshape(content.shape[0], content.shape[1], -1)
            frames_by_slot[k] = await ctx.compute(warp_content, x, st.pose.matrix, (st.width, st.height), lut=st.lut,
                                                  gain=st.gain)
        await ctx.show(frames_by_slot, settle_s=opts.settle_s, require=list(frames_by_slot))
        scores["baseline"], tiles["baseline"] = _score(T, await ctx.capture(camera, frames=frames), black, s, region)
    ctx.progress("evaluate", "", steps - 1, steps, "ours")
    scores["ours"], tiles["ours"] = _score(T, await seen(ours), black, s, region)
    ctx.progress("evaluate", "", steps, steps, "scored")

    # predictions through the measured L (what the solver believed), for comparison with the captures
    def predicted(x: np.ndarray) -> dict:
        c = (tr.L @ x.reshape(-1, x.shape[2])).reshape(*tr.camera_shape, -1) / np.float32(s)
        return quality(T[region], c[region]).as_dict()

    order = ["none"] + (["baseline"] if base_res else []) + ["ours"]
    images = [T[region]] + [tiles[k] for k in order]
    labels = ["target"] + [f"{k} {scores[k]['psnr']:.2f} dB / {scores[k]['ssim']:.3f}" for k in order]
    pic = side_by_side(images, labels)
    ok, png = cv2.imencode(".png", cv2.cvtColor(pic, cv2.COLOR_RGB2BGR))
    if not ok:
        raise JobError("could not encode the side-by-side picture")
    atomic_write_bytes(compensation_dir(rig) / "quality.png", png.tobytes())
    out = {**scores, "predicted": {"none": await ctx.compute(predicted, none), "ours": await ctx.compute(predicted, ours)},
           "region": {"x": [region[1].start, region[1].stop], "y": [region[0].start, region[0].stop]},
           "captures_averaged": frames, "picture": f"{SUBDIR}/quality.png", "image": name}
    out["ordering"] = {
        "ours_minus_none_db": round(scores["ours"]["psnr"] - scores["none"]["psnr"], 3),
        **({"ours_minus_baseline_db": round(scores["ours"]["psnr"] - scores["baseline"]["psnr"], 3),
            "baseline_minus_none_db": round(scores["baseline"]["psnr"] - scores["none"]["psnr"], 3)} if base_res else {}),
    }
    write_result(rig, "quality.json", out)
    return out
