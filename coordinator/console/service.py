"""The operator console's web server, in the coordinator's event loop.

``Console(rig, "127.0.0.1:7680", tls=...)``, ``await start()``, ``await stop()``; :attr:`port`
is the port it listens on (port 0 picks a free one). ``rig`` is the coordinator as the console
sees it (:class:`coordinator.ports.ConsoleRig`). It serves HTTPS with the coordinator's
certificate when it is given one (``tls``), plain HTTP otherwise. It answers
only requests whose Host names it: an address it listens on, or one of ``hosts`` (the
``--console-host`` allow-list; :mod:`coordinator.console.hosts`).
"""
from __future__ import annotations

import ipaddress
import logging
import os
import ssl
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

from aiohttp import web
from aiohttp.http_exceptions import HttpProcessingError

from coordinator.console import auth
from coordinator.console.app import ConsoleApp, make_app
from coordinator.console.audit import ActionLog
from coordinator.console.hosts import HostCheck, check_allowed
from coordinator.console.live import Live
from coordinator.errors import CoordinatorError
from coordinator.ports import ConsoleRig

log = logging.getLogger(__name__)

#: where the console listens unless the operator says otherwise
DEFAULT_LISTEN = "127.0.0.1:7680"


def parse_listen(listen: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[v6]:PORT`` for IPv6) -> (host, port); CoordinatorError naming the form."""
    host, sep, port = str(listen).strip().rpartition(":")
    host = host.strip("[]")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise CoordinatorError(f"console address {listen!r} must be HOST:PORT, e.g. {DEFAULT_LISTEN} "
                               "(port 0: any free port; [::1]:7680 for IPv6)")
    return host, int(port)


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class HttpLog(logging.LoggerAdapter):
    """What the console's HTTP server logs. A request aiohttp could not parse (a bad header, a
    duplicate Host, random bytes) becomes one WARNING line naming the peer and the reason, with
    no traceback, at most one every ``every_s`` seconds (then with the count since); every other
    record passes unchanged. ``clock`` is monotonic seconds (injectable)."""

    def __init__(self, logger: logging.Logger, *, every_s: float = 10.0, clock=time.monotonic):
        super().__init__(logger, {})
        self.every_s, self.clock = every_s, clock
        self._last: float | None = None
        self._since = 0

    def log(self, level, msg, *args, exc_info=None, **kw):
        exc = sys.exc_info()[1] if exc_info is True else exc_info[1] if isinstance(exc_info, tuple) else exc_info
        if level < logging.ERROR or not isinstance(exc, HttpProcessingError):
            self.logger.log(level, msg, *args, exc_info=exc_info, **kw)
            return
        now = self.clock()
        if self._last is not None and now - self._last < self.every_s:
            self._since += 1
            return
        more = f" ({self._since} more since)" if self._since else ""
        self._last, self._since = now, 0
        peer = args[0] if args else "?"
        reason = " ".join(str(exc.message or exc).split())[:200]
        self.logger.warning("console: refused a malformed request from %s: %s%s", peer, reason, more)


def ssl_context(tls: tuple[bytes, bytes]) -> ssl.SSLContext:
    """A server context for the PEM certificate (chain) and key (loaded from private temp files)."""
    cert, key = tls
    ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    with tempfile.TemporaryDirectory(prefix="shadowless-console-") as d:
        paths = []
        for name, data in (("cert.pem", cert), ("key.pem", key)):
            p = Path(d) / name
            fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            paths.append(p)
        try:
            ctx.load_cert_chain(paths[0], paths[1])
        except ssl.SSLError as exc:
            raise CoordinatorError(f"the console cannot use the coordinator's TLS certificate and key: {exc}") from exc
    return ctx


def _nothing() -> None:
    pass


class Console:
    """The operator console of ``coordinator``, listening on ``listen`` (``HOST:PORT``); with
    ``tls`` (PEM certificate chain and key) it serves HTTPS."""

    def __init__(self, coordinator: ConsoleRig, listen: str = DEFAULT_LISTEN, *, idle_s: float = auth.IDLE_S,
                 hosts: list[str] | tuple[str, ...] = (), tls: tuple[bytes, bytes] | None = None):
        self.coord = coordinator
        self.tls = tls
        self.listen = listen
        self.host, self._port = parse_listen(listen)
        try:
            self.hosts = tuple(check_allowed(h) for h in hosts)
        except ValueError as exc:
            raise CoordinatorError(f"console host {exc}") from None
        self.http_log = HttpLog(logging.getLogger("coordinator.console.http"))
        self.idle_s = idle_s
        self.port = 0
        self.secure = tls is not None
        self.app: ConsoleApp | None = None
        self._runner: web.AppRunner | None = None
        self._unlisten_jobs: Callable[[], None] = _nothing

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{'https' if self.secure else 'http'}://{host}:{self.port}/"

    async def start(self) -> None:
        ctx = ssl_context(self.tls) if self.tls is not None else None
        audit = ActionLog(self.coord.rig.path)
        live = Live(self.coord, audit)
        self.app = ConsoleApp(self.coord, audit, live, secure=self.secure, idle_s=self.idle_s)
        live.logins = self.app.login_figures
        runner = web.AppRunner(make_app(self.app), access_log=None, handle_signals=False, shutdown_timeout=2.0,
                               logger=self.http_log)
        await runner.setup()
        try:
            site = web.TCPSite(runner, self.host, self._port, ssl_context=ctx)
            await site.start()
        except OSError as exc:
            await runner.cleanup()
            raise CoordinatorError(f"the console cannot listen on {self.listen}: {exc}") from exc
        self._runner = runner
        self.port = int(runner.addresses[0][1])
        try:
            ipaddress.ip_address(self.host)
            names: tuple[str, ...] = ()
        except ValueError:
            names = (self.host,)        # listening on a name: browsers may use it
        self.app.hosts = HostCheck([(a[0], int(a[1])) for a in runner.addresses], scheme="https" if self.secure
                                   else "http", names=names, allowed=self.hosts)
        self.app.url = self.url.replace("//0.0.0.0:", "//127.0.0.1:").replace("//[::]:", "//[::1]:")
        live.start()
        self._unlisten_jobs = self.coord.listen_jobs(live.poke)   # a job's progress reaches the page as it happens
        if not is_loopback(self.host):
            log.warning("the operator console at %s is reachable from other machines%s", self.url,
                        "" if self.secure else " WITHOUT TLS: the token and the session travel in clear; give the "
                                               "coordinator a certificate")
        log.info("operator console at %s", self.url)

    async def stop(self) -> None:
        self._unlisten_jobs()
        self._unlisten_jobs = _nothing
        if self.app is not None:
            await self.app.live.stop()      # the open event streams end
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None
