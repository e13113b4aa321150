"""Where a node's rendered frames go: offscreen, a fullscreen window, or the virtual room.

An :class:`Output` owns the GL context the node renders with (one thread owns
both). The presenter calls, for every frame, in this order and from that thread:

1. ``renderer.render(...)`` into the renderer's framebuffer (early, as soon as the frame arrives),
2. :meth:`Output.prepare` (still before the presentation time: e.g. blit to the window's back buffer),
3. :meth:`Output.swap` exactly at the presentation time (must be fast: this instant is the swap),
4. :meth:`Output.after_swap` (read-back, PNG snapshots, sending to the room: off the critical instant).

Specs understood by :func:`open_output`: ``offscreen`` (default), ``window[:MONITOR]``
and ``room://HOST:PORT``.
"""
from __future__ import annotations

import abc
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # pragma: no cover
    import moderngl

    from node.render.renderer import Renderer


class OutputError(RuntimeError):
    """An output cannot be opened or used; the message says what to do."""


@dataclass(frozen=True)
class SwapInfo:
    """What was just swapped in."""

    slot: str
    frame_id: int
    tag: str
    pts_ns: int
    swap_rig_ns: int
    host_monotonic_ns: int


class Output(abc.ABC):
    kind: str = "abstract"

    @abc.abstractmethod
    def make_context(self) -> "moderngl.Context":
        """Create (once) and return the GL context the renderer must use."""

    def native_size(self) -> tuple[int, int] | None:
        """(width, height) the display wants, or None if any size will do."""
        return None

    def prepare(self, renderer: "Renderer") -> None:
        """Called after rendering, before the presentation time."""

    def swap(self) -> None:
        """Called at the presentation time. Must return quickly."""

    def after_swap(self, renderer: "Renderer", info: SwapInfo) -> None:
        """Called right after :meth:`swap`; may read back and ship the frame."""

    def close(self) -> None:
        """Release the context and any connection."""


def open_output(spec: str, *, slot: str, snapshot_dir: Path | None = None) -> Output:
    """Open the output named by ``spec`` for node ``slot``.

    ``snapshot_dir``: if given, every frame whose tag starts with ``show`` is
    also written to ``snapshot_dir/<slot>.png`` (atomically) for inspection.
    """
    raise NotImplementedError  # filled in with the outputs below
