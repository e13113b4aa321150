"""The ``compensate`` job on a mesh rig: one bounded least-squares solve in texture space.

``p' = argmin ||W^1/2 (L p - c')||^2 + lam ||p - p0||^2, 0 <= p <= 1`` over the texels ``L``
measured (:mod:`coordinator.compensation.mesh_transport`); ``W`` weighs each camera pixel by the
cosine of its viewing angle (:func:`~imaging.compensation.mesh_geometry.row_weights`: per pixel,
as the captures are scored); with several cameras the rows are all
their pixels, each also weighed by its texel's share of that camera
(:mod:`coordinator.compensation.mesh_cameras`). Texels no camera sees (or that
could not be measured) stay uncompensated: they keep ``p0``, the content at the level of the
uncompensated start (``none``), and their count and share are reported.

The target is the content as the camera would see it on the object without blur: sampled at each
camera pixel's uv (:func:`~imaging.compensation.texture_space.content_at_view`) times
``level`` times the rig's white at that pixel (``L 1``). On an object the rig's white changes with
the surface's orientation to the projectors; keeping it (removing the blur, not the shading)
keeps the target within reach everywhere, where a flat target would dim the whole object to its
least lit part. The per-projector baseline asks each projector for its own share of that target,
``c' white_i / white`` (on a table, where every projector lights every point alike, this is the
``c' / N`` of the planar baseline).

Quality is scored over the visible surface (the pixels the solve weighs): captures minus black
and the target, both divided by the target's 99th percentile, PSNR and SSIM over those pixels only
(:func:`~imaging.compensation.mesh_geometry.masked_quality`); with several cameras over all
their pixels together, and per camera. An object can be lit far brighter than the table the camera's
exposure was set on (25 projectors on the bust's crown: 1.9 times the camera's full scale), and a
clipped capture scores the sensor, not the compensation. ``L`` was measured at an exposure that keeps
the rig's white in range (:mod:`imaging.compensation.exposure`), and the evaluation captures at
that one, lowered further if the white on the scored surface still passes :data:`HEADROOM` of full
scale (:func:`evaluation_exposure`; reported, and warned about on a camera that cannot change it).
"""
from __future__ import annotations

import time

import cv2
import numpy as np
import scipy.sparse as sp

from imaging.compensation.errors import CompensationError
from imaging.compensation.exposure import HEADROOM
from imaging.compensation.geometry import row_white
from coordinator.compensation.image_param import prepare_image
from coordinator.compensation.jobkit import (
    baseline_exposure,
    content_size,
    rounded,
    throttled,
)
from coordinator.compensation.memory_check import check_stored
from imaging.compensation.mesh_geometry import masked_quality, measured_texels
from coordinator.compensation.mesh_transport import (
    capture_cameras,
    ensure_mesh_baseline,
    ensure_mesh_transport,
    load_geometry,
    solve_weights,
    stored_cameras,
    texel_summary,
)
from coordinator.compensation.options import CompensateOptions
from imaging.compensation.quality import side_by_side
from imaging.compensation.ridge import RidgeProblem, best_scale
from imaging.compensation.solver import SolveResult, solve
from coordinator.compensation.store import (
    SUBDIR,
    compensation_dir,
    transport_summary,
    write_result,
)
from imaging.compensation.texture_space import content_at_view, mesh_warp
from coordinator.jobs import JobContext, JobError
from protos.store import atomic_write_bytes

__all__ = ["run_mesh_compensate", "WeightedProblem", "weighted_solve", "solve_baseline", "evaluation_exposure"]

#: percentile of the target (over the visible surface) that scores divide by
SCORE_PERCENTILE = 99.0


class WeightedProblem:
    """The solve's rows and columns: camera pixels with a weight, texels with a column in ``L``.

    ``L`` (n_camera, n_content) becomes ``diag(sqrt(w)) L`` restricted to ``rows`` x ``cols``;
    :meth:`rows_of` applies the same to a camera image.
    """

    def __init__(self, weights: np.ndarray, measured: np.ndarray) -> None:
        w = np.asarray(weights, np.float32).ravel()
        self.rows = np.flatnonzero(w > 0)
        self.cols = np.flatnonzero(np.asarray(measured, bool))
        self.sqrt_w = np.sqrt(w[self.rows])

    def matrix(self, L: sp.spmatrix) -> sp.csr_matrix:
        Lr = sp.csr_matrix(L)[self.rows][:, self.cols]
        return sp.csr_matrix(sp.diags(self.sqrt_w) @ Lr, dtype=np.float32)

    def rows_of(self, image: np.ndarray) -> np.ndarray:
        a = np.asarray(image, np.float32)
        a = a.reshape(-1, a.shape[-1]) if a.ndim == 3 else a.reshape(-1, 1)
        return np.ascontiguousarray(a[self.rows] * self.sqrt_w[:, None])


