"""Light transport recovered while the captures are still being taken.

:func:`~imaging.compensation.transport.transport_from_captures` consumes an iterator of
captures; the job takes them on its event loop. :func:`transport_while_capturing` runs the
recovery on a worker thread fed through a bounded :class:`CaptureFeed`, so each capture is
used and dropped as it arrives (memory stays at a few captures whatever the dot grid) and
the recovery overlaps the next pattern's capture. :func:`dot_captures` is what it consumes while
``L`` is measured (each dot pattern shown and captured at the dots' exposure), and
:func:`warn_cut_windows` says when the recovered windows cut light, on a table and on a mesh alike.
"""
from __future__ import annotations

import asyncio
import queue
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator
from typing import Any

import numpy as np
import scipy.sparse as sp

from imaging.compensation.errors import CompensationError
from imaging.compensation.exposure import DotExposure
from imaging.compensation.geometry import EDGE_WARNING
from imaging.compensation.transport import transport_from_captures
from coordinator.jobs.errors import JobError

__all__ = ["CaptureFeed", "transport_while_capturing", "dot_captures", "warn_cut_windows"]


class CaptureFeed:
    """A blocking iterator over captures, fed from the job's loop and consumed on a worker thread."""

    _END = object()

    def __init__(self, size: int = 4) -> None:
        self._q: queue.Queue = queue.Queue(maxsize=size)
        self._error: BaseException | None = None

    def offer(self, item: object) -> bool:
        """Queue ``item`` if there is room (the queue is bounded: the consumer sets the pace)."""
        try:
            self._q.put_nowait(item)
            return True
        except queue.Full:
            return False

    def offer_end(self) -> bool:
        """Queue the end of the captures if there is room."""
        return self.offer(self._END)

    def abort(self, exc: BaseException) -> None:
        """Stop the consumer: it raises :class:`CompensationError` naming ``exc``."""
        self._error = exc
        try:
            while True:
                self._q.get_nowait()
        except queue.Empty:
            pass
        self._q.put(self._END)

    def __iter__(self) -> Iterator[np.ndarray]:
        while True:
            item = self._q.get()
            if item is self._END:
                if self._error is not None:
                    raise CompensationError(f"captures stopped: {self._error}")
                return
            yield item


async def transport_while_capturing(ctx: Any, captures: AsyncIterator[np.ndarray], black: np.ndarray, *,
                                    recover: Callable[..., sp.csr_matrix] = transport_from_captures,
                                    **options: Any) -> sp.csr_matrix:
    """:func:`transport_from_captures` (or ``recover``, which takes the same ``(captures, black, **options)``)
    on a worker thread (``ctx.compute``) while ``captures`` are taken.

    ``options`` are those of :func:`transport_from_captures` (``grid``, ``homography``,
    ``radius``, ...). A capture count or shape the dot grid does not accept raises
    :class:`JobError`; an error while capturing stops the recovery and propagates.
    """
    feed = CaptureFeed()
    task = asyncio.ensure_future(ctx.compute(recover, feed, black, **options))
    try:
        async for img in captures:
            while not task.done() and not feed.offer(img):
                await asyncio.sleep(0.005)
            if task.done():
                break
        while not task.done() and not feed.offer_end():
            await asyncio.sleep(0.005)
        return await task
    except BaseException as exc:
        feed.abort(exc)
        await asyncio.gather(task, return_exceptions=True)
        if isinstance(exc, ValueError):
            raise JobError(f"light transport: {exc}") from exc
        raise


async def dot_captures(ctx: Any, patterns: int, show: Callable[[int], Awaitable[None]], dots: DotExposure,
                       capture: Callable[[float | None, int], Awaitable[np.ndarray]], frames: int
                       ) -> AsyncIterator[np.ndarray]:
    """Dot pattern ``k`` of ``patterns`` shown (``show(k)``) and captured at the dots' exposure
    (:meth:`~imaging.compensation.exposure.DotExposure.take`), one after the other, with the
    ``transport`` progress: the captures :func:`transport_while_capturing` consumes."""
    for k in range(patterns):
        await show(k)
        yield await dots.take(k, capture, frames)
        ctx.progress("transport", "", k + 1, patterns, "dot patterns")


def warn_cut_windows(log: Callable[[str], None], edge: float, radius: int) -> None:
    """Warn when more than :data:`~imaging.compensation.geometry.EDGE_WARNING` of the measured light
    (``edge``, a share) lies on the edge of the ``2 radius + 1``-pixel windows: the PSFs are wider."""
    if edge > EDGE_WARNING:
        log(f"warning: {100 * edge:.1f} % of the measured light lies on the edge of the {2 * radius + 1}-pixel "
            f"windows: the PSFs are larger (defocus?); measure again with a larger radius (--radius {radius + 1})")
