"""The composition root: a coordinator as a process serves it.

:class:`CoordinatorApp` builds the core :class:`~coordinator.server.Coordinator` (which takes no
transport), the gRPC services (:func:`coordinator.wire.serve.serve`), the operator console
(:class:`coordinator.console.Console`) and the mDNS :class:`~coordinator.mdns.Advertiser` side by
side, and starts and stops them in order. It is the one module that knows all of them; each of
them sees the core through a Protocol of :mod:`coordinator.ports`.

Start: the advertiser is made first (a mistyped ``--mdns-interface`` is refused before anything
starts); then the core takes the rig's lock and settles what a crash left; then the services
listen, the console listens, the advertiser announces, and the core watches its nodes. A start
refused part-way undoes what it began, so the next try (with other options) may take the rig.
Stop: the console, health NOT_SERVING, mDNS unregister, node streams closed, the server stopped,
and last the core (playback ends, the rig's lock is freed).
"""
from __future__ import annotations

import dataclasses
import errno
import logging
import time
from typing import Any, Callable

from coordinator.errors import OPERATOR_ERRORS, CoordinatorError
from coordinator.mdns import Advertiser
from coordinator.rig import Rig
from coordinator.server import Coordinator
from coordinator.wire.frame_packets import FramePackets
from coordinator.wire.serve import serve
from protos import sd_notify

log = logging.getLogger(__name__)