def weighted_solve(wp: WeightedProblem, L: sp.spmatrix, target: np.ndarray, content: np.ndarray,
                   opts: CompensateOptions, progress=None) -> tuple[SolveResult, np.ndarray, np.ndarray, float]:
    """Solve on the measured texels from the content scaled to the target; returns the result, the full image
    (unsolved texels keep the start; the caller pads the chart edges), the start and its scale (runs on a worker thread)."""
    ch, cw, nc = content.shape
    Lw = wp.matrix(L)
    tw = wp.rows_of(target)
    flat = content.reshape(-1, nc)
    alpha = best_scale(Lw @ flat[wp.cols], tw)
    start = np.clip(content * np.float32(alpha), 0, 1).astype(np.float32)
    x0 = np.ascontiguousarray(start.reshape(-1, nc)[wp.cols])
    problem = RidgeProblem(Lw, opts.regularization)
    res = solve(problem.op, problem.target(tw, x0), x0=x0, max_iter=opts.max_iter, tol=opts.tol, est_tol=opts.est_tol,
                method=opts.method, progress=progress)
    x = start.reshape(-1, nc).copy()
    x[wp.cols] = np.clip(res.x.reshape(-1, nc), 0, 1)
    return res, x.reshape(ch, cw, nc), start, alpha


async def run_mesh_compensate(ctx: JobContext, opts: CompensateOptions, slots: list[str], image: np.ndarray,
                              name: str, t0: float, *, shown_as: str) -> dict:
    """The ``compensate`` job's solve, evaluation and result on a mesh rig (see the module docstring); with
    ``persist`` the result is shown as the rig's content named ``shown_as``."""
    if opts.baseline:
        baseline_exposure(ctx, opts)  # refused before any capture
    tr, cams = await ensure_mesh_transport(ctx, opts, slots, measure=opts.measure)
    # the weighted ridge problem, with the baseline's L_i it will hold beside it
    check_stored(tr.L, what="the compensation solve" + (f" with {len(tr.slots)} per-projector baselines"
                                                        if opts.baseline else ""),
                 baselines=len(tr.slots) if opts.baseline else 0)
    cw, ch = content_size(ctx)
    content = prepare_image(image, (cw, ch), srgb=opts.srgb)
    measured = measured_texels(tr.L)
    try:
        w = await ctx.compute(solve_weights, cams, tr)
    except CompensationError as exc:
        raise JobError(str(exc)) from exc
    region = w > 0
    white = row_white(tr.L, tr.camera_shape)
    T = content_at_view(content, cams.view)
    target = np.ascontiguousarray(np.float32(opts.level) * white[:, :, None] * T)
    wp = WeightedProblem(w, measured)
    ctx.progress("solve", "", 0, opts.max_iter, "objective")
    progress = throttled(lambda k, f: ctx.progress("solve", "", k, opts.max_iter, "objective", f))
    res, x, none, alpha = await ctx.compute(weighted_solve, wp, tr.L, target, content, opts, progress)
    x, none = cams.pad(x), cams.pad(none)        # the chart edges the nodes sample, as the dots were shown
    ctx.progress("solve", "", res.iterations, res.iterations, res.reason, res.objective)
    solved = np.zeros(cw * ch, bool)
    solved[wp.cols[np.diff(sp.csc_matrix(wp.matrix(tr.L)).indptr) > 0]] = True
    tex = texel_summary(tr, cams)
    on = int(tex["on_mesh"])
    result = {
        "image": name, "surface": "mesh", "content_size": [cw, ch], "channels": int(x.shape[2]),
        "target_level": opts.level, "target_level_from": "the rig's white at each camera pixel (the surface's shading "
                                                          "kept)",
        "level": opts.level, "none_scale": round(alpha, 6),
        "solve": {"method": opts.method, "iterations": res.iterations, "reason": res.reason,
                  "converged": res.converged, "penalised_objective": res.objective, "regularization": opts.regularization,
                  "gap": rounded(res.gap, 6), "seconds": round(res.seconds, 3), "lipschitz": res.lipschitz,
                  "rows": int(len(wp.rows)), "columns": int(len(wp.cols))},
        "transport": transport_summary(tr),
        "texture": {**tex, "compensated": int(solved.sum()), "uncompensated": on - int(solved[cams.on_mesh].sum()),
                    "uncompensated_share": rounded(1 - solved[cams.on_mesh].sum() / on if on else 1.0, 4),
                    "note": "texels no camera sees well stay uncompensated (the content at the none level)"},
        "weights": "cos(viewing angle) per camera pixel (x its texel's share of the camera, with several), "
                   "median 1; 0 off the visible surface",
        "saturated_fraction": {"low": round(float(np.mean(x[solved.reshape(ch, cw)] <= 1e-4)), 5),
                               "high": round(float(np.mean(x[solved.reshape(ch, cw)] >= 1 - 1e-4)), 5)},
    }
    base_x = None
    if opts.baseline:
        base_L, base_summary = await ensure_mesh_baseline(ctx, tr, opts)
        if not base_L:
            raise JobError("baseline: no projector adds light to the camera image")
        t_b = time.monotonic()
        base_x, results = await ctx.compute(
            solve_baseline, base_L, wp, white, target, content, opts,
            lambda k, i, n, res: ctx.progress("baseline solve", k, i, n, f"{res.iterations} iterations"))
        base_x = {k: cams.pad(v) for k, v in base_x.items()}
        result["baseline"] = {**base_summary, "solve_seconds": round(time.monotonic() - t_b, 3),
                              "iterations": sum(r.iterations for r in results),
                              "solve_seconds_sum": round(sum(r.seconds for r in results), 3)}
        result["baseline_over_ours_seconds"] = round(result["baseline"]["solve_seconds_sum"] / max(res.seconds, 1e-9), 2)
    if opts.evaluate:
        result["quality"] = await _evaluate(ctx, tr, cams, none, x, base_x, target, region, opts, name, white)
    result["wall_s"] = round(time.monotonic() - t0, 3)
    write_result(ctx.rig, "result.json", result)
    if opts.persist:
        ctx.show_still(np.ascontiguousarray(x), name=shown_as, persist=True)
        result["content"] = "shown on every projector (the mesh's texture) and stored as the rig's content"
    return result


