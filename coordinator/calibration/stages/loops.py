"""The loops the ``calibrate`` stages share, on a table and on a mesh alike.

* :func:`one_by_one`: the sequential modes, one projector after another; a projector that fails
  is skipped with ``keep_going`` and stops the run otherwise; a camera problem (:class:`Abort`)
  always stops it.
* :func:`coded_dot_rounds`, :func:`coarse_fits` and :func:`refuse_unfound`: the multiplexed modes'
  first stage, coded dots from every projector at once, each projector's coarse pose fitted from
  its dots, one more round (another seed) for the projectors still short of dots, and the failure
  of those left.
"""
from __future__ import annotations

import math
from collections.abc import Awaitable, Callable
from typing import Any, TypeVar

import numpy as np

from coordinator.calibration.runs import save_slot
from coordinator.calibration.stages.state import Abort, State
from coordinator.jobs import JobError
from imaging.calibration import multiplex
from imaging.calibration.errors import CalibrationError
from protos.wording import count

__all__ = ["one_by_one", "coded_dot_rounds", "coarse_fits", "refuse_unfound"]

T = TypeVar("T")


async def one_by_one(st: State, measure: Callable[[str], Awaitable[T]],
                     pose_of: Callable[[str, T, int], tuple[Any, dict]]) -> None:
    """Calibrate ``st.todo`` one after another: ``measure(slot)`` shows and captures what the projector
    needs and fits it (a :class:`JobError` or :class:`CalibrationError` fails that projector), then
    ``pose_of(slot, measured, captures_before)`` gives its pose and figures, saved at once."""
    ctx, opts = st.ctx, st.opts
    for n, slot in enumerate(st.todo):
        before = st.shots
        try:
            measured = await measure(slot)
        except Abort:
            raise
        except (JobError, CalibrationError) as exc:
            if not opts.keep_going:
                raise JobError(str(exc)) from exc
            st.failed[slot] = str(exc)
            ctx.log(f"{slot}: {exc}")
            continue
        pose, doc = pose_of(slot, measured, before)
        save_slot(ctx, slot, pose, doc)
        st.results[slot] = doc
        rms = doc["rms_px"] or math.nan
        ctx.progress("projectors", slot, n + 1, len(st.todo),
                     "calibrated" + ("" if math.isnan(rms) else f", reprojection error {rms:.3f} px"), value=rms)


async def coded_dot_rounds(st: State, decide: Callable[[multiplex.CodedDots, list[list[np.ndarray]], list[str]],
                                                       Awaitable[list[str]]],
                           **plan: Any) -> list[str]:
    """Show and capture the coded dots of ``st.todo`` all at once, in up to two rounds; ``decide(plan, caps,
    pending)`` decodes a round (``caps``: per pattern, every camera's capture) and returns the projectors
    still short of dots, who get the second round. ``plan``: more arguments of
    :func:`~imaging.calibration.multiplex.plan_coded_dots`. Returns the projectors left short."""
    ctx, opts = st.ctx, st.opts
    pending = list(st.todo)
    for attempt in range(2):
        if not pending:
            break
        dots = multiplex.plan_coded_dots({s: st.sizes[s] for s in pending}, seed=opts.seed + attempt, **plan)
        caps: list[list[np.ndarray]] = []
        stage = "coded dots" if attempt == 0 else "coded dots (retry)"
        for k in range(dots.captures):
            ctx.progress(stage, "", k, dots.captures, f"{count(len(pending), 'projector')} at once")
            caps.append(await st.shoot(dots.frames(k), require=pending))
        ctx.progress(stage, "", dots.captures, dots.captures, "decoding")
        pending = await decide(dots, caps, pending)
    return pending


async def coarse_fits(pending: list[str], fit: Callable[[str], Awaitable[T | None]], into: dict[str, T]) -> list[str]:
    """Each pending projector's coarse pose, ``fit(slot)``, put in ``into``; the projectors whose fit is None
    (too few dots) or fails (:class:`CalibrationError`) are returned, still short of dots."""
    still = []
    for s in pending:
        try:
            got = await fit(s)
        except CalibrationError:
            got = None
        if got is None:
            still.append(s)
        else:
            into[s] = got
    return still


def refuse_unfound(st: State, pending: list[str], seen: dict[str, int], *, aimed_at: str,
                   too_few: Callable[[str], str]) -> None:
    """Fail each projector left short of coded dots: not seen at all, or ``too_few(slot)``; the run stops
    unless ``keep_going``."""
    for s in pending:
        if seen[s] == 0:
            st.failed[s] = (f"projector {s} not seen by the camera (none of its coded dots was found): check that it "
                            f"is on, shows the patterns and is aimed at the {aimed_at}")
        else:
            st.failed[s] = too_few(s)
        st.ctx.log(st.failed[s])
    if pending and not st.opts.keep_going:
        raise JobError("; ".join(st.failed[s] for s in pending))
