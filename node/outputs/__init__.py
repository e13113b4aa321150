"""Where a node's rendered frames go: offscreen, a fullscreen window, or the virtual room.

Specs understood by :func:`open_output`: ``offscreen`` (default), ``window[:MONITOR]``
and ``room://HOST:PORT``. The contract every output fulfils is :class:`Output`
(see :mod:`node.outputs.base`). The room output, :class:`node.outputs.room_link.RoomOutput`,
is imported only when a ``room://`` spec is opened.
"""
from __future__ import annotations

from node.outputs.base import (
    SPEC_FORMS,
    Output,
    OutputError,
    SwapInfo,
    headless_context,
    wants_snapshot,
    write_snapshot,
)
from node.outputs.factory import open_output
from node.outputs.offscreen import OffscreenOutput
from node.outputs.window import WindowOutput

__all__ = [
    "SPEC_FORMS",
    "OffscreenOutput",
    "Output",
    "OutputError",
    "SwapInfo",
    "WindowOutput",
    "headless_context",
    "open_output",
    "wants_snapshot",
    "write_snapshot",
]