def solve_baseline(base_L: dict[str, sp.csr_matrix], wp: WeightedProblem, white: np.ndarray, target: np.ndarray,
                   content: np.ndarray, opts: CompensateOptions, done=None
                   ) -> tuple[dict[str, np.ndarray], list[SolveResult]]:
    """The conventional method: each projector's own weighted ridge problem for its share of the target
    (``c' white_i / white``), from its own uncompensated start (runs on a worker thread). ``done(slot, k, n,
    result)``, if given, after each projector's solve."""
    xs, results = {}, []
    names = sorted(base_L)
    with np.errstate(divide="ignore", invalid="ignore"):
        for i, k in enumerate(names):
            share = np.where(white > 0, row_white(base_L[k], white.shape) / white, 0).astype(np.float32)
            res, x, _, _ = weighted_solve(wp, base_L[k], target * share[:, :, None], content, opts)
            xs[k] = x
            results.append(res)
            if done is not None:
                done(k, i + 1, len(names), res)
    return xs, results


def evaluation_exposure(white: np.ndarray, black: np.ndarray, region: np.ndarray) -> tuple[float, float]:
    """``(exposure, peak)``: the relative exposure (at most 1) at which black plus the rig's white stays within
    :data:`HEADROOM` of full scale (1.0) over ``region``, and that peak, both relative to the exposure ``L``
    and ``black`` were captured at.

    ``white``: (Hc, Wc) the rig's white (``L 1``, camera units above black); ``black``: (Hc, Wc[, C]) the
    black capture; ``region``: (Hc, Wc) bool, the scored pixels.
    """
    b = np.asarray(black, np.float32)
    b = b.max(axis=2) if b.ndim == 3 else b
    if not region.any():
        return 1.0, 0.0
    peak = float(np.max((white + b)[region]))
    return (min(1.0, HEADROOM / peak) if peak > 0 else 1.0), peak


def _scores(goal: np.ndarray, captured: np.ndarray, region: np.ndarray, cameras: int) -> dict:
    """:func:`masked_quality` over the visible surface of the stacked image; with several cameras also each
    camera's own (``per_camera``, in their order), where it sees any of it."""
    out = masked_quality(goal, captured, region)
    if cameras > 1:
        h = region.shape[0] // cameras
        out["per_camera"] = [masked_quality(goal[k * h:(k + 1) * h], captured[k * h:(k + 1) * h],
                                            region[k * h:(k + 1) * h]) if region[k * h:(k + 1) * h].any() else None
                             for k in range(cameras)]
    return out


