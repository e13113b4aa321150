"""The compensation solve on a mesh rig: one bounded least-squares solve in texture space.

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

This module holds the numerics (the weighted problem, the baseline's solves, the evaluation's exposure
and scores); :class:`~coordinator.compensation.mesh_surface.MeshSurface` runs them in the jobs.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from coordinator.compensation.options import CompensateOptions
from imaging.compensation.exposure import HEADROOM
from imaging.compensation.geometry import row_white
from imaging.compensation.mesh_geometry import masked_quality
from imaging.compensation.ridge import RidgeProblem, best_scale
from imaging.compensation.solver import SolveResult, solve

__all__ = ["WeightedProblem", "weighted_solve", "solve_baseline", "evaluation_exposure", "stacked_scores",
           "SCORE_PERCENTILE"]

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


def stacked_scores(goal: np.ndarray, captured: np.ndarray, region: np.ndarray, cameras: int) -> dict:
    """:func:`masked_quality` over the visible surface of the stacked image; with several cameras also each
    camera's own (``per_camera``, in their order), where it sees any of it."""
    out = masked_quality(goal, captured, region)
    if cameras > 1:
        h = region.shape[0] // cameras
        out["per_camera"] = [masked_quality(goal[k * h:(k + 1) * h], captured[k * h:(k + 1) * h],
                                            region[k * h:(k + 1) * h]) if region[k * h:(k + 1) * h].any() else None
                             for k in range(cameras)]
    return out
