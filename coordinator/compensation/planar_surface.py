"""A table: the :class:`~coordinator.compensation.surface.Surface` of a rig whose projectors all have a
homography pose.

``L`` maps ``content`` pixels to ``camera`` pixels (:mod:`coordinator.compensation.planar_transport`);
the target is the content as the camera would see it on a blur-free rig
(:func:`~imaging.compensation.geometry.camera_target`), scaled to a level the rig reaches inside
the content's inscribed rectangle (:func:`~imaging.compensation.geometry.target_level`). The solve
is ``p' = argmin ||L p - c'||^2 + lam ||p - p0||^2, 0 <= p <= 1``
(:class:`~imaging.compensation.ridge.RidgeProblem`; ``p0`` the uncompensated image, the small ridge
keeps the measured ``L``'s noise out of the result). With the per-projector baseline, the level is
lowered to what the dimmest projector can reach ``N`` times over (the conventional method asks
every projector for ``c'/N``), so its ``L_i`` are measured before the solve. Captures are scored
(PSNR/SSIM) inside the inscribed rectangle.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from coordinator.compensation.jobkit import content_size, rounded, throttled
from coordinator.compensation.memory_check import check_solve
from coordinator.compensation.options import REGULARIZATION, CompensateOptions, TransportOptions
from coordinator.compensation.planar_transport import ensure_baseline, ensure_transport
from coordinator.compensation.store import StoredTransport
from coordinator.compensation.surface import Baselines, Solution, SolveFigures, TransportFigures, nonempty
from coordinator.jobs import JobContext, JobError
from coordinator.jobs.results import Figures
from imaging.compensation.geometry import camera_target, inscribed_region, row_white, target_level
from imaging.compensation.quality import quality
from imaging.compensation.ridge import RidgeProblem, best_scale
from imaging.compensation.solver import SolveResult, solve
from protos.spaces import warp_content

__all__ = ["PlanarSurface", "PlanarSolution", "PlanarScoring"]


@dataclass(frozen=True, kw_only=True)
class PlanarSolution(Solution):
    """A table's solution, with what its baseline and evaluation use: ``content`` (H, W, C) float32, the
    camera-space target ``T`` (Hc, Wc, C) at level 1 and its level ``s``, the scored ``region`` (rows,
    cols) and the baseline's ``L_i`` when they were measured for the level."""

    content: np.ndarray
    T: np.ndarray
    s: float
    target: np.ndarray
    region: tuple[slice, slice]
    base: Baselines | None = None


