"""What the compensation jobs share on top of their :class:`~coordinator.jobs.JobContext`."""
from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from coordinator.compensation.errors import CompensationError
from coordinator.compensation.geometry import content_to_camera
from coordinator.jobs import JobContext, JobError

__all__ = ["content_size", "rig_geometry", "rounded", "throttled"]


def content_size(ctx: JobContext) -> tuple[int, int]:
    """The rig's content size ``(W, H)``."""
    return ctx.rig.config.content_width, ctx.rig.config.content_height


def rig_geometry(ctx: JobContext, camera: int) -> tuple[np.ndarray, tuple[int, int]]:
    """Content -> camera homography of the rig and the camera size it was calibrated at (:func:`content_to_camera`)."""
    try:
        return content_to_camera(ctx.rig.path, content_size(ctx), camera=camera)
    except CompensationError as exc:
        raise JobError(str(exc)) from exc


def rounded(v: float | None, nd: int = 4) -> float | None:
    """``v`` rounded for a JSON result; None when missing or not finite."""
    return None if v is None or not math.isfinite(float(v)) else round(float(v), nd)


def throttled(fn: Callable[[int, float], None], period: float = 0.2) -> Callable[[int, float], None]:
    """``fn`` called at most every ``period`` seconds (solver progress callbacks come every iteration)."""
    last = [0.0]

    def cb(k: int, f: float) -> None:
        now = time.monotonic()
        if now - last[0] >= period:
            last[0] = now
            fn(k, f)

    return cb
