"""The ``compensate_sequence`` job: frames compensated one after the other, then played in sync.

Each frame is solved from the previous frame's solution moved by the content's change
(:class:`~coordinator.compensation.ridge.ContentWarmStart`): ``first_iterations`` for the first
frame, ``iterations`` for each later one, so the time per frame is bounded. The frames are
played as 16-bit content on every node (``play``), and the figures stored in
``compensation/sequence.json``. The stored light transport is required unless ``measure``.
"""
from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np

from coordinator.compensation.errors import CompensationError
from coordinator.compensation.geometry import camera_target, inscribed_region, row_white, target_level
from coordinator.compensation.image_param import decode_image_param, prepare_image
from coordinator.compensation.jobkit import content_size
from coordinator.compensation.options import SequenceOptions, TransportOptions
from coordinator.compensation.ridge import ContentWarmStart, RidgeProblem
from coordinator.compensation.store import transport_summary, write_result
from coordinator.compensation.transport_job import ensure_transport
from coordinator.jobs import JobContext, JobError

__all__ = ["OPTIONS", "run"]

OPTIONS = SequenceOptions


async def run(ctx: JobContext, opts: SequenceOptions) -> dict:
    """Compensate every frame (warm starts), then play them unless ``play`` is off."""
    t0 = time.monotonic()
    slots = ctx.select_slots(None, need_pose=True, planar=True)
    tr = await ensure_transport(ctx, TransportOptions(camera=opts.camera), slots, measure=opts.measure)
    cw, ch = content_size(ctx)
    region = inscribed_region(tr.H, (cw, ch), tr.camera_shape, margin=int(tr.meta["radius"]) + 2)
    s = target_level(row_white(tr.L, tr.camera_shape), region, opts.level)
    problem = await ctx.compute(RidgeProblem, tr.L, opts.regularization)
    comp = ContentWarmStart(problem, iterations=opts.iterations, first_iterations=opts.first_iterations,
                            content_shape=(ch, cw))
    times: list[float] = []
    objectives: list[float] = []
    frames: list[np.ndarray] = []
    for k, item in enumerate(opts.frames):
        try:
            image, name = decode_image_param(item)
        except CompensationError as exc:
            raise JobError(f"frame {k}: {exc}") from exc
        content = prepare_image(image, (cw, ch), srgb=opts.srgb)
        target = camera_target(content, tr.H, tr.camera_shape) * np.float32(s)
        t = time.perf_counter()
        res = await ctx.compute(comp, target, content)
        times.append(time.perf_counter() - t)
        objectives.append(problem.data_objective(res.x, target))
        x = np.clip(res.x, 0, 1).reshape(ch, cw, -1)
        frames.append(np.rint(x * 65535).astype(np.uint16))
        ctx.progress("compensate", "", k + 1, len(opts.frames), f"{1000 * times[-1]:.0f} ms", res.objective)
    warm = times[1:] or times
    summary: dict[str, Any] = {
        "frames": len(frames), "iterations_per_frame": opts.iterations, "first_iterations": opts.first_iterations,
        "target_level": round(s, 6), "ms_first_frame": round(1000 * times[0], 2),
        "ms_per_frame_mean": round(1000 * float(np.mean(warm)), 2),
        "ms_per_frame_median": round(1000 * float(np.median(warm)), 2),
        "ms_per_frame_max": round(1000 * float(np.max(warm)), 2),
        "objective_mean": float(np.mean(objectives)), "scale": comp.scale, "transport": transport_summary(tr),
    }
    if opts.play:
        ctx.progress("play", "", 0, len(frames) * (opts.loops + 1), f"{opts.fps:g} fps")
        played = await ctx.play(frames, fps=opts.fps, loops=opts.loops)
        summary["play"] = dataclasses.asdict(played)
    summary["wall_s"] = round(time.monotonic() - t0, 3)
    write_result(ctx.rig, "sequence.json", summary)
    return summary
