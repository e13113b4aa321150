"""The latest small picture of what each projector shows: the operator console's thumbnails.

Nodes make a preview only when asked (:mod:`node.preview`), and the coordinator asks a node
only while someone looks at its thumbnail: the console's ``GET /api/thumbnail/{slot}`` calls
:meth:`Previews.want`, and for :data:`WANTED_FOR_S` after that the node's ``Previews`` stream
carries a request every :data:`ASK_EVERY_S`. Nobody looking costs nothing: no request is sent,
no picture is made.

What a node sends back is bounded before it is kept: an 8-bit RGB PNG of at most
:data:`MAX_WIDTH` x :data:`MAX_HEIGHT` pixels and :data:`MAX_PNG_BYTES`, its header matching
the sizes it declares, answering a request this coordinator made (one preview per request).
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import struct
import time
from dataclasses import dataclass
from typing import AsyncIterator, Callable

log = logging.getLogger(__name__)

MAX_WIDTH = 160
MAX_HEIGHT = 120
MAX_PNG_BYTES = 64 * 1024
#: a node is asked this often while its thumbnail is wanted (a little under a second: >= 1 a second arrive)
ASK_EVERY_S = 0.9
#: a thumbnail fetched is wanted this long (the page fetches each visible one about once a second)
WANTED_FOR_S = 3.0
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@dataclass(frozen=True)
class Preview:
    """A node's preview as it arrived: ``png`` (8-bit RGB, ``width`` x ``height``) of what its
    projector showed at frame ``frame_id`` (0: none), area-averaged from ``output_width`` x
    ``output_height`` projector pixels, answering request ``request_id``."""

    request_id: int
    frame_id: int
    png: bytes
    width: int
    height: int
    output_width: int = 0
    output_height: int = 0


@dataclass(frozen=True)
class Thumbnail:
    """A slot's latest preview and when it arrived (:attr:`Previews.clock` seconds)."""

    preview: Preview
    received_s: float


def png_header(data: bytes) -> tuple[int, int, int, int] | None:
    """(width, height, bit depth, colour type) from a PNG's IHDR chunk; None if ``data`` does not start as a PNG."""
    if len(data) < 33 or data[:8] != PNG_SIGNATURE or data[12:16] != b"IHDR":
        return None
    width, height, depth, colour = struct.unpack(">IIBB", data[16:26])
    return width, height, depth, colour


def refusal(p: Preview) -> str | None:
    """Why a preview is not kept (None: it is)."""
    if len(p.png) > MAX_PNG_BYTES:
        return f"{len(p.png)} bytes, more than {MAX_PNG_BYTES}"
    if not (1 <= p.width <= MAX_WIDTH and 1 <= p.height <= MAX_HEIGHT):
        return f"{p.width}x{p.height} pixels, beyond {MAX_WIDTH}x{MAX_HEIGHT}"
    header = png_header(p.png)
    if header is None:
        return "not a PNG"
    if header != (p.width, p.height, 8, 2):
        return f"its PNG header says {header[0]}x{header[1]}, {header[2]}-bit colour type {header[3]}, not 8-bit RGB " \
               f"{p.width}x{p.height}"
    return None


class Previews:
    """Each slot's latest thumbnail, and the requests that bring them (see the module docstring).

    Parameters
    ----------
    clock : callable
        Seconds, monotonic (injectable for tests).
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic):
        self.clock = clock
        self.latest: dict[str, Thumbnail] = {}
        self.asked: dict[str, int] = {}        # requests sent, per slot
        self.received: dict[str, int] = {}     # previews kept, per slot
        self.refused = 0                       # previews not kept (see refusal())
        self._wanted_until: dict[str, float] = {}
        self._asked_id: dict[str, int] = {}     # the newest request sent to each slot's node
        self._answered_id: dict[str, int] = {}  # the newest request answered by a kept preview
        self._next_id = 0
        self._wake: dict[str, set[asyncio.Event]] = {}
        self._warned: set[str] = set()

    # ------------------------------------------------------------------ who looks
    def want(self, slot: str) -> None:
        """Someone looks at ``slot``'s thumbnail: ask its node for previews for the next WANTED_FOR_S."""
        was = self.wanted(slot)
        self._wanted_until[slot] = self.clock() + WANTED_FOR_S
        if not was:
            for ev in self._wake.get(slot, ()):
                ev.set()

    def wanted(self, slot: str) -> bool:
        return self._wanted_until.get(slot, -math.inf) > self.clock()

    def thumbnail(self, slot: str) -> Thumbnail | None:
        return self.latest.get(slot)

    # ------------------------------------------------------------------ the nodes
    async def asks(self, slot: str, wake: asyncio.Event, closed: Callable[[], bool]) -> AsyncIterator[int]:
        """Request ids for ``slot``'s node: one every ASK_EVERY_S while its thumbnail is wanted, none
        otherwise (waiting on ``wake``, which :meth:`want` and the session's end set); ends when
        ``closed()``."""
        wakes = self._wake.setdefault(slot, set())
        wakes.add(wake)
        next_at = -math.inf
        try:
            while not closed():
                now = self.clock()
                if not self.wanted(slot) or now < next_at:
                    wake.clear()
                    if not self.wanted(slot):
                        await wake.wait()
                    else:
                        # not wait_for: on 3.11 it drops a cancel that meets the set wake event
                        with contextlib.suppress(TimeoutError):
                            async with asyncio.timeout(next_at - now):
                                await wake.wait()
                    continue
                self._next_id += 1
                self._asked_id[slot] = self._next_id
                self.asked[slot] = self.asked.get(slot, 0) + 1
                next_at = now + ASK_EVERY_S
                yield self._next_id
        finally:
            wakes.discard(wake)

    def accept(self, slot: str, p: Preview) -> bool:
        """Keep ``p`` as ``slot``'s thumbnail if it is within bounds and answers a request not yet
        answered; whether it was kept."""
        why = refusal(p)
        if why is None and not (self._answered_id.get(slot, 0) < p.request_id <= self._asked_id.get(slot, 0)):
            why = f"it answers request {p.request_id}, not one asked and unanswered"
        if why is not None:
            self.refused += 1
            level = logging.WARNING if slot not in self._warned else logging.DEBUG
            self._warned.add(slot)
            log.log(level, "node %s sent a preview that is not kept: %s", slot, why)
            return False
        self._answered_id[slot] = p.request_id
        self.latest[slot] = Thumbnail(p, self.clock())
        self.received[slot] = self.received.get(slot, 0) + 1
        return True
