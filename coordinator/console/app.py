"""The console's web application: routes, the login and session checks every request passes,
and the security headers every response carries.

* ``GET /`` and ``/static/*``: the page (plain files shipped with the package; the HTML embeds
  no rig data, everything arrives as JSON and is put on the page with ``textContent``).
* ``POST /login`` (a user's name and password, or the rig token), ``POST /logout``,
  ``GET /api/session`` (who is logged in, their role, and the CSRF token of the browser's
  session, for a reloaded page); admins list and manage the rig's users under ``/api/users``
  (:mod:`coordinator.console.people`).
* ``GET /api/status`` (the snapshot, JSON), ``GET /api/events`` (server-sent events) and
  ``GET /api/job/options`` (every job's options, for the job form).
* ``GET /api/pictures``, ``/api/pictures/{name}`` and ``/api/camera.png``: the jobs' pictures and
  the camera's view (:mod:`coordinator.console.pictures`).
* ``GET /api/thumbnail/{slot}``: what a slot's projector shows, small (:mod:`coordinator.console.thumbnails`).
* ``POST /api/stop``, ``/api/blackout``, ``/api/identify``, ``/api/gain``, ``/api/show``, ``/api/play``,
  ``/api/job`` (start one) and ``/api/job/cancel``.

Every request must name the console in its ``Host`` header (an address it listens on, or an
allowed name: :mod:`coordinator.console.hosts`), else it is answered 421 (a DNS-rebinding page
names its own). Every POST must come from the console's own origin (``Origin`` header equal to
this scheme and Host) and, but the login, carry the session's CSRF token in ``X-CSRF-Token``;
everything under ``/api/`` needs a session. Every POST but the logout also needs the operator role
(a viewer is answered 403 with one line, which the action log records), managing users the admin
role (:meth:`ConsoleApp.guard`). Logins are limited as :mod:`coordinator.console.auth` says.
"""
from __future__ import annotations

import asyncio
import json
import logging
import time
import warnings
from importlib import resources
from typing import TYPE_CHECKING, Awaitable, Callable

from aiohttp import web

from coordinator.console import auth
from coordinator.console import cues as cue_routes
from coordinator.console.actions import MAX_UPLOAD_BYTES, Actions
from coordinator.console.hosts import HostCheck
from coordinator.console.people import People
from coordinator.console.page_wording import helps_for_the_page
from coordinator.console.pictures import Pictures
from coordinator.console.slot_routes import SlotRoutes
from coordinator.console.thumbnails import Thumbnails
from coordinator.jobs.errors import JobError
from coordinator.jobs.options import form_fields
from coordinator.jobs.registry import JOBS, resolve
from coordinator.users import TOKEN_WHO, Role, UserStore

if TYPE_CHECKING:  # pragma: no cover - types only
    from coordinator.console.audit import ActionLog
    from coordinator.console.live import Live
    from coordinator.ports import ConsoleRig

log = logging.getLogger(__name__)

#: no inline script or style, nothing from elsewhere, never framed
CSP = ("default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; connect-src 'self'; "
       "form-action 'self'; frame-ancestors 'none'; base-uri 'none'")
SECURITY_HEADERS = {
    "Content-Security-Policy": CSP,
    "X-Content-Type-Options": "nosniff",
    "X-Frame-Options": "DENY",
    "Referrer-Policy": "no-referrer",
    "Cross-Origin-Opener-Policy": "same-origin",
    "Cross-Origin-Resource-Policy": "same-origin",
}
STATIC = {"index.html": "text/html", "console.js": "text/javascript", "console.css": "text/css",
          "pictures.js": "text/javascript", "blend.js": "text/javascript", "people.js": "text/javascript",
          "health.js": "text/javascript", "layout.js": "text/javascript", "confirm.js": "text/javascript"}