class PlanarSurface:
    """The table's transport, solve and scoring (see the module docstring)."""

    kind = "table"
    regularization = REGULARIZATION
    shown_note = "shown on every projector and stored as the rig's content"

    def refuse(self, opts: TransportOptions) -> None:
        if opts.camera_indices is not None:
            raise JobError("camera_indices (several cameras measuring L together) is for a mesh rig; a table's L is "
                           "measured with one camera (camera, --camera-index)")

    async def transport(self, ctx: JobContext, opts: TransportOptions, slots: list[str], *,
                        measure: bool = True) -> StoredTransport:
        return await ensure_transport(ctx, opts, slots, measure=measure)

    async def baselines(self, ctx: JobContext, tr: StoredTransport, opts: TransportOptions) -> Baselines:
        return await ensure_baseline(ctx, tr, opts)

    async def transport_figures(self, ctx: JobContext, tr: StoredTransport) -> TransportFigures:
        white = row_white(tr.L, tr.camera_shape)
        rows, cols = inscribed_region(tr.H, content_size(ctx), tr.camera_shape, margin=int(tr.meta["radius"]) + 2)
        region = white[rows, cols]
        return TransportFigures(white={"p2": rounded(float(np.percentile(region, 2)), 5),
                                       "median": rounded(float(np.median(region)), 5),
                                       "max": rounded(float(region.max()), 5)})

    def check_solve(self, tr: StoredTransport, content_size: tuple[int, int], opts: CompensateOptions) -> None:
        # before the solve's operators are built, with the baseline's L_i it will hold beside them
        check_solve(content_size, tr.camera_shape, int(tr.meta["radius"]),
                    baselines=len(tr.slots) if opts.baseline else 0)

    async def solve(self, ctx: JobContext, tr: StoredTransport, content: np.ndarray,
                    opts: CompensateOptions) -> PlanarSolution:
        ch, cw = content.shape[:2]
        T = camera_target(content, tr.H, tr.camera_shape)
        region = inscribed_region(tr.H, (cw, ch), tr.camera_shape, margin=int(tr.meta["radius"]) + 2)
        white = row_white(tr.L, tr.camera_shape)
        s = target_level(white, region, opts.level)
        level_note = "rig white"
        base = None
        if opts.baseline:
            base = nonempty(await self.baselines(ctx, tr, opts))
            # the conventional method asks every projector for c'/N: the target must be within each one's reach
            s_base = opts.level * len(base[0]) * min(target_level(row_white(Li, tr.camera_shape), region, 1.0)
                                                     for Li in base[0].values())
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
        progress = throttled(lambda k, f: ctx.progress("solve", "", k, opts.max_iter, f"objective {f:.4g}", f))
        res = await ctx.compute(solve, problem.op, problem.target(target, none), x0=none, content_shape=(ch, cw),
                                max_iter=opts.max_iter, tol=opts.tol, est_tol=opts.est_tol, method=opts.method,
                                progress=progress)
        ctx.progress("solve", "", res.iterations, res.iterations, f"{res.reason}, objective {res.objective:.4g}",
                     res.objective)
        x = np.clip(res.x, 0, 1).astype(np.float32).reshape(ch, cw, -1)
        data_objective = await ctx.compute(problem.data_objective, x, target)
        initial_objective = await ctx.compute(problem.data_objective, none, target)
        figures = SolveFigures(method=opts.method, iterations=res.iterations, reason=res.reason,
                               converged=res.converged, objective=data_objective, initial_objective=initial_objective,
                               penalised_objective=res.objective, regularization=mu, gap=rounded(res.gap, 6),
                               seconds=round(res.seconds, 3), lipschitz=res.lipschitz)
        return PlanarSolution(
            tr=tr, x=x, none=none, none_scale=round(alpha, 6), seconds=res.seconds, target_level=round(s, 6),
            target_level_from=level_note, solve=figures,
            saturated_fraction={"low": round(float(np.mean(x <= 1e-4)), 5),
                                "high": round(float(np.mean(x >= 1 - 1e-4)), 5)},
            content=content, T=T, s=s, target=target, region=region, base=base)

    async def solution_baselines(self, ctx: JobContext, sol: PlanarSolution, opts: CompensateOptions) -> Baselines:
        # measured while solving, for the target's level (the baseline's projectors must reach it)
        return sol.base if sol.base is not None else nonempty(await self.baselines(ctx, sol.tr, opts))

    async def solve_baselines(self, ctx: JobContext, sol: PlanarSolution, base_L: dict[str, sp.csr_matrix],
                              opts: CompensateOptions) -> tuple[dict[str, np.ndarray], list[SolveResult]]:
        names = sorted(base_L)
        results = await ctx.compute(_solve_baseline, ctx, base_L, names, sol.target, sol.content, opts)
        ch, cw = sol.content.shape[:2]
        xs = {k: np.asarray(r.x, np.float32).reshape(ch, cw, -1) for k, r in zip(names, results)}
        return xs, results

    async def scoring(self, ctx: JobContext, sol: PlanarSolution, opts: CompensateOptions) -> PlanarScoring:
        return PlanarScoring(ctx, sol, opts.eval_frames)


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


class PlanarScoring:
    """A table's evaluation: one camera (the one ``L`` was measured with); captures minus black, divided by
    the target level, scored against the target inside the inscribed rectangle."""

    def __init__(self, ctx: JobContext, sol: PlanarSolution, frames: int) -> None:
        self.ctx, self.sol, self.frames = ctx, sol, frames
        self.camera = int(sol.tr.meta["camera"])

    async def capture(self) -> np.ndarray:
        return await self.ctx.capture(self.camera, frames=self.frames)

    def score(self, capture: np.ndarray, black: np.ndarray) -> tuple[Figures, np.ndarray]:
        sol = self.sol
        seen = (np.asarray(capture, np.float32) - black) / np.float32(sol.s)
        if sol.T.shape[2] == 1:
            seen = seen.mean(axis=2, keepdims=True)
        t, c = sol.T[sol.region], seen[sol.region]
        return quality(t, c).as_dict(), c

    async def baseline_frames(self, base_x: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        frames_by_slot = {}
        for k, x in base_x.items():
            st = self.ctx.rig.slot(k)
            frames_by_slot[k] = await self.ctx.compute(warp_content, x, st.pose.matrix, (st.width, st.height),
                                                       lut=st.lut, gain=st.gain)
        return frames_by_slot

    def predicted(self, x: np.ndarray) -> Figures:
        sol, tr = self.sol, self.sol.tr
        c = (tr.L @ x.reshape(-1, x.shape[2])).reshape(*tr.camera_shape, -1) / np.float32(sol.s)
        return quality(sol.T[sol.region], c[sol.region]).as_dict()

    def tiles(self, tiles: dict[str, np.ndarray], order: list[str]) -> list[np.ndarray]:
        return [self.sol.T[self.sol.region]] + [tiles[k] for k in order]

    def figures(self) -> Figures:
        region = self.sol.region
        return {"region": {"x": [region[1].start, region[1].stop], "y": [region[0].start, region[0].stop]}}
