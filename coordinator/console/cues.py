"""The console's cue routes: the cue list, GO, back and jump (the panel is ``static/cues.js``).

* ``GET /api/cues``: the cue state as JSON (:meth:`coordinator.api.CueState.to_json`: the cues,
  ``current`` and ``next`` as indices, ``fired_at`` and ``follow_at`` as Unix times, ``fading``);
  the same object is in ``/api/status`` and the event stream under ``cues``.
* ``POST /api/cues`` with ``{"cues": [...]}``: store a new list (refused with one line, nothing
  stored, when a cue cannot be fired); ``POST /api/cues/go``, ``/api/cues/back``, ``/api/cues/jump``
  with ``{"id": ...}``: fire a cue.

Each action is the core's own method (:mod:`coordinator.cues`), performed and logged by the
console's :class:`~coordinator.console.actions.Actions` with who acted; every fire, whoever
fired it (the command line, OSC, an auto-follow), is written to the same action log.
"""
from __future__ import annotations

import asyncio
import json
from typing import TYPE_CHECKING, Any

from aiohttp import web

from coordinator.console.actions import BadRequest, _json_body
from protos.cues import CueList

#: the largest cue list a POST may carry (a thousand cues with long names fit)
MAX_CUES_BYTES = 512 * 1024

if TYPE_CHECKING:  # pragma: no cover - types only
    from coordinator.console.actions import Actions
    from coordinator.console.auth import Session


class CueRoutes:
    """The cue endpoints, performed and logged by the console's :class:`Actions`."""

    def __init__(self, actions: "Actions"):
        self.actions = actions
        self._writes: set[asyncio.Future] = set()

    @property
    def coord(self) -> Any:
        return self.actions.coord

    async def state(self, request: web.Request, session: "Session") -> web.Response:
        return web.json_response(self.coord.cue_state().to_json())

    async def store(self, request: web.Request, session: "Session") -> web.Response:
        async def act(params):
            raw = await request.content.read(MAX_CUES_BYTES + 1)
            if len(raw) > MAX_CUES_BYTES:
                raise BadRequest(f"the cue list is larger than {MAX_CUES_BYTES // 1024} KiB")
            try:
                doc = json.loads(raw or b"{}")
            except ValueError as exc:
                raise BadRequest(f"the request body is not JSON: {exc}") from None
            cues = CueList.from_json(doc)
            params.update(cues=len(cues))
            return self.coord.set_cues(cues, who=session.who)
        return await self.actions.run(request, session, "cues", act)

    async def go(self, request: web.Request, session: "Session") -> web.Response:
        async def act(params):
            return self.coord.cue_go(who=session.who)
        return await self.actions.run(request, session, "cue go", act)

    async def back(self, request: web.Request, session: "Session") -> web.Response:
        async def act(params):
            return self.coord.cue_back(who=session.who)
        return await self.actions.run(request, session, "cue back", act)

    async def jump(self, request: web.Request, session: "Session") -> web.Response:
        async def act(params):
            doc = await _json_body(request)
            cue_id = doc.get("id")
            if not isinstance(cue_id, str) or not cue_id:
                raise BadRequest('name the cue to jump to: {"id": "3"}')
            params.update(id=cue_id)
            return self.coord.cue_jump(cue_id, who=session.who)
        return await self.actions.run(request, session, "cue jump", act)

    def log_fires(self) -> None:
        """Every fire (from anywhere) goes to the console's action log, and the page hears of it."""
        audit, live = self.actions.audit, self.actions.live

        def on_fire(**entry: Any) -> None:
            fut = asyncio.ensure_future(audit.record(**entry))
            self._writes.add(fut)
            fut.add_done_callback(self._writes.discard)
            live.poke()

        self.coord.cue_engine().on_fire = on_fire


def register(app: web.Application, console: Any) -> None:
    """Add the cue routes to the console's ``app`` (``console``: its ConsoleApp), guarded as every route
    (a POST needs an operator), and log every fire."""
    routes = CueRoutes(console.actions)
    c = console
    app.router.add_get("/api/cues", c.guard(routes.state))
    app.router.add_post("/api/cues", c.guard(routes.store))
    app.router.add_post("/api/cues/go", c.guard(routes.go))
    app.router.add_post("/api/cues/back", c.guard(routes.back))
    app.router.add_post("/api/cues/jump", c.guard(routes.jump))
    if hasattr(c.coord, "cue_engine"):
        routes.log_fires()