# the calibration tools on the camera view, the cue panel, and their styles (console/static)
STATIC.update({"calibrate.js": "text/javascript", "cues.js": "text/javascript", "panels.css": "text/css"})
MAX_LOGIN_BYTES = 4096
#: foreign Host headers logged (each once); later ones are refused without a log line
MAX_FOREIGN_HOSTS = 64

KEY = web.AppKey("console", object)


def _load_static() -> dict[str, bytes]:
    root = resources.files("coordinator.console") / "static"
    return {name: (root / name).read_bytes() for name in STATIC}


def client_address(request: web.Request) -> str:
    """The peer's address (no proxy is trusted: forwarded headers are ignored)."""
    return request.remote or "unknown"


def _error(cls: type[web.HTTPException], message: str, **kw) -> web.HTTPException:
    return cls(text=json.dumps({"ok": False, "error": message}), content_type="application/json", **kw)


class ConsoleApp:
    """The handlers, sharing the console's sessions, limiter, live view, actions and log."""

    def __init__(self, coord: "ConsoleRig", audit: "ActionLog", live: "Live", *, secure: bool,
                 idle_s: float = auth.IDLE_S):
        self.coord, self.audit, self.live, self.secure = coord, audit, live, secure
        self.sessions = auth.Sessions(idle_s=idle_s)
        self.limiter = auth.LoginLimiter()
        self.devices = auth.DeviceCookies(coord.token_key(auth.DEVICE_KEY_PURPOSE))
        self.hosts: HostCheck | None = None     # set once the console knows where it listens
        self.url = ""                           # where it does, for the refusal of a foreign Host
        self.foreign_hosts: set[str] = set()    # the Hosts refused so far (each logged once)
        self._global_said: float | None = None  # when the spent global login budget was last logged
        # logins since start, for the page: wrong tokens, refused while a limit held, the last wrong one
        self.logins = {"failed": 0, "refused": 0, "last_failed_at": None}
        self.users = UserStore(coord.rig.path)     # re-read whenever users.json changes on disk
        self._login_lock = asyncio.Lock()          # one login decided at a time (the limiter's rule)
        self.actions = Actions(coord, audit, live)
        self.static = _load_static()
        self._job_options: str | None = None

    # ------------------------------------------------------------------ checks
    def host_ok(self, request: web.Request) -> bool:
        """Whether the request's Host header names this console (an address or an allowed name)."""
        return self.hosts is not None and self.hosts.ok(request.headers.get("Host"))

    def origin_ok(self, request: web.Request) -> bool:
        """Whether a POST comes from this console's own page (its Origin is this scheme and
        Host, which :meth:`host_ok` checked)."""
        origin, host = request.headers.get("Origin"), request.headers.get("Host")
        if not origin or not host:
            return False
        return origin.lower() == f"{request.scheme}://{host}".lower()

    def _say_global_limit(self) -> None:
        """Log, at most once a minute, that the global login budget is spent (many addresses guessing)."""
        now = self.limiter.clock()
        if self._global_said is None or now - self._global_said >= 60.0:
            self._global_said = now
            log.warning("console: more than %d failed logins a minute from many addresses: logins from addresses "
                        "without a device cookie are tried once every %.0f s in all, addresses that failed last; "
                        "browsers that logged in here before are not held back",
                        self.limiter.budget, self.limiter.window_s / self.limiter.budget)

    def login_figures(self) -> dict:
        """What the page shows of logins: wrong tokens and refused logins since start, when the
        last wrong one came (Unix time), and whether new browsers are held back right now."""
        return {**self.logins, "held_back": self.limiter.held_back(),
                "budget_per_min": round(self.limiter.budget * 60.0 / self.limiter.window_s)}

    def session_of(self, request: web.Request, *, touch: bool = True) -> auth.Session | None:
        return self.sessions.get(request.cookies.get(auth.COOKIE), touch=touch)

    def role_now(self, session: auth.Session) -> Role | None:
        """The role ``session``'s person holds now (users.json is re-read when it changed): a
        token login is an admin; None when the user was removed, or their password set again
        since this session's login."""
        if session.who == TOKEN_WHO:
            return Role.ADMIN
        user = self.users.get(session.who)
        return user.role if user is not None and user.password_set == session.stamp else None

    def guard(self, handler: Callable[[web.Request, auth.Session], Awaitable[web.StreamResponse]], *,
              role: str | None = None):
        """A handler that needs a session; for POST also the Origin and the CSRF token. ``role`` is
        the least role it needs: by default ``operator`` for a POST (an action) and ``viewer``
        otherwise. The handler finds who acted in ``request["who"]`` and their role in
        ``request["role"]``."""
        fixed = Role(role) if role is not None else None

        async def wrapped(request: web.Request) -> web.StreamResponse:
            if request.method == "POST" and not self.origin_ok(request):
                raise _error(web.HTTPForbidden, "refused: the request does not come from the console's own page "
                                                "(Origin missing or foreign)")
            session = self.session_of(request)
            if session is None:
                raise _error(web.HTTPUnauthorized, "log in first (no session, or it expired)")
            if request.method == "POST" and not auth.csrf_ok(session, request.headers.get(auth.CSRF_HEADER)):
                raise _error(web.HTTPForbidden, f"refused: missing or wrong {auth.CSRF_HEADER} header; reload the page")
            now = self.role_now(session)
            if now is None:
                self.sessions.close(session.sid)
                raise _error(web.HTTPUnauthorized, f"log in again: user {session.who} was removed or given a new "
                                                   "password")
            session.role = now.value
            need = fixed or (Role.OPERATOR if request.method == "POST" else Role.VIEWER)
            if not now.allows(need):
                what = request.path.removeprefix("/api/") or request.path
                why = (f"refused: {session.who} is a {now}, and {what} needs the {need} role (an admin grants it: "
                       f"shadowless rig user role {session.who} {need})")
                if request.method == "POST":
                    await self.audit.record(who=session.who, address=client_address(request), action=what, ok=False,
                                            result=why)
                    self.live.poke()
                raise _error(web.HTTPForbidden, why)
            with warnings.catch_warnings():     # plain string keys on purpose: every handler module reads them
                warnings.simplefilter("ignore", web.NotAppKeyWarning)
                request["who"], request["role"] = session.who, session.role
            return await handler(request, session)

        return wrapped

    # ------------------------------------------------------------------ pages
    def _static(self, name: str) -> web.Response:
        return web.Response(body=self.static[name], content_type=STATIC[name], charset="utf-8",
                            headers={"Cache-Control": "no-cache"})

    async def index(self, request: web.Request) -> web.Response:
        return self._static("index.html")

    async def static_file(self, request: web.Request) -> web.Response:
        name = request.match_info["name"]
        if name not in STATIC or name == "index.html":
            raise web.HTTPNotFound()
        return self._static(name)

    # ------------------------------------------------------------------ login
    async def login(self, request: web.Request) -> web.Response:
        """``{"name": ..., "password": ...}`` (a user of the rig) or ``{"token": ...}`` (the rig
        token: an admin named ``token``)."""
        address = client_address(request)
        if not self.origin_ok(request):
            raise _error(web.HTTPForbidden, "refused: the login does not come from the console's own page")
        raw = await request.content.read(MAX_LOGIN_BYTES + 1)
        token, name, password = "", None, ""
        try:
            doc = json.loads(raw) if len(raw) <= MAX_LOGIN_BYTES else None
            if isinstance(doc, dict) and isinstance(doc.get("name"), str) and doc["name"].strip():
                name = doc["name"].strip().lower()[:64]
                password = doc["password"] if isinstance(doc.get("password"), str) else ""
            elif isinstance(doc, dict) and isinstance(doc.get("token"), str):
                token = doc["token"]
        except ValueError:
            pass
        # one login at a time from the limiter's check to its verdict: none slips past the same check
        async with self._login_lock:
            device = self.devices.verify(request.cookies.get(auth.DEVICE_COOKIE))
            wait, limit = self.limiter.wait(address, device, name)
            if wait:
                self.logins["refused"] += 1
                if limit == "global":
                    self._say_global_limit()
                why = {"address": f"too many failed logins from {address}",
                       "device": "too many failed logins from this browser",
                       "name": f"too many failed logins for {name}",
                       "global": "too many failed logins from many addresses"}[limit]
                raise _error(web.HTTPTooManyRequests, f"{why}: try again in {wait} s",
                             headers={"Retry-After": str(wait)})
            if name is not None:
                # a scrypt hash, off the event loop (an unknown name costs the same)
                role = await asyncio.to_thread(self.users.verify, name, password) if password else None
                who = name
            else:
                role = Role.ADMIN if token and self.coord.token_matches(token) else None
                who = TOKEN_WHO
            if role is None:
                self.limiter.failed(address, device, name)
                self.logins["failed"] += 1
                self.logins["last_failed_at"] = round(time.time())
                await self.audit.record(who="-", address=address, action="login", ok=False,
                                        result="wrong name or password" if name is not None else "wrong token",
                                        params={"name": name} if name is not None else None)
                self.live.poke()
                if name is not None:
                    raise _error(web.HTTPUnauthorized, "wrong name or password (or paste the rig's token with the "
                                                       "name left empty)")
                raise _error(web.HTTPUnauthorized, "wrong token: paste the rig's token (the file `token` in the rig "
                                                   "directory), or log in with your name and password")
            self.limiter.succeeded(address, device, name)
        user = self.users.get(who) if name is not None else None
        session = self.sessions.open(address, who=who, role=role.value, stamp=user.password_set if user else "")
        await self.audit.record(who=session.who, address=address, action="login", ok=True,
                                result=f"logged in as {role}")
        self.live.poke()
        resp = web.json_response({"ok": True, "csrf": session.csrf, "who": session.who, "role": session.role})
        resp.set_cookie(auth.COOKIE, session.sid, httponly=True, samesite="Strict", secure=self.secure, path="/")
        # this browser's logins are then limited by its own failures only (auth's module docstring)
        resp.set_cookie(auth.DEVICE_COOKIE, self.devices.issue(device), httponly=True, samesite="Strict",
                        secure=self.secure, path="/login", max_age=auth.DEVICE_MAX_AGE_S)
        return resp

    async def logout(self, request: web.Request, session: auth.Session) -> web.Response:
        self.sessions.close(session.sid)
        await self.audit.record(who=session.who, address=client_address(request), action="logout", ok=True,
                                result="logged out")
        self.live.poke()
        resp = web.json_response({"ok": True})
        resp.del_cookie(auth.COOKIE, path="/", samesite="Strict", secure=self.secure, httponly=True)
        return resp

    async def session_info(self, request: web.Request, session: auth.Session) -> web.Response:
        return web.json_response({"ok": True, "csrf": session.csrf, "who": session.who, "role": session.role})

    # ------------------------------------------------------------------ the rig
    async def status(self, request: web.Request, session: auth.Session) -> web.Response:
        return web.Response(text=self.live.current(), content_type="application/json")

    async def job_options(self, request: web.Request, session: auth.Session) -> web.Response:
        """Every job's options (name, kind, default, choices, bounds, group, help), for its form."""
        if self._job_options is None:
            def build() -> dict:
                out = {}
                for kind in JOBS:
                    try:
                        out[kind] = helps_for_the_page(form_fields(resolve(kind).options))   # no flags
                    except JobError as exc:      # a job whose libraries this install lacks
                        out[kind] = {"unavailable": str(exc)}
                return out
            self._job_options = json.dumps(await asyncio.to_thread(build), allow_nan=False)
        return web.Response(text=self._job_options, content_type="application/json")

    async def events(self, request: web.Request, session: auth.Session) -> web.StreamResponse:
        sid = session.sid
        return await self.live.stream(request, lambda: self.sessions.get(sid, touch=False) is not None,
                                      headers=SECURITY_HEADERS)


