"""What the frame-by-frame compensation jobs share (``compensate_sequence``, ``compensate_video``):
the stored light transport turned into a warm-started solver, one frame solved at a time, and
the figures of the run.

:func:`open_frame_solver` selects the planar projectors, takes the stored ``L`` (measured first
only when asked, through the table's :class:`~coordinator.compensation.planar_surface.PlanarSurface`),
sets the target level and builds the
:class:`~imaging.compensation.ridge.ContentWarmStart`; :meth:`FrameSolver.solve` turns one
decoded picture into its compensated 16-bit frame, timing the solve; :meth:`FrameSolver.summary`
gives the per-frame figures both jobs report.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from imaging.compensation.geometry import camera_target, inscribed_region, row_white, target_level
from coordinator.compensation.image_param import prepare_image
from coordinator.compensation.jobkit import content_size
from coordinator.compensation.memory_check import check_solve
from imaging.compensation.motion import MotionWarp
from coordinator.compensation.options import TransportOptions
from coordinator.compensation.planar_surface import PlanarSurface
from imaging.compensation.ridge import ContentWarmStart, RidgeProblem
from coordinator.compensation.store import StoredTransport, transport_summary
from coordinator.jobs import JobContext

__all__ = ["FrameSolver", "SolvedFrame", "open_frame_solver", "motion_warp", "to_uint16", "psnr"]


def motion_warp(flow: str) -> MotionWarp | None:
    """The jobs' motion warm start for ``--motion FLOW``: ``"off"`` (None) or a DIS preset, the flow
    estimated at full resolution (the jobs are not real time: the accurate flow is worth its cost)."""
    return None if flow == "off" else MotionWarp(scale=1, preset=flow)


def to_uint16(x: np.ndarray) -> np.ndarray:
    """A solution as 16-bit content: ``rint(clip(x, 0, 1) * 65535)``.

    ``x``: (H, W, C) float32 (any shape; kept). Returns the same shape as uint16.
    """
    return np.rint(np.clip(x, 0, 1) * 65535).astype(np.uint16)


def psnr(target: np.ndarray, seen: np.ndarray) -> float:
    """PSNR in dB of ``seen`` (clipped to [0, 1]) against ``target``, data range 1 (float64 sums).

    Both (..., C) float of one shape; ``inf`` when they are equal.
    """
    t = np.asarray(target, np.float64)
    s = np.clip(np.asarray(seen, np.float64), 0.0, 1.0)
    if t.shape != s.shape:
        raise ValueError(f"target {t.shape} and seen {s.shape} differ in shape")
    mse = float(np.mean((t - s) ** 2))
    return float("inf") if mse == 0 else float(10.0 * np.log10(1.0 / mse))


@dataclass(frozen=True)
class SolvedFrame:
    """One compensated frame: ``frame`` (H, W, C) uint16, the solve's wall time, its data
    objective ``||L x - c'||^2`` and, when asked, the predicted PSNR (dB, through the measured
    ``L``, inside the inscribed region) of the uncompensated content and of ours."""

    frame: np.ndarray
    seconds: float
    objective: float
    psnr_none: float | None = None
    psnr_ours: float | None = None


@dataclass
class FrameSolver:
    """Warm-started compensation of frames one after the other, over the stored transport.

    ``size`` is the rig's content size ``(W, H)``; ``level`` the target white in camera units;
    ``region`` the camera region (rows, cols) the PSNR figures are computed in.
    """

    transport: StoredTransport
    problem: RidgeProblem
    warm: ContentWarmStart
    size: tuple[int, int]
    level: float
    region: tuple[slice, slice]
    srgb: bool = False
    times: list[float] = field(default_factory=list)
    objectives: list[float] = field(default_factory=list)
    psnrs: list[tuple[float, float]] = field(default_factory=list)
    shares: list[float] = field(default_factory=list)  #: each motion start's share of the moved start

    def solve(self, image: np.ndarray, *, predict: bool = False) -> SolvedFrame:
        """Compensate the next frame (blocking: run it through ``ctx.compute``).

        ``image``: (h, w, C) uint8/uint16/float32 picture at any size (resized to the content
        size, :func:`~.image_param.prepare_image`). Returns its :class:`SolvedFrame`; the
        frame is (H, W, C) uint16 with C the picture's channels (1 or 3).
        """
        tr = self.transport
        content = prepare_image(image, self.size, srgb=self.srgb)
        target = camera_target(content, tr.H, tr.camera_shape) * np.float32(self.level)
        t = time.perf_counter()
        res = self.warm(target, content)
        seconds = time.perf_counter() - t
        x = np.clip(res.x, 0, 1).reshape(self.size[1], self.size[0], -1)
        obj = self.problem.data_objective(x, target)
        self.times.append(seconds)
        self.objectives.append(obj)
        if self.warm.last_share is not None:
            self.shares.append(self.warm.last_share)
        p_none = p_ours = None
        if predict:
            p_none, p_ours = self._predicted(content, x, target)
            self.psnrs.append((p_none, p_ours))
        return SolvedFrame(to_uint16(x), seconds, obj, p_none, p_ours)

    def _predicted(self, content: np.ndarray, x: np.ndarray, target: np.ndarray) -> tuple[float, float]:
        """Predicted PSNR (through the measured ``L``) of the scaled content and of ``x``, in the region."""
        s = np.float32(self.level)
        c = content.shape[2]
        goal = target[self.region] / s
        shape = (*self.transport.camera_shape, c)
        none = np.clip(content * np.float32(self.warm.scale or 0.0), 0, 1)
        seen_none = self.problem.data.matvec(none.reshape(-1, c)).reshape(shape)[self.region] / s
        seen_ours = self.problem.data.matvec(x.reshape(-1, c)).reshape(shape)[self.region] / s
        return round(psnr(goal, seen_none), 3), round(psnr(goal, seen_ours), 3)

    def checkpoint(self) -> dict[str, np.ndarray] | None:
        """The solver's state and figures as arrays (for ``np.savez``); None before the first frame."""
        st = self.warm.state()
        if st is None:
            return None
        x, content, scale = st
        return {"x": x, "content": content, "scale": np.float64(scale), "times": np.asarray(self.times, np.float64),
                "objectives": np.asarray(self.objectives, np.float64),
                "psnrs": np.asarray(self.psnrs, np.float64).reshape(-1, 2),
                "shares": np.asarray(self.shares, np.float64)}

    def restore(self, saved: dict[str, np.ndarray]) -> None:
        """Continue from a :meth:`checkpoint` (``ValueError`` when it does not fit)."""
        self.warm.restore(saved["x"], saved["content"], float(saved["scale"]))
        self.times = [float(v) for v in saved["times"]]
        self.objectives = [float(v) for v in saved["objectives"]]
        self.psnrs = [(float(a), float(b)) for a, b in np.asarray(saved["psnrs"]).reshape(-1, 2)]
        self.shares = [float(v) for v in saved["shares"]] if "shares" in saved else []

    def summary(self) -> dict[str, Any]:
        """The run's figures: frames, the first frame's and the later frames' solve times (ms),
        the mean data objective, the content -> target scale, the transport, PSNR means when
        predicted, and the mean share of the moved start when the correction follows the motion."""
        times = self.times or [0.0]
        warm = times[1:] or times
        out: dict[str, Any] = {
            "frames": len(self.times), "iterations_per_frame": self.warm.iterations,
            "first_iterations": self.warm.first_iterations,
            "motion": self.warm.motion.preset if self.warm.motion is not None else "off",
            "target_level": round(self.level, 6),
            "ms_first_frame": round(1000 * times[0], 2),
            "ms_per_frame_mean": round(1000 * float(np.mean(warm)), 2),
            "ms_per_frame_median": round(1000 * float(np.median(warm)), 2),
            "ms_per_frame_max": round(1000 * float(np.max(warm)), 2),
            "objective_mean": float(np.mean(self.objectives)) if self.objectives else None,
            "scale": self.warm.scale, "transport": transport_summary(self.transport),
        }
        if self.shares:   # how much of each start moved with the picture (0: the rig's pattern, kept in place)
            out["motion_share_mean"] = round(float(np.mean(self.shares)), 3)
        if self.psnrs:
            a = np.asarray(self.psnrs, np.float64)
            out["predicted_psnr"] = {"none_mean": round(float(np.mean(a[:, 0])), 3),
                                     "ours_mean": round(float(np.mean(a[:, 1])), 3),
                                     "ours_min": round(float(np.min(a[:, 1])), 3),
                                     "gain_mean_db": round(float(np.mean(a[:, 1] - a[:, 0])), 3)}
        return out


async def open_frame_solver(ctx: JobContext, *, camera: int, measure: bool, level: float, regularization: float,
                            iterations: int, first_iterations: int, srgb: bool, motion: str = "off") -> FrameSolver:
    """The solver for the rig's planar projectors over the stored transport (measured first when
    none is valid and ``measure``; otherwise a :class:`~coordinator.jobs.JobError` says to run
    `shadowless transport`)."""
    slots = ctx.select_slots(None, need_pose=True, planar=True)
    tr = await PlanarSurface().transport(ctx, TransportOptions(camera=camera), slots, measure=measure)
    cw, ch = content_size(ctx)
    region = inscribed_region(tr.H, (cw, ch), tr.camera_shape, margin=int(tr.meta["radius"]) + 2)
    s = target_level(row_white(tr.L, tr.camera_shape), region, level)
    check_solve((cw, ch), tr.camera_shape, int(tr.meta["radius"]), what="the frames' solver")
    problem = await ctx.compute(RidgeProblem, tr.L, regularization)
    warm = ContentWarmStart(problem, iterations=iterations, first_iterations=first_iterations, content_shape=(ch, cw),
                            motion=motion_warp(motion))
    return FrameSolver(tr, problem, warm, (cw, ch), float(s), region, srgb=srgb)
