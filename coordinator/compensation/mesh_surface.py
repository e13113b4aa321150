"""An object: the :class:`~coordinator.compensation.surface.Surface` of a rig whose projectors all have a
3x4 pose onto a mesh.

The content is the mesh's texture. ``L`` maps texels to camera pixels, measured by one or several
cameras together (:mod:`coordinator.compensation.mesh_transport`); the target is the content seen at
each camera pixel's uv times ``level`` times the rig's white there, and the solve weighs each camera
pixel by how well it sees the surface (:mod:`coordinator.compensation.mesh_compensate`, where the
reasons are). Texels no camera sees stay uncompensated and are counted. The per-projector baseline's
``L_i`` are measured after the solve (its level does not depend on them). Captures are scored over
the visible surface, at an exposure that keeps the rig's white inside the camera's range.

A :class:`MeshSurface` serves one job: it keeps the rig's geometry in its cameras
(:class:`~coordinator.compensation.mesh_rig.MeshCameras`) from the transport on.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from coordinator.compensation.jobkit import rounded, throttled
from coordinator.compensation.memory_check import check_stored
from coordinator.compensation.mesh_compensate import (
    SCORE_PERCENTILE,
    WeightedProblem,
    evaluation_exposure,
    solve_baseline,
    stacked_scores,
    weighted_solve,
)
from coordinator.compensation.mesh_rig import MeshCameras
from coordinator.compensation.mesh_transport import (
    capture_cameras,
    ensure_mesh_baseline,
    ensure_mesh_transport,
    load_geometry,
    solve_weights,
    stored_cameras,
    texel_summary,
)
from coordinator.compensation.options import MESH_REGULARIZATION, CompensateOptions, TransportOptions
from coordinator.compensation.store import StoredTransport
from coordinator.compensation.surface import Baselines, Solution, SolveFigures, TransportFigures, nonempty
from coordinator.jobs import JobContext, JobError
from coordinator.jobs.results import Figures
from imaging.compensation.errors import CompensationError
from imaging.compensation.geometry import row_white
from imaging.compensation.mesh_geometry import measured_texels
from imaging.compensation.quality_figure import packed_views
from imaging.compensation.solver import SolveResult
from imaging.compensation.texture_space import content_at_view, mesh_warp

__all__ = ["MeshSurface", "MeshSolution", "MeshScoring"]


@dataclass(frozen=True, kw_only=True)
class MeshSolution(Solution):
    """A mesh's solution, with what its baseline and evaluation use: the geometry ``cams``, the weighted
    problem ``wp``, the content (H, W, C) float32, the rig's white (K Hc, Wc) and the target
    (K Hc, Wc, C) in camera units, and the scored ``region`` (K Hc, Wc) bool."""

    cams: MeshCameras
    wp: WeightedProblem
    content: np.ndarray
    white: np.ndarray
    target: np.ndarray
    region: np.ndarray


class MeshSurface:
    """The mesh's transport, solve and scoring (see the module docstring)."""

    kind = "mesh"
    regularization = MESH_REGULARIZATION
    shown_note = "shown on every projector (the mesh's texture) and stored as the rig's content"

    def __init__(self) -> None:
        self.cams: MeshCameras | None = None

    def refuse(self, opts: TransportOptions) -> None:
        pass        # one camera or several: both measure a mesh

    async def transport(self, ctx: JobContext, opts: TransportOptions, slots: list[str], *,
                        measure: bool = True) -> StoredTransport:
        tr, self.cams = await ensure_mesh_transport(ctx, opts, slots, measure=measure)
        return tr

    async def baselines(self, ctx: JobContext, tr: StoredTransport, opts: TransportOptions) -> Baselines:
        return await ensure_mesh_baseline(ctx, tr, opts)

    async def _weights(self, ctx: JobContext, tr: StoredTransport) -> np.ndarray:
        try:
            return await ctx.compute(solve_weights, self.cams, tr)
        except CompensationError as exc:
            raise JobError(str(exc)) from exc

    async def transport_figures(self, ctx: JobContext, tr: StoredTransport) -> TransportFigures:
        white = row_white(tr.L, tr.camera_shape)
        region = await self._weights(ctx, tr)
        vals = white[region > 0]
        return TransportFigures(surface=self.kind, texture=texel_summary(tr, self.cams),
                                white={"p2": rounded(float(np.percentile(vals, 2)), 5),
                                       "median": rounded(float(np.median(vals)), 5),
                                       "max": rounded(float(vals.max()), 5)},
                                visible_surface_pixels=int(np.count_nonzero(region)))

    def check_solve(self, tr: StoredTransport, content_size: tuple[int, int], opts: CompensateOptions) -> None:
        # the weighted ridge problem, with the baseline's L_i it will hold beside it
        check_stored(tr.L, what="the compensation solve" + (f" with {len(tr.slots)} per-projector baselines"
                                                            if opts.baseline else ""),
                     baselines=len(tr.slots) if opts.baseline else 0)

    async def solve(self, ctx: JobContext, tr: StoredTransport, content: np.ndarray,
                    opts: CompensateOptions) -> MeshSolution:
        cams = self.cams
        ch, cw = content.shape[:2]
        measured = measured_texels(tr.L)
        w = await self._weights(ctx, tr)
        region = w > 0
        white = row_white(tr.L, tr.camera_shape)
        T = content_at_view(content, cams.view)
        target = np.ascontiguousarray(np.float32(opts.level) * white[:, :, None] * T)
        wp = WeightedProblem(w, measured)
        ctx.progress("solve", "", 0, opts.max_iter, "objective")
        progress = throttled(lambda k, f: ctx.progress("solve", "", k, opts.max_iter, f"objective {f:.4g}", f))
        res, x, none, alpha = await ctx.compute(weighted_solve, wp, tr.L, target, content, opts, progress)
        x, none = cams.pad(x), cams.pad(none)        # the chart edges the nodes sample, as the dots were shown
        ctx.progress("solve", "", res.iterations, res.iterations, f"{res.reason}, objective {res.objective:.4g}",
                     res.objective)
        solved = np.zeros(cw * ch, bool)
        solved[wp.cols[np.diff(sp.csc_matrix(wp.matrix(tr.L)).indptr) > 0]] = True
        tex = texel_summary(tr, cams)
        on = int(tex["on_mesh"])
        figures = SolveFigures(method=opts.method, iterations=res.iterations, reason=res.reason,
                               converged=res.converged, penalised_objective=res.objective,
                               regularization=opts.regularization, gap=rounded(res.gap, 6),
                               seconds=round(res.seconds, 3), lipschitz=res.lipschitz, rows=int(len(wp.rows)),
                               columns=int(len(wp.cols)))
        return MeshSolution(
            tr=tr, x=x, none=none, none_scale=round(alpha, 6), seconds=res.seconds, target_level=opts.level,
            target_level_from="the rig's white at each camera pixel (the surface's shading kept)", solve=figures,
            texture={**tex, "compensated": int(solved.sum()), "uncompensated": on - int(solved[cams.on_mesh].sum()),
                     "uncompensated_share": rounded(1 - solved[cams.on_mesh].sum() / on if on else 1.0, 4),
                     "note": "texels no camera sees well stay uncompensated (the content at the none level)"},
            weights="cos(viewing angle) per camera pixel (x its texel's share of the camera, with several), "
                    "median 1; 0 off the visible surface",
            saturated_fraction={"low": round(float(np.mean(x[solved.reshape(ch, cw)] <= 1e-4)), 5),
                                "high": round(float(np.mean(x[solved.reshape(ch, cw)] >= 1 - 1e-4)), 5)},
            cams=cams, wp=wp, content=content, white=white, target=target, region=region)

    async def solution_baselines(self, ctx: JobContext, sol: MeshSolution, opts: CompensateOptions) -> Baselines:
        return nonempty(await self.baselines(ctx, sol.tr, opts))

    async def solve_baselines(self, ctx: JobContext, sol: MeshSolution, base_L: dict[str, sp.csr_matrix],
                              opts: CompensateOptions) -> tuple[dict[str, np.ndarray], list[SolveResult]]:
        base_x, results = await ctx.compute(
            solve_baseline, base_L, sol.wp, sol.white, sol.target, sol.content, opts,
            lambda k, i, n, res: ctx.progress("baseline solve", k, i, n, f"{res.iterations} iterations"))
        return {k: sol.cams.pad(v) for k, v in base_x.items()}, results

    async def scoring(self, ctx: JobContext, sol: MeshSolution, opts: CompensateOptions) -> MeshScoring:
        return MeshScoring(ctx, sol, opts.eval_frames)


