"""The ``transport`` job: the rig's light transport ``L`` from dot-grid captures.

Every projector shows the same dot pattern at once, so the captures do not grow with their
number; ``L`` (camera pixels x content pixels) is stored in ``compensation/transport.npz`` and
reused while the rig is as it was measured (``force`` measures again). With ``baseline``, each
projector's ``L_i`` is measured too, one projector at a time, for the conventional method only.

How the dots are laid out and recovered depends on the surface
(:class:`~coordinator.compensation.surface.Surface`): on a table content pixels through each
projector's homography (:mod:`coordinator.compensation.planar_transport`); on a mesh its texture's
texels, through each projector's 3x4 pose, seen by one or several cameras
(:mod:`coordinator.compensation.mesh_transport`). This job has one body for both.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

from coordinator.compensation.baselines import BaselineFigures
from coordinator.compensation.jobkit import baseline_exposure
from coordinator.compensation.options import TransportOptions
from coordinator.compensation.store import transport_summary
from coordinator.compensation.surface import TransportFigures
from coordinator.compensation.surfaces import surface_for
from coordinator.jobs import JobContext
from coordinator.jobs.results import Figures, JobResult, optional, spread

__all__ = ["OPTIONS", "run", "TransportResult"]

OPTIONS = TransportOptions


@dataclass(frozen=True, kw_only=True)
class TransportResult(JobResult):
    """The ``transport`` job's result: the measurement's stored figures
    (:func:`~coordinator.compensation.store.transport_summary`) and the surface's
    (:class:`~coordinator.compensation.surface.TransportFigures`) side by side at the top, the baseline's
    measurement when asked, and the job's wall time."""

    measurement: Figures = spread()
    figures: TransportFigures = spread()
    baseline: BaselineFigures | None = optional()
    wall_s: float


async def run(ctx: JobContext, opts: TransportOptions) -> TransportResult:
    """Measure (or reuse) ``L``, and with ``baseline`` each projector's ``L_i``; their figures."""
    t0 = time.monotonic()
    slots = ctx.select_slots(opts.slots, need_pose=True)
    surface = surface_for(ctx, slots)
    surface.refuse(opts)
    if opts.baseline:
        baseline_exposure(ctx, opts)  # refused before any capture
    tr = await surface.transport(ctx, opts, slots)
    figures = await surface.transport_figures(ctx, tr)
    baseline = (await surface.baselines(ctx, tr, opts))[1] if opts.baseline else None
    return TransportResult(measurement=transport_summary(tr), figures=figures, baseline=baseline,
                           wall_s=round(time.monotonic() - t0, 3))