@web.middleware
async def host_check(request: web.Request, handler) -> web.StreamResponse:
    """Every request names the console in its Host header, or is answered 421 with one line."""
    console: ConsoleApp = request.app[KEY]
    if not console.host_ok(request):
        host = request.headers.get("Host")
        if console.hosts is None:
            raise _error(web.HTTPMisdirectedRequest, "refused: the console is not listening yet")
        message = console.hosts.refusal(host, console.url)
        key = (host or "")[:100]
        if key not in console.foreign_hosts and len(console.foreign_hosts) < MAX_FOREIGN_HOSTS:
            console.foreign_hosts.add(key)      # said once per Host: a page retrying cannot flood the log
            log.warning("console: %s (from %s)", message, client_address(request))
        raise _error(web.HTTPMisdirectedRequest, message)
    return await handler(request)


@web.middleware
async def security_headers(request: web.Request, handler) -> web.StreamResponse:
    """The security headers on every answer, errors included; nothing under /api/ is cached."""
    try:
        resp = await handler(request)
    except web.HTTPException as exc:
        exc.headers.update(SECURITY_HEADERS)
        exc.headers.setdefault("Cache-Control", "no-store")
        raise
    if not resp.prepared:       # an event stream set its own before it started
        resp.headers.update(SECURITY_HEADERS)
        if request.path.startswith(("/api/", "/login", "/logout")):
            resp.headers["Cache-Control"] = "no-store"
    return resp


