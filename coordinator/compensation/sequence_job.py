"""The ``compensate_sequence`` job: frames compensated one after the other, then played in sync.

Each frame is solved from the previous frame's solution moved by the content's change, its
correction moved along the content's motion as far as that helps (``motion``,
:class:`~imaging.compensation.ridge.ContentWarmStart`, through
:class:`~coordinator.compensation.frames.FrameSolver`): ``first_iterations`` for the first
frame, ``iterations`` for each later one, so the time per frame is bounded. The frames are
played as 16-bit content on every node (``play``), and the figures stored in
``compensation/sequence.json``. The stored light transport is required unless ``measure``.
(``compensate_video`` does the same for a video asset and stores the result as an asset.)
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from imaging.compensation.errors import CompensationError
from coordinator.compensation.frames import open_frame_solver
from coordinator.compensation.image_param import decode_image_param
from coordinator.compensation.options import SequenceOptions
from coordinator.compensation.store import write_result
from coordinator.jobs import JobContext, JobError
from coordinator.jobs.results import Figures, JobResult, optional, spread

__all__ = ["OPTIONS", "run", "SequenceResult"]

OPTIONS = SequenceOptions


@dataclass(frozen=True, kw_only=True)
class SequenceResult(JobResult):
    """The ``compensate_sequence`` job's result (also ``compensation/sequence.json``): the frames' figures
    (:meth:`~coordinator.compensation.frames.FrameSolver.summary`) at the top, how they played when
    played, and the job's wall time."""

    frame_figures: Figures = spread()
    play: Figures | None = optional()
    wall_s: float


async def run(ctx: JobContext, opts: SequenceOptions) -> SequenceResult:
    """Compensate every frame (warm starts), then play them unless ``play`` is off."""
    t0 = time.monotonic()
    solver = await open_frame_solver(ctx, camera=opts.camera, measure=opts.measure, level=opts.level,
                                     regularization=opts.regularization, iterations=opts.iterations,
                                     first_iterations=opts.first_iterations, srgb=opts.srgb,
                                     motion=opts.motion)
    frames: list[np.ndarray] = []
    for k, item in enumerate(opts.frames):
        try:
            image, _ = decode_image_param(item)
        except CompensationError as exc:
            raise JobError(f"frame {k}: {exc}") from exc
        out = await ctx.compute(solver.solve, image)
        frames.append(out.frame)
        ctx.progress("compensate", "", k + 1, len(opts.frames), f"solved in {1000 * out.seconds:.0f} ms, objective {out.objective:.4g}",
                     out.objective)
    figures = solver.summary()
    play = None
    if opts.play:
        ctx.progress("play", "", 0, len(frames) * (opts.loops + 1), f"{opts.fps:g} fps")
        played = await ctx.play(frames, fps=opts.fps, loops=opts.loops)
        play = dataclasses.asdict(played)
    summary = SequenceResult(frame_figures=figures, play=play, wall_s=round(time.monotonic() - t0, 3))
    write_result(ctx.rig, "sequence.json", summary.to_wire())
    return summary