class CoordinatorApp:
    """A coordinator with its edges. Create, ``await start()``, ``await stop()``.

    Parameters
    ----------
    rig : Rig
    token : bytes
        The rig's secret.
    listen : str
        gRPC address, e.g. ``0.0.0.0:7600`` (port 0: any free port, see :attr:`port`).
    mdns_interfaces : list of str, optional
        Advertise on these IPv4 addresses only.
    advertise : bool
        Advertise over mDNS.
    tls : (cert, key), optional
        PEM certificate chain and key, for the gRPC services and the console alike.
    latency_ms, cameras, clock_ns
        Given to the core (:class:`~coordinator.server.Coordinator`).
    console : str, optional
        Serve the operator console (a web page) on this ``HOST:PORT`` (see :attr:`console_port`).
    console_hosts : list of str, optional
        Names (``NAME`` or ``NAME:PORT``) a browser may use for the console besides the addresses it listens on.
    console_optional : bool
        A console that cannot listen is said loudly (the log, ``status``) and the rig runs on;
        by default :meth:`start` refuses with one line instead.
    """

    def __init__(self, rig: Rig, token: bytes, *, listen: str = "0.0.0.0:7600", mdns_interfaces: list[str] | None = None,
                 advertise: bool = True, tls: tuple[bytes, bytes] | None = None, latency_ms: float | None = None,
                 cameras: list[str] | None = None, clock_ns: Callable[[], int] = time.monotonic_ns,
                 console: str | None = None, console_hosts: list[str] | None = None, console_optional: bool = False,
                 mtc_port: str | None = None):
        self.listen, self.tls = listen, tls
        self.mdns_interfaces, self.advertise = mdns_interfaces, advertise
        self.console_listen, self.console_optional = console, console_optional
        self.console_hosts = list(console_hosts or ())
        self.mtc_port = mtc_port    # MIDI timecode's port, over rig.toml's [osc] mtc_port
        #: what `status` says of the console: its address, "NOT SERVED (why)" or "off"
        self.console_state = "off" if console is None else "starting"
        self.port = 0               # the gRPC port, once listening
        self.console_port = 0       # the console's port, once listening
        self.coordinator = Coordinator(rig, token, encoding=FramePackets, latency_ms=latency_ms, cameras=cameras,
                                       clock_ns=clock_ns, console_state=lambda: self.console_state)
        self.console: Any = None    # the Console, once it listens (coordinator.console.Console)
        self.osc: Any = None        # show control over OSC, once it listens (coordinator.osc.service.OscService)
        self._server: Any = None      # the gRPC server (coordinator.wire.serve)
        self._health: Any = None
        self._advertiser: Advertiser | None = None

    async def start(self) -> None:
        """Listen, register the services (health and reflection too), serve the console, advertise,
        watch the nodes. Takes the rig directory's lock first: RigLockError if another coordinator
        serves it."""
        coord = self.coordinator
        config = coord.rig.config
        # made first: a mistyped --mdns-interface is refused before anything starts
        advertiser = (Advertiser(rig_name=config.name, rig_id=config.rig_id, instance_id=coord.instance_id,
                                 interfaces=self.mdns_interfaces)
                      if self.advertise else None)
        coord.open()
        try:
            self._server, self._health, self.port = await serve(coord, self.listen, tls=self.tls)
            if self.console_listen is not None:
                await self._start_console()
            await self._start_osc()
            if advertiser is not None:
                self._advertiser = advertiser
                await advertiser.start(self.port)
        except BaseException:
            await self._undo_start()
            raise
        coord.start()
        log.info("coordinator for rig %r (%s) listening on port %d, instance %s",
                 config.name, config.rig_id, self.port, coord.instance_id)
        # under systemd (Type=notify): ready now
        sd_notify.notify("READY=1", f"STATUS=rig {config.name} on port {self.port}")

    async def _undo_start(self) -> None:
        """Stop what a refused :meth:`start` had begun (mDNS, OSC, console, gRPC server) and free the rig's lock."""
        if self.osc is not None:
            await self.osc.stop()
            self.osc = None
        if self._advertiser is not None:
            await self._advertiser.stop()
            self._advertiser = None
        if self.console is not None:
            await self.console.stop()
            self.console = None
        if self._server is not None:
            await self._server.stop(0)
            self._server = None
        await self.coordinator.close()

    async def _start_console(self) -> None:
        """Serve the operator console. One that cannot listen (its port taken: the operator's browser
        would reach whatever holds it) stops the start with one line, unless it is optional: then
        the rig runs on and says so in the log and in ``status``."""
        from coordinator.console import Console   # aiohttp only when the console is wanted
        listen = self.console_listen
        console = Console(self.coordinator, listen, hosts=self.console_hosts, tls=self.tls)
        try:
            await console.start()
        except OPERATOR_ERRORS as exc:
            why = bind_failure(exc, listen)
            if not self.console_optional:
                raise CoordinatorError(f"the operator console cannot listen on {listen}: {why}; choose "
                                       "another --console HOST:PORT, --no-console, or --console-optional to run "
                                       "without it") from None
            self.console_state = f"NOT SERVED ({why})"
            log.error("console: NOT SERVED (%s): the rig runs on without its page (--console-optional)", why)
        else:
            self.console, self.console_port = console, console.port
            host = listen.rpartition(":")[0].strip("[]") or "0.0.0.0"
            scheme = "https" if self.tls is not None else "http"
            self.console_state = f"{scheme}://{host}:{console.port}/"

    async def _start_osc(self) -> None:
        """Show control over OSC, when rig.toml's ``[osc]`` names where to listen (a bad table or a
        port it cannot take stops the start with one line). Its commands go to the console's action log."""
        from coordinator.osc.config import load_osc
        config = load_osc(self.coordinator.rig.path)
        if self.mtc_port:
            config = dataclasses.replace(config, mtc_port=self.mtc_port)
        if not config.on:
            return
        from coordinator.console.audit import ActionLog
        from coordinator.osc.service import OscService     # python-osc only when OSC is wanted
        page = self.console.app if self.console is not None else None      # one action log for both
        audit = page.audit if page is not None else ActionLog(self.coordinator.rig.path)
        osc = OscService(self.coordinator, config, audit, poke=page.live.poke if page is not None else (lambda: None))
        await osc.start()
        self.osc = osc

    async def stop(self, grace: float = 2.0) -> None:
        """Graceful shutdown: health NOT_SERVING, mDNS unregister, streams closed, server stopped."""
        sd_notify.notify("STOPPING=1")
        if self.osc is not None:
            await self.osc.stop()
        if self.console is not None:
            await self.console.stop()
        if self._health is not None:
            await self._health.enter_graceful_shutdown()
        if self._advertiser is not None:
            try:
                await self._advertiser.stop()
            except Exception:  # pragma: no cover - best effort on shutdown
                log.exception("mDNS unregister failed")
        self.coordinator.end_sessions()
        if self._server is not None:
            await self._server.stop(grace)
        await self.coordinator.close()


def bind_failure(exc: BaseException, listen: str) -> str:
    """Why a listener could not bind, in a few words: ``port 7680 in use`` for the usual case."""
    cause = exc.__cause__
    port = listen.rpartition(":")[2]
    if isinstance(cause, OSError) and cause.errno == errno.EADDRINUSE:
        return f"port {port} in use"
    if isinstance(cause, OSError) and cause.errno == errno.EADDRNOTAVAIL:
        return f"address {listen.rpartition(':')[0]} is not on this host"
    if isinstance(cause, OSError) and cause.strerror:
        return cause.strerror.lower()
    return str(exc)
