"""``GET /api/thumbnail/{slot}``: the latest small picture of what a slot's projector shows.

The answer is the node's own PNG (8-bit RGB, at most 160 x 120, see :mod:`coordinator.previews`),
never cached, with ``X-Frame-Id`` (the frame it shows), ``X-Age-Ms`` (since it arrived) and
``X-Output-Size`` (the projector pixels it was made from). Asking is what makes the coordinator
ask the slot's node for previews, for a few seconds: the page fetches the thumbnails of the rows
it shows about once a second while it is visible, so nobody looking costs nothing. 404 with the
reason in JSON when the slot is unknown or no picture came yet.
"""
from __future__ import annotations

import json
from typing import TYPE_CHECKING

from aiohttp import web

if TYPE_CHECKING:  # pragma: no cover - types only
    from coordinator.console.auth import Session
    from coordinator.ports import ConsoleRig


def _not_found(message: str) -> web.HTTPNotFound:
    return web.HTTPNotFound(text=json.dumps({"ok": False, "error": message}), content_type="application/json")


class Thumbnails:
    """The thumbnail route's handler, on ``coord.previews``."""

    def __init__(self, coord: "ConsoleRig"):
        self.coord = coord

    async def thumbnail(self, request: web.Request, session: "Session") -> web.Response:
        slot = request.match_info["slot"]
        if slot not in self.coord.rig.slots:
            raise _not_found(f"no slot {slot!r} in rig {self.coord.rig.config.name!r}")
        previews = self.coord.previews
        previews.want(slot)
        thumb = previews.thumbnail(slot)
        if thumb is None:
            link = self.coord.slot_link(slot)
            why = ("no node has joined it" if link == "none" else
                   "its node is not connected" if link == "closed" else
                   "its node was just asked for one (it comes within a second or two; a node of an older "
                   "version never sends one)")
            raise _not_found(f"no thumbnail of {slot} yet: {why}")
        p = thumb.preview
        age_ms = max(0.0, (previews.clock() - thumb.received_s) * 1e3)
        return web.Response(body=p.png, content_type="image/png",
                            headers={"Cache-Control": "no-store", "X-Frame-Id": str(p.frame_id),
                                     "X-Age-Ms": f"{age_ms:.0f}",
                                     "X-Output-Size": f"{p.output_width}x{p.output_height}"})
