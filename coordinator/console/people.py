"""The console's user management, for admins: list, add, change the role of and remove the rig's
users (:class:`coordinator.users.UserStore`, the same file ``shadowless rig user`` edits).

* ``GET /api/users``: the users (name, role, when made and changed; never a hash) and the open
  sessions (who, role, address, seconds idle).
* ``POST /api/users`` ``{"name", "role", "password"}``: add one.
* ``POST /api/users/role`` ``{"name", "role"}`` and ``POST /api/users/remove`` ``{"name"}``.

Each answers JSON like every action, and lands in the action log with who did it (the password
never does). A change holds at once: the console looks every session's role up at each request.
"""
from __future__ import annotations

import asyncio
from typing import TYPE_CHECKING, Any

from aiohttp import web

from coordinator.console.actions import BadRequest, _json_body
from coordinator.users import UserError, UserStore

if TYPE_CHECKING:  # pragma: no cover - types only
    from coordinator.console.actions import Actions
    from coordinator.console.auth import Session, Sessions


def _field(doc: dict[str, Any], key: str) -> str:
    v = doc.get(key)
    if not isinstance(v, str) or not v.strip():
        raise BadRequest(f"give the user's {key}")
    return v


class People:
    """The handlers; ``actions`` runs and logs each change as the console's other actions are."""

    def __init__(self, store: UserStore, sessions: "Sessions", actions: "Actions"):
        self.store, self.sessions, self.actions = store, sessions, actions

    async def listing(self, request: web.Request, session: "Session") -> web.Response:
        now = self.sessions.clock()
        users = [{"name": u.name, "role": u.role.value, "created": u.created, "changed": u.changed}
                 for u in await asyncio.to_thread(self.store.list)]
        open_ = sorted(({"who": s.who, "role": s.role, "address": s.address, "idle_s": round(now - s.last_used)}
                        for s in self.sessions.open_sessions()), key=lambda d: (d["who"], d["idle_s"]))
        return web.json_response({"ok": True, "users": users, "sessions": open_, "file_error": self.store.error})

    async def add(self, request: web.Request, session: "Session") -> web.Response:
        async def act(params):
            doc = await _json_body(request)
            name, role = _field(doc, "name"), _field(doc, "role")
            params.update(name=name, role=role)         # never the password
            try:
                return await asyncio.to_thread(self.store.add, name, role, _field(doc, "password"))
            except UserError as exc:
                raise BadRequest(str(exc)) from None
        return await self.actions.run(request, session, "add user", act)

    async def set_role(self, request: web.Request, session: "Session") -> web.Response:
        async def act(params):
            doc = await _json_body(request)
            name, role = _field(doc, "name"), _field(doc, "role")
            params.update(name=name, role=role)
            try:
                return await asyncio.to_thread(self.store.set_role, name, role)
            except UserError as exc:
                raise BadRequest(str(exc)) from None
        return await self.actions.run(request, session, "user role", act)

    async def remove(self, request: web.Request, session: "Session") -> web.Response:
        async def act(params):
            doc = await _json_body(request)
            name = _field(doc, "name")
            params.update(name=name)
            try:
                return await asyncio.to_thread(self.store.remove, name)
            except UserError as exc:
                raise BadRequest(str(exc)) from None
        return await self.actions.run(request, session, "remove user", act)
