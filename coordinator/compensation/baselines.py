"""The per-projector baseline's light transports ``L_i``, measured one projector at a time.

The conventional method this project compares itself with needs each projector's own ``L_i``:
every projector black, then, one projector after another, the dot patterns shown on it alone and
captured (``N`` times the captures of ``L``). What a pattern looks like in a projector's own
pixels, what a capture is and how ``L_i`` is recovered from the captures depends on the surface
(a :class:`BaselineScan` says it); the loop, what is stored (``compensation/baseline-<slot>.npz``
through :func:`~coordinator.compensation.store.save_baseline_transport`), which projectors are left
out (those adding no light) and the figures are the same on a table and on a mesh.
"""
from __future__ import annotations

import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp

from coordinator.compensation.capture_feed import transport_while_capturing
from coordinator.compensation.options import TransportOptions
from coordinator.compensation.store import StoredTransport, save_baseline_transport
from coordinator.jobs import JobContext
from coordinator.jobs.results import JobResult

__all__ = ["BaselineScan", "BaselineFigures", "measure_baselines", "lit_baselines"]


@dataclass(frozen=True, kw_only=True)
class BaselineFigures(JobResult):
    """The baseline's measurement: the projectors kept, those left out (no light), those measured now (the
    rest were stored), its captures (in all, and per projector when any was measured), the frames averaged
    per capture, the exposure relative to ``L``'s, and its time."""

    slots: list[str]
    excluded: list[str]
    measured: list[str]
    captures: int
    captures_per_projector: int | None
    frames: int
    exposure: float
    seconds: float


@dataclass(frozen=True)
class BaselineScan:
    """How a surface shows and captures its baseline's dot patterns.

    ``frame(slot, k)``: the projector's own frame (its pixels, uint8) for dot pattern ``k`` of
    ``patterns``; ``capture()``: one capture of what the rig shows, (Hc, Wc, 3) float32 (several
    cameras: stacked); ``recover``: the keyword arguments of
    :func:`~coordinator.compensation.capture_feed.transport_while_capturing` that recover ``L_i``.
    """

    patterns: int
    frame: Callable[[str, int], Awaitable[np.ndarray]]
    capture: Callable[[], Awaitable[np.ndarray]]
    recover: dict[str, Any] = field(default_factory=dict)


async def measure_baselines(ctx: JobContext, tr: StoredTransport, opts: TransportOptions, scan: BaselineScan, *,
                            fingerprint: str, todo: list[str], out: dict[str, sp.csr_matrix]) -> None:
    """Measure ``todo``'s ``L_i`` one projector at a time (after one black capture), store each as it is
    recovered and add it to ``out``."""
    frames = opts.baseline_frame_count
    ctx.log(f"baseline: measuring {len(todo)} projector(s) one at a time ({scan.patterns} patterns x "
            f"{frames} frame(s) each, exposure x{opts.baseline_exposure:g})")
    await ctx.show({s: None for s in tr.slots}, settle_s=opts.settle_s, require=[])
    black = await scan.capture()
    for n, s in enumerate(todo):

        async def patterns(s=s):
            for k in range(scan.patterns):
                frame = await scan.frame(s, k)
                await ctx.show({s: frame}, settle_s=opts.settle_s, require=[s])
                yield await scan.capture()
                ctx.progress("baseline transport", s, k + 1, scan.patterns, f"projector {n + 1}/{len(todo)}")

        Li = await transport_while_capturing(ctx, patterns(), black, dot_value=opts.baseline_exposure, **scan.recover)
        await ctx.compute(save_baseline_transport, ctx.rig, s, Li,
                          {"fingerprint": fingerprint, "slot": s, "frames": frames, "exposure": opts.baseline_exposure,
                           "date": time.strftime("%Y-%m-%dT%H:%M:%S%z")})
        out[s] = Li


def lit_baselines(ctx: JobContext, tr: StoredTransport, opts: TransportOptions, out: dict[str, sp.csr_matrix], *,
                  todo: list[str], captures: int, seconds: float, captures_per_projector: int | None,
                  unlit: str) -> tuple[dict[str, sp.csr_matrix], BaselineFigures]:
    """``out`` without the projectors that add no light to the camera image (below 1/1000 of their share of
    ``L``'s light; logged with ``unlit``, the likely reason), and the figures of the measurement."""
    total = float(tr.L.sum())
    excluded = [s for s in tr.slots if float(out[s].sum()) < 1e-3 * total / max(len(tr.slots), 1)]
    for s in excluded:
        ctx.log(f"baseline: {s} adds no light to the camera image ({unlit}); left out")
        out.pop(s)
    return out, BaselineFigures(slots=sorted(out), excluded=excluded, measured=todo, captures=captures,
                                captures_per_projector=captures_per_projector, frames=opts.baseline_frame_count,
                                exposure=opts.baseline_exposure, seconds=round(seconds, 3))