async def _evaluate(ctx: JobContext, tr, cams, none: np.ndarray, ours: np.ndarray,
                    base_x: dict[str, np.ndarray] | None, target: np.ndarray, region: np.ndarray,
                    opts: CompensateOptions, name: str, white: np.ndarray) -> dict:
    """Capture none / baseline / ours; PSNR, SSIM over the visible surface and the side-by-side picture."""
    rig = ctx.rig
    cameras = stored_cameras(tr)
    frames = opts.eval_frames
    base = float(tr.meta.get("exposure", 1.0))          # L's captures were taken at this exposure
    f, peak = evaluation_exposure(white, tr.black, region)
    if f < 1.0 and not all(ctx.supports_exposure(c) for c in cameras):
        ctx.log(f"warning: the rig's white reaches {peak:.2f} of the camera's full scale on the scored surface: its "
                "captures clip there and cap the scores; lower the camera's exposure (or --level)")
        f = 1.0
    elif f < 1.0:
        ctx.log(f"the rig's white reaches {peak:.2f} of the camera's full scale on the scored surface: evaluating at "
                f"{f:.3f} times the exposure L was measured at")
    exposure = base * f
    shot = {"exposure": exposure} if exposure < 1.0 else {}
    steps = 3 if base_x else 2
    ref = float(np.percentile(target[region], SCORE_PERCENTILE))
    if ref <= 0:
        raise JobError("the rig adds no light to the visible surface: check the light-transport measurement")
    goal = target / np.float32(ref)

    async def seen(image: np.ndarray) -> np.ndarray:
        await ctx.show_content(image, settle_s=opts.settle_s)
        return await capture_cameras(ctx, cameras, frames=frames, **shot)

    def score(capture: np.ndarray) -> tuple[dict, np.ndarray]:
        c = (np.asarray(capture, np.float32) - black) / np.float32(ref * f)
        if goal.shape[2] == 1:
            c = c.mean(axis=2, keepdims=True)
        return _scores(goal, c, region, len(cameras)), c

    ctx.progress("evaluate", "", 0, steps, "without compensation")
    black = await seen(np.zeros(none.shape[:2], np.float32))
    scores: dict[str, dict] = {}
    tiles: dict[str, np.ndarray] = {}
    scores["none"], tiles["none"] = score(await seen(none))
    if base_x is not None:
        ctx.progress("evaluate", "", 1, steps, "baseline")
        views = (await load_geometry(ctx, sorted(base_x), cameras, projectors=True)).projectors
        frames_by_slot = {}
        for k, x in base_x.items():
            st = rig.slot(k)
            frames_by_slot[k] = await ctx.compute(mesh_warp, x, views[k], lut=st.lut, gain=st.gain)
        await ctx.show(frames_by_slot, settle_s=opts.settle_s, require=list(frames_by_slot))
        scores["baseline"], tiles["baseline"] = score(await capture_cameras(ctx, cameras, frames=frames, **shot))
    ctx.progress("evaluate", "", steps - 1, steps, "ours")
    scores["ours"], tiles["ours"] = score(await seen(ours))
    ctx.progress("evaluate", "", steps, steps, "scored")

    def predicted(x: np.ndarray) -> dict:
        c = (tr.L @ x.reshape(-1, x.shape[2])).reshape(*tr.camera_shape, -1) / np.float32(ref)
        return _scores(goal, c, region, len(cameras))

    ys, xs = np.nonzero(region)
    box = (slice(max(ys.min() - 4, 0), ys.max() + 5), slice(max(xs.min() - 4, 0), xs.max() + 5))
    order = ["none"] + (["baseline"] if base_x is not None else []) + ["ours"]
    inside = region[box][:, :, None]
    images = [np.where(inside, goal[box], 0)] + [np.where(inside, np.clip(tiles[k][box], 0, 1), 0) for k in order]
    labels = ["target"] + [f"{k} {scores[k]['psnr']:.2f} dB / {scores[k]['ssim']:.3f}" for k in order]
    pic = side_by_side(images, labels)
    ok, png = cv2.imencode(".png", cv2.cvtColor(pic, cv2.COLOR_RGB2BGR))
    if not ok:
        raise JobError("could not encode the side-by-side picture")
    atomic_write_bytes(compensation_dir(rig) / "quality.png", png.tobytes())
    out = {**scores, "predicted": {"none": await ctx.compute(predicted, none), "ours": await ctx.compute(predicted, ours)},
           "region": {"visible_surface_pixels": int(region.sum()), "of_mesh_pixels": int(cams.view.on_mesh.sum()),
                      "score_reference": round(ref, 6)},
           "exposure": round(exposure, 4), "transport_exposure": round(base, 4),
           "white_peak_of_full_scale": round(peak, 4),
           "captures_averaged": frames, "picture": f"{SUBDIR}/quality.png", "image": name}
    out["ordering"] = {
        "ours_minus_none_db": round(scores["ours"]["psnr"] - scores["none"]["psnr"], 3),
        **({"ours_minus_baseline_db": round(scores["ours"]["psnr"] - scores["baseline"]["psnr"], 3),
            "baseline_minus_none_db": round(scores["baseline"]["psnr"] - scores["none"]["psnr"], 3)}
           if base_x is not None else {}),
    }
    write_result(rig, "quality.json", out)
    return out
