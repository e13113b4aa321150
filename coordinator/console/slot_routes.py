"""The console's per-slot tools: ``POST /api/solo`` (``{"slots": [...]}``; an empty list ends the
solo) and ``POST /api/pattern`` (``{"name": "grid", "slots": [...]}``; no ``slots``: every slot).

Each calls the same :class:`Coordinator` method as the command line (``solo``,
``show_test_pattern``: :mod:`coordinator.slot_tools`), through :meth:`Actions.run`, so each is in
the action log with its result or refusal, and answers as every action does. The caller
(``app.py``) has checked the session, the CSRF token and the Origin.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

from aiohttp import web

from coordinator.console.actions import BadRequest, _json_body
from coordinator.test_patterns import PATTERNS

if TYPE_CHECKING:  # pragma: no cover - types only
    from coordinator.console.actions import Actions
    from coordinator.console.auth import Session

#: the most slots one request names (a rig of more is chosen with no list: every slot)
MAX_SLOTS = 1024


def _slots(doc: dict[str, Any], *, required: bool) -> list[str] | None:
    """The request's ``slots``: a list of slot names (None when absent and not required)."""
    slots = doc.get("slots")
    if slots is None and not required:
        return None
    if not isinstance(slots, list) or not all(isinstance(s, str) and s for s in slots):
        raise BadRequest("slots must be a list of slot names, e.g. {\"slots\": [\"r1c1\", \"r1c2\"]}")
    if len(slots) > MAX_SLOTS:
        raise BadRequest(f"name at most {MAX_SLOTS} slots")
    return slots


class SlotRoutes:
    """The two endpoints, performed and logged by the console's :class:`Actions`."""

    def __init__(self, actions: "Actions"):
        self.actions = actions

    async def solo(self, request: web.Request, session: "Session") -> web.Response:
        async def act(params):
            doc = await _json_body(request)
            slots = _slots(doc, required=True)
            params.update(slots=slots)
            return self.actions.coord.solo(slots)
        return await self.actions.run(request, session, "solo", act)

    async def pattern(self, request: web.Request, session: "Session") -> web.Response:
        async def act(params):
            doc = await _json_body(request)
            name = doc.get("name")
            slots = _slots(doc, required=False)
            params.update(name=name, slots=slots if slots is not None else "all")
            if not isinstance(name, str) or name not in PATTERNS:
                raise BadRequest(f"unknown test pattern {name!r}: choose one of {', '.join(PATTERNS)}")
            return await self.actions.coord.show_test_pattern(name, slots)
        return await self.actions.run(request, session, "pattern", act)