class MeshScoring:
    """A mesh's evaluation: the cameras ``L`` was measured with, stacked, at an exposure that keeps the rig's
    white on the scored surface within the cameras' range; captures minus black and the target, both divided
    by the target's :data:`SCORE_PERCENTILE` percentile, scored over the visible surface."""

    def __init__(self, ctx: JobContext, sol: MeshSolution, frames: int) -> None:
        tr = sol.tr
        self.ctx, self.sol, self.frames = ctx, sol, frames
        self.cameras = stored_cameras(tr)
        self.base = float(tr.meta.get("exposure", 1.0))          # L's captures were taken at this exposure
        f, self.peak = evaluation_exposure(sol.white, tr.black, sol.region)
        if f < 1.0 and not all(ctx.supports_exposure(c) for c in self.cameras):
            ctx.log(f"warning: the rig's white reaches {self.peak:.2f} of the camera's full scale on the scored "
                    "surface: its captures clip there and cap the scores; lower the camera's exposure (or --level)")
            f = 1.0
        elif f < 1.0:
            ctx.log(f"the rig's white reaches {self.peak:.2f} of the camera's full scale on the scored surface: "
                    f"evaluating at {f:.3f} times the exposure L was measured at")
        self.f = f
        self.exposure = self.base * f
        self.shot = {"exposure": self.exposure} if self.exposure < 1.0 else {}
        self.ref = float(np.percentile(sol.target[sol.region], SCORE_PERCENTILE))
        if self.ref <= 0:
            raise JobError("the rig adds no light to the visible surface: check the light-transport measurement")
        self.goal = sol.target / np.float32(self.ref)

    async def capture(self) -> np.ndarray:
        return await capture_cameras(self.ctx, self.cameras, frames=self.frames, **self.shot)

    def score(self, capture: np.ndarray, black: np.ndarray) -> tuple[Figures, np.ndarray]:
        c = (np.asarray(capture, np.float32) - black) / np.float32(self.ref * self.f)
        if self.goal.shape[2] == 1:
            c = c.mean(axis=2, keepdims=True)
        return stacked_scores(self.goal, c, self.sol.region, len(self.cameras)), c

    async def baseline_frames(self, base_x: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        views = (await load_geometry(self.ctx, sorted(base_x), self.cameras, projectors=True)).projectors
        frames_by_slot = {}
        for k, x in base_x.items():
            st = self.ctx.rig.slot(k)
            frames_by_slot[k] = await self.ctx.compute(mesh_warp, x, views[k], lut=st.lut, gain=st.gain)
        return frames_by_slot

    def predicted(self, x: np.ndarray) -> Figures:
        tr = self.sol.tr
        c = (tr.L @ x.reshape(-1, x.shape[2])).reshape(*tr.camera_shape, -1) / np.float32(self.ref)
        return stacked_scores(self.goal, c, self.sol.region, len(self.cameras))

    def tiles(self, tiles: dict[str, np.ndarray], order: list[str]) -> list[np.ndarray]:
        # each camera's view cut to its own part of the visible surface (not the black between them),
        # packed one under the other or side by side: only the picture's layout, no score depends on it
        images = [self.goal] + [np.clip(tiles[k], 0, 1) for k in order]
        return packed_views(images, self.sol.region, len(self.cameras), across=len(images))

    def figures(self) -> Figures:
        sol = self.sol
        return {"region": {"visible_surface_pixels": int(sol.region.sum()),
                           "of_mesh_pixels": int(sol.cams.view.on_mesh.sum()), "score_reference": round(self.ref, 6)},
                "exposure": round(self.exposure, 4), "transport_exposure": round(self.base, 4),
                "white_peak_of_full_scale": round(self.peak, 4)}
