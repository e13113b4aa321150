"""The ``compensate`` job: one bounded least-squares solve for an image, stored and shown.

``p' = argmin ||L p - c'||^2 + lam ||p - p0||^2, 0 <= p <= 1`` over the stored light transport
(measured first when none is valid), ``p0`` the uncompensated image. The result becomes the rig's
content (float32) and is shown on every node. With ``evaluate``, the result without compensation,
with ours and (``baseline``) with the per-projector method are captured and scored against the
target (PSNR/SSIM) and put side by side in ``compensation/quality.png``
(:mod:`coordinator.compensation.evaluation`).

The job has one body for every rig; what the target is, how the solve is weighed and where
captures are scored is the rig's :class:`~coordinator.compensation.surface.Surface`: a table
(:mod:`coordinator.compensation.planar_surface`: content pixels through one homography) or an
object (:mod:`coordinator.compensation.mesh_surface`: the mesh's texture, weighted by how well the
camera sees each part of the surface). The figures go to ``compensation/result.json``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from coordinator.compensation.baselines import BaselineFigures
from coordinator.compensation.evaluation import evaluate
from coordinator.compensation.image_param import load_image_param, prepare_image
from coordinator.compensation.jobkit import baseline_exposure, content_size
from coordinator.compensation.options import CompensateOptions
from coordinator.compensation.store import transport_summary, write_result
from coordinator.compensation.surface import SolveFigures
from coordinator.compensation.surfaces import surface_for
from coordinator.jobs import JobContext, JobError
from coordinator.jobs.results import Figures, JobResult, optional, spread
from imaging.compensation.errors import CompensationError

__all__ = ["OPTIONS", "run", "CompensateResult"]

OPTIONS = CompensateOptions


#: the name a compensated image is shown under (see :func:`run`)
COMPENSATED_PREFIX = "compensated "


@dataclass(frozen=True, kw_only=True)
class BaselineSolve(JobResult):
    """The per-projector baseline of a ``compensate`` result: its measurement's figures, then its solves'
    wall time, iterations and the sum of their own times."""

    measurement: BaselineFigures = spread()
    solve_seconds: float
    iterations: int
    solve_seconds_sum: float


@dataclass(frozen=True, kw_only=True)
class CompensateResult(JobResult):
    """The ``compensate`` job's result (``compensation/result.json`` holds it without ``content``).

    ``surface``, ``texture`` and ``weights`` are a mesh's; ``baseline`` and ``baseline_over_ours_seconds``
    come with the per-projector baseline, ``quality`` with the evaluation, ``content`` once the result
    is shown as the rig's content.
    """

    image: str
    surface: str | None = optional()
    content_size: list[int]
    channels: int
    target_level: float
    target_level_from: str
    level: float
    none_scale: float
    solve: SolveFigures
    transport: Figures
    texture: Figures | None = optional()
    weights: str | None = optional()
    saturated_fraction: Figures
    baseline: BaselineSolve | None = optional()
    baseline_over_ours_seconds: float | None = optional()
    quality: Figures | None = optional()
    wall_s: float
    content: str | None = optional()


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


async def run(ctx: JobContext, opts: CompensateOptions) -> CompensateResult:
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
    surface = surface_for(ctx, slots)
    if opts.regularization is None:
        opts = replace(opts, regularization=surface.regularization)
    surface.refuse(opts)
    if opts.baseline:
        baseline_exposure(ctx, opts)  # refused before any capture
    tr = await surface.transport(ctx, opts, slots, measure=opts.measure)
    cw, ch = content_size(ctx)
    surface.check_solve(tr, (cw, ch), opts)
    content = prepare_image(image, (cw, ch), srgb=opts.srgb)
    sol = await surface.solve(ctx, tr, content, opts)
    baseline = base_x = over = None
    if opts.baseline:
        base_L, base_summary = await surface.solution_baselines(ctx, sol, opts)
        t_b = time.monotonic()
        base_x, results = await surface.solve_baselines(ctx, sol, base_L, opts)
        baseline = BaselineSolve(measurement=base_summary, solve_seconds=round(time.monotonic() - t_b, 3),
                                 iterations=sum(r.iterations for r in results),
                                 solve_seconds_sum=round(sum(r.seconds for r in results), 3))
        over = round(baseline.solve_seconds_sum / max(sol.seconds, 1e-9), 2)
    quality = None
    if opts.evaluate:
        quality = await evaluate(ctx, await surface.scoring(ctx, sol, opts), sol.none, sol.x, base_x, opts, name)
    result = CompensateResult(
        image=name, surface=None if surface.kind == "table" else surface.kind,   # a table's result never named it
        content_size=[cw, ch], channels=int(sol.x.shape[2]), target_level=sol.target_level,
        target_level_from=sol.target_level_from, level=opts.level, none_scale=sol.none_scale, solve=sol.solve,
        transport=transport_summary(tr), texture=sol.texture, weights=sol.weights,
        saturated_fraction=sol.saturated_fraction, baseline=baseline, baseline_over_ours_seconds=over,
        quality=quality, wall_s=round(time.monotonic() - t0, 3))
    write_result(ctx.rig, "result.json", result.to_wire())
    if opts.persist:
        ctx.show_still(np.ascontiguousarray(sol.x), name=f"{COMPENSATED_PREFIX}{name}", persist=True)
        result = replace(result, content=surface.shown_note)
    return result
