"""What the compensation jobs share on top of their :class:`~coordinator.jobs.JobContext`."""
from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from imaging.compensation.errors import CompensationError
from imaging.compensation.geometry import content_to_camera
from coordinator.compensation.store import StoredTransport, load_valid_transport
from coordinator.jobs import JobContext, JobError

__all__ = ["content_size", "rig_geometry", "rounded", "throttled", "baseline_exposure", "stored_transport"]


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


def baseline_exposure(ctx: JobContext, opts: Any) -> float | None:
    """The exposure of the baseline's captures (None: the camera's own); refused for a camera that cannot
    change it per capture."""
    if opts.baseline_exposure == 1.0:
        return None
    if not ctx.supports_exposure(opts.camera):
        raise JobError(f"camera {opts.camera} ({ctx.camera_spec(opts.camera)}) cannot change exposure per capture; "
                       "average frames instead (baseline_frames)")
    return opts.baseline_exposure


def stored_transport(ctx: JobContext, state: str, given: dict[str, Any], key: np.ndarray, slots: list[str], *,
                     force: bool, measure: bool, surface: str | None = None) -> "StoredTransport | None":
    """The stored light transport when it is still valid for the rig as it is now (logged: it is
    reused), None when a new one must be measured (after warning about slots without an inverse
    LUT), and a JobError when none is valid and ``measure`` is False. ``surface``: only a
    measurement made on that kind of surface counts ("mesh")."""
    rig = ctx.rig
    if not force:
        found = load_valid_transport(rig, state, given, key, slots, log=ctx.log)
        if found is not None and (surface is None or found.meta.get("surface") == surface):
            ctx.log(f"light transport: reusing the stored measurement of {found.meta.get('date', '?')} "
                    f"({found.meta.get('captures')} captures)")
            return found
    if not measure:
        asked = ", ".join(f"{k} {v}" for k, v in sorted(given.items()))
        raise JobError("no valid light-transport measurement for the rig as it is now (poses, LUTs or gains changed, "
                       f"or none was made{'; or it was measured with another ' + asked if asked else ''}): "
                       "run `shadowless transport`")
    missing = [s for s in slots if rig.slot(s).lut is None]
    if missing:
        ctx.log(f"warning: {', '.join(missing)} have no inverse-response LUT: the light transport assumes linear "
                "projectors; run `shadowless response` first")
    return None