def make_app(console: ConsoleApp) -> web.Application:
    app = web.Application(middlewares=[security_headers, host_check], client_max_size=MAX_UPLOAD_BYTES + (1 << 20))
    app[KEY] = console
    c, a = console, console.actions
    app.router.add_get("/", c.index)
    app.router.add_get("/static/{name}", c.static_file)
    app.router.add_post("/login", c.login)
    app.router.add_post("/logout", c.guard(c.logout, role="viewer"))
    app.router.add_get("/api/session", c.guard(c.session_info))
    people = People(c.users, c.sessions, a)
    app.router.add_get("/api/users", c.guard(people.listing, role="admin"))
    app.router.add_post("/api/users", c.guard(people.add, role="admin"))
    app.router.add_post("/api/users/role", c.guard(people.set_role, role="admin"))
    app.router.add_post("/api/users/remove", c.guard(people.remove, role="admin"))
    app.router.add_get("/api/status", c.guard(c.status))
    app.router.add_get("/api/events", c.guard(c.events))
    app.router.add_get("/api/job/options", c.guard(c.job_options))
    app.router.add_post("/api/stop", c.guard(a.stop))
    app.router.add_post("/api/blackout", c.guard(a.blackout))
    app.router.add_post("/api/identify", c.guard(a.identify))
    app.router.add_post("/api/gain", c.guard(a.gain))
    app.router.add_post("/api/show", c.guard(a.show))
    app.router.add_post("/api/play", c.guard(a.play))
    app.router.add_post("/api/job", c.guard(a.job))
    app.router.add_post("/api/job/cancel", c.guard(a.cancel_job))
    tools = SlotRoutes(a)
    app.router.add_post("/api/solo", c.guard(tools.solo))
    app.router.add_post("/api/pattern", c.guard(tools.pattern))
    p = Pictures(console.coord)
    app.router.add_get("/api/pictures", c.guard(p.listing))
    app.router.add_get("/api/pictures/{name}", c.guard(p.picture))
    app.router.add_get("/api/camera.png", c.guard(p.camera))
    app.router.add_get("/api/thumbnail/{slot}", c.guard(Thumbnails(console.coord).thumbnail))
    cue_routes.register(app, console)
    return app
