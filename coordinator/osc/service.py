"""The OSC show-control server: a UDP socket in the coordinator's event loop.

Each datagram is checked against the allow-list before anything is read from it; one from
another address is dropped, and the log says so once a minute per address (with the count since).
A datagram from an allowed sender is parsed by python-osc (a message or a bundle of them; a
bundle's time tag is not waited for: its messages run at once, in order) and each message runs its
command (:mod:`coordinator.osc.commands`) as ``osc:<sender ip>``; every command, done or refused,
lands in the rig's action log, and a refusal is also answered to the sender as
``/shadowless/error ADDRESS REASON``. ``/shadowless/status`` is answered to the sender's address
and port; the status (:mod:`coordinator.osc.feedback`) goes to the feedback targets and the
subscribed senders whenever it changes (checked a few times a second, only while someone listens).
``/shadowless/timecode`` keeps the latest external clock; while it is fresh (a message in the last
second) a playing show is checked against it a few times a second and seeks when it is off
(:mod:`coordinator.osc.timecode`). MIDI timecode from ``mtc_port`` (:mod:`coordinator.osc.mtc`,
read by :mod:`coordinator.osc.mtc_input`) is the same external clock, chased the same way: the
same threshold, the same hold after a seek, and the same stop (MTC that stops is no longer fresh
after a second). With ``mtc_port`` and no ``listen``, only the chase runs.
"""
from __future__ import annotations

import asyncio
import inspect
import ipaddress
import logging
import math
import socket
import time
from typing import TYPE_CHECKING, Any, Callable

from pythonosc.osc_message_builder import OscMessageBuilder
from pythonosc.osc_packet import OscPacket, ParseError

from coordinator.cues import edge_logs
from coordinator.errors import OPERATOR_ERRORS, CoordinatorError, Refusal
from coordinator.osc import commands, timecode
from coordinator.osc.config import OscConfig
from coordinator.osc.feedback import feedback

if TYPE_CHECKING:  # pragma: no cover - types only
    from coordinator.console.audit import ActionLog
    from coordinator.osc.commands import OscRig

log = logging.getLogger(__name__)

PREFIX = commands.PREFIX
#: how often the status is compared with what was last sent, and a fresh timecode with the show (s)
TICK_S = 0.25
#: a subscription lasts this long unless renewed (s)
SUBSCRIBE_S = 600.0
SUBSCRIBERS_MAX = 32
#: a timecode older than this no longer moves the show (the external clock stopped)
TIMECODE_FRESH_S = 1.0
#: after a seek, the show is left to settle this long before it is compared again (s)
SEEK_HOLD_S = 0.5
#: the least lead of a chase's seek (the show's own changes take the latency budget, at least this)
MIN_LEAD_NS = 150_000_000
#: senders off the allow-list (and malformed datagrams) are logged once per this many seconds per address
SAY_EVERY_S = 60.0
SAID_MAX = 1024
MAX_DATAGRAM = 65507


def encode(address: str, args: tuple[Any, ...]) -> bytes:
    """One OSC message's datagram (ints as 32-bit ints, floats as 32-bit floats, text as strings)."""
    b = OscMessageBuilder(address=address)
    for a in args:
        if isinstance(a, bool):
            b.add_arg(a)
        elif isinstance(a, int):
            b.add_arg(max(-(1 << 31), min(a, (1 << 31) - 1)))
        elif isinstance(a, float):
            b.add_arg(a if math.isfinite(a) else 0.0)
        else:
            b.add_arg(str(a)[:1000])
    return b.build().dgram


def _loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


#: the addresses the service answers itself (the name of the method that does), not through
#: :func:`coordinator.osc.commands.run`: they are not rig commands and are not logged
_OWN: dict[str, str] = {
    f"{PREFIX}/status": "_status",
    f"{PREFIX}/subscribe": "_subscription",
    f"{PREFIX}/unsubscribe": "_subscription",
    f"{PREFIX}/timecode": "_timecode",
}
#: every address show control answers (any other is refused as unknown): the rig commands and the service's own
ANSWERED: frozenset[str] = frozenset(commands.COMMANDS) | frozenset(_OWN)


def _port(value: Any) -> int | None:
    """A UDP port from an OSC argument: a whole number (:func:`commands.whole_number`: an int, or a
    float such as TouchDesigner's 9001.0) in 1..65535; None for anything else."""
    port = commands.whole_number(value)
    return port if port is not None and 1 <= port <= 65535 else None


class _Protocol(asyncio.DatagramProtocol):
    def __init__(self, service: "OscService"):
        self.service = service

    def datagram_received(self, data: bytes, addr: tuple) -> None:
        self.service.received(data, addr)

    def error_received(self, exc: Exception) -> None:      # e.g. a feedback target's port is closed (ICMP)
        log.debug("OSC: %s", exc)


class OscService:
    """Show control over OSC for ``coord`` as ``config`` says; every command to ``audit``.
    ``poke`` is called after each logged entry (the console's live view). Create, ``await
    start()``, ``await stop()``; :attr:`port` is the UDP port once listening."""

    def __init__(self, coord: "OscRig", config: OscConfig, audit: "ActionLog", *,
                 poke: Callable[[], None] = lambda: None, clock: Callable[[], float] = time.monotonic):
        if not config.on:
            raise ValueError("show control is off in this configuration (no listen address, no mtc_port)")
        self.coord, self.config, self.audit, self.poke, self.clock = coord, config, audit, poke, clock
        self.port = 0
        self.ignored: dict[str, int] = {}           # sender address -> datagrams dropped (off the allow-list)
        self.handled = 0                            # messages from allowed senders
        self._said: dict[str, tuple[float, int]] = {}   # address -> (last logged, dropped since)
        self._subscribers: dict[tuple[str, int], float] = {}   # (host, port) -> until (clock)
        self._targets: list[tuple] = []             # the feedback targets, resolved
        self._last_key: tuple | None = None
        #: the last external clock: (seconds, rig ns, clock, who, address)
        self._tc: tuple[float, int, float, str, str] | None = None
        self.mtc: Any = None                        # the MIDI timecode input (coordinator.osc.mtc_input.MtcInput)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._hold_until = 0.0
        self._transport: asyncio.DatagramTransport | None = None
        self._task: asyncio.Task | None = None
        self._wake = asyncio.Event()
        self._pending: set[asyncio.Task] = set()

    @property
    def url(self) -> str:
        if self.config.listen is None:
            return "off"
        host = self.config.listen[0]
        return f"udp://{'[' + host + ']' if ':' in host else host}:{self.port}"

    # ------------------------------------------------------------------ life
    async def start(self) -> None:
        loop = self._loop = asyncio.get_running_loop()
        if self.config.mtc_port is not None:
            from coordinator.osc.mtc_input import MtcInput     # mido only when MTC is wanted
            mtc = MtcInput(self.config.mtc_port, self.mtc_readings, self.coord.rig_now)
            await asyncio.to_thread(mtc.open)       # CoordinatorError in one line: no library, no such port
            self.mtc = mtc
        if self.config.listen is None:
            self._task = asyncio.create_task(self._tick_loop(), name="osc feedback")
            return
        host, port = self.config.listen
        for t_host, t_port in self.config.feedback:
            try:
                infos = await loop.getaddrinfo(t_host, t_port, type=socket.SOCK_DGRAM)
                self._targets.append(infos[0][4][:2])
            except OSError as exc:
                log.error("OSC: feedback target %s:%d cannot be resolved (%s): left out", t_host, t_port, exc)
        try:
            transport, _ = await loop.create_datagram_endpoint(lambda: _Protocol(self), local_addr=(host, port))
        except OSError as exc:
            if self.mtc is not None:
                self.mtc.close()
            raise CoordinatorError(f"show control cannot listen on udp {host}:{port}: {exc.strerror or exc}; "
                                   "choose another [osc] listen in rig.toml") from None
        self._transport = transport
        self.port = int(transport.get_extra_info("sockname")[1])
        self._task = asyncio.create_task(self._tick_loop(), name="osc feedback")
        allow = ", ".join(str(n) for n in self.config.allow)
        if not _loopback(host) and all(n.is_loopback for n in self.config.allow):
            log.warning("OSC listens on %s but hears this machine only: name the show controllers in [osc] allow "
                        "of rig.toml (e.g. allow = [\"10.0.0.0/24\"])", self.url)
        log.info("show control over OSC on %s, hearing %s (OSC has no authentication: anyone who can send from "
                 "those addresses drives the show)", self.url, allow)

    async def stop(self) -> None:
        if self.mtc is not None:
            self.mtc.close()
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)
            self._task = None
        if self._transport is not None:
            self._transport.close()
            self._transport = None
        if self._pending:
            await asyncio.gather(*self._pending, return_exceptions=True)

    # ------------------------------------------------------------------ receiving
    def _say(self, address: str, what: str) -> None:
        """Log ``what`` about ``address`` at most once a minute, with the count since."""
        now = self.clock()
        last = self._said.get(address)
        if last is not None and now - last[0] < SAY_EVERY_S:
            self._said[address] = (last[0], last[1] + 1)
            return
        more = f" ({last[1]} more since)" if last and last[1] else ""
        if last is None and len(self._said) >= SAID_MAX:
            self._said.pop(next(iter(self._said)))
        self._said[address] = (now, 0)
        log.warning("OSC: %s%s", what, more)

    def received(self, data: bytes, addr: tuple) -> None:
        ip, port = str(addr[0]), int(addr[1])
        if not self.config.allows(ip):
            self.ignored[ip] = self.ignored.get(ip, 0) + 1
            if len(self.ignored) > SAID_MAX:
                self.ignored.pop(next(iter(self.ignored)))
            self._say(ip, f"ignored a message from {ip}: not in [osc] allow of rig.toml "
                          f"({', '.join(str(n) for n in self.config.allow)})")
            return
        try:
            messages = OscPacket(data).messages
        except (ParseError, ValueError, IndexError, TypeError) as exc:
            self._say(ip, f"could not read a datagram from {ip} as OSC ({' '.join(str(exc).split())[:120]})")
            return
        for timed in messages:
            self.handled += 1
            self._handle(timed.message.address, list(timed.message.params), (ip, port))

    def _handle(self, address: str, args: list, sender: tuple[str, int]) -> None:
        who = f"osc:{sender[0]}"
        own = _OWN.get(address)
        if own is not None:         # status, subscriptions, timecode: not rig commands, not logged
            getattr(self, own)(address, args, sender, who)
            return
        params = {"address": address[:200], "args": [a[:200] if isinstance(a, str) else a if isinstance(
            a, (int, float, bool)) else repr(a)[:200] for a in args[:8]]}
        action = address.removeprefix(PREFIX + "/")[:80] if address.startswith(PREFIX + "/") else address[:80]
        try:
            with edge_logs():       # this command's entry is the one: a cue it fires is not logged twice
                result = commands.run(self.coord, address, args, who=who)
        except (commands.OscError, ValueError) as exc:
            self._refused(sender, who, action, address, str(exc), params)
            return
        except Refusal as exc:
            self._refused(sender, who, action, address, exc.message, params)
            return
        except OPERATOR_ERRORS as exc:
            self._refused(sender, who, action, address, str(exc), params)
            return
        except Exception as exc:  # noqa: BLE001 - the sender hears that it failed, the log says why
            log.exception("OSC command %s failed", address)
            self._refused(sender, who, action, address, f"internal error ({type(exc).__name__}): {exc}", params)
            return
        if inspect.isawaitable(result):
            self._spawn(self._finish(result, sender, who, action, address, params))
            return
        self._spawn(self._record(who, sender, action, True, str(result), params))

    async def _finish(self, pending, sender, who, action, address, params) -> None:
        try:
            result = await pending
        except Exception as exc:  # noqa: BLE001 - as for a command that refuses at once
            text = " ".join((exc.message if isinstance(exc, Refusal) else str(exc)).split())   # one line, as at once
            self._send([sender], [(f"{PREFIX}/error", (address, text))])
            await self._record(who, sender, action, False, text, params)
            return
        await self._record(who, sender, action, True, str(result), params)

    def _refused(self, sender, who: str, action: str, address: str, why: str, params: dict) -> None:
        why = " ".join(why.split())
        self._send([sender], [(f"{PREFIX}/error", (address, why))])
        self._spawn(self._record(who, sender, action, False, why, params))

    def _spawn(self, coro) -> None:
        task = asyncio.get_running_loop().create_task(coro)
        self._pending.add(task)
        task.add_done_callback(self._pending.discard)

    async def _record(self, who: str, sender: tuple[str, int], action: str, ok: bool, result: str,
                      params: dict) -> None:
        edge = "mtc" if who.startswith("mtc:") else "osc"
        await self.audit.record(who=who, address=sender[0], action=f"{edge} {action}", ok=ok, result=result,
                                params=params)
        self.poke()
        self._wake.set()        # the status may have changed: compare it now

    # ------------------------------------------------------------------ status, subscriptions, timecode
    def _status(self, address: str, args: list, sender: tuple[str, int], who: str) -> None:
        self._send_status([sender])

    def _subscription(self, address: str, args: list, sender: tuple[str, int], who: str) -> None:
        port = sender[1]
        if args:
            port = _port(args[0])
            if port is None:
                self._send([sender], [(f"{PREFIX}/error", (address, f"PORT must be a whole number 1..65535, "
                                                                    f"got {args[0]!r}"))])
                return
        key = (sender[0], port)
        if address.endswith("/unsubscribe"):
            self._subscribers.pop(key, None)
            return
        if key not in self._subscribers and len(self._subscribers) >= SUBSCRIBERS_MAX:
            oldest = min(self._subscribers, key=self._subscribers.get)
            del self._subscribers[oldest]
        self._subscribers[key] = self.clock() + SUBSCRIBE_S
        self._send_status([key])

    def _timecode(self, address: str, args: list, sender: tuple[str, int], who: str) -> None:
        fps = self.config.timecode_fps
        try:
            if len(args) == 2 and isinstance(args[1], (int, float)) and not isinstance(args[1], bool) \
                    and 1 <= args[1] <= 1000:
                fps = float(args[1])
            elif len(args) != 1:
                raise ValueError(f"{PREFIX}/timecode takes one argument (\"hh:mm:ss:ff\" or seconds) and an "
                                 f"optional FPS, got {len(args)}")
            seconds = timecode.timecode_seconds(args[0], fps)
        except ValueError as exc:
            self._say(f"timecode {sender[0]}", f"timecode from {sender[0]} refused: {exc}")
            self._send([sender], [(f"{PREFIX}/error", (f"{PREFIX}/timecode", str(exc)))])
            return
        self.external_clock(seconds, self.coord.rig_now(), who, sender[0])

    def external_clock(self, seconds: float, at_ns: int, who: str, address: str) -> None:
        """The external clock says ``seconds`` (timecode, before ``timecode_offset_s``) at rig time
        ``at_ns``: what the chase follows from now on (OSC and MIDI timecode alike)."""
        self._tc = (seconds - self.config.timecode_offset_s, at_ns, self.clock(), who, address)
        self._wake.set()

    def mtc_readings(self, port: str, readings: list) -> None:
        """MIDI timecode readings of ``port`` (:class:`coordinator.osc.mtc.Reading`), from any thread
        (rtmidi's): the newest goes to the chase in the event loop."""
        loop, r = self._loop, readings[-1]
        if loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(self.external_clock, r.seconds, r.at_ns, f"mtc:{port}", "midi")

    @property
    def clock_fresh(self) -> bool:
        """Whether an external clock (OSC or MIDI timecode) arrived in the last TIMECODE_FRESH_S."""
        return self._tc is not None and self.clock() - self._tc[2] <= TIMECODE_FRESH_S

    def _chase(self) -> None:
        """Seek the playing show when a fresh external clock is further off than the threshold."""
        tc = self._tc
        now = self.clock()
        if not self.clock_fresh or now < self._hold_until:
            return
        status = self.coord.status()
        lead = max(MIN_LEAD_NS, int(status.latency_budget_ms * 1e6))
        seek = timecode.chase(tc[0], tc[1], status.show, self.coord.rig_now(),
                              threshold_s=self.config.chase_threshold_ms / 1e3, lead_ns=lead)
        if seek is None:
            return
        self._hold_until = now + SEEK_HOLD_S
        direction = "behind" if seek.drift_s > 0 else "ahead of"
        params = {"frame": seek.frame, "drift_ms": round(seek.drift_s * 1e3, 1)}
        try:
            self.coord.show_control("seek", frame=seek.frame, at_ns=seek.at_ns)
        except (Refusal, ValueError, *OPERATOR_ERRORS) as exc:
            text = exc.message if isinstance(exc, Refusal) else str(exc)
            self._spawn(self._record(tc[3], (tc[4], 0), "timecode chase", False, text, params))
            return
        self._spawn(self._record(tc[3], (tc[4], 0), "timecode chase", True,
                                 f"seek to frame {seek.frame}: the show was {abs(seek.drift_s) * 1e3:.0f} ms "
                                 f"{direction} the clock", params))

    # ------------------------------------------------------------------ sending
    def _send(self, targets, messages) -> None:
        if self._transport is None:
            return
        for address, args in messages:
            data = encode(address, args)
            for t in targets:
                try:
                    self._transport.sendto(data, t)
                except OSError as exc:
                    self._say(f"send {t[0]}", f"cannot send to {t[0]}:{t[1]}: {exc.strerror or exc}")

    def _send_status(self, targets) -> None:
        fb = feedback(self.coord.status(), self._cue_state())
        self._send(targets, fb.messages)

    def _cue_state(self) -> Any | None:
        get = getattr(self.coord, "cue_state", None)
        if get is None:
            return None
        try:
            return get()
        except Exception:  # noqa: BLE001 - the status goes out without the cues rather than not at all
            log.exception("OSC: the cue state could not be read")
            return None

    def _listeners(self) -> list:
        now = self.clock()
        for key in [k for k, until in self._subscribers.items() if until < now]:
            del self._subscribers[key]
        return list(self._targets) + list(self._subscribers)

    async def _tick_loop(self) -> None:
        while True:
            try:    # not wait_for: on 3.11 it loses a cancel that meets a set event, and stop() hung
                async with asyncio.timeout(TICK_S):
                    await self._wake.wait()
            except TimeoutError:
                pass
            self._wake.clear()
            try:
                self._chase()
                listeners = self._listeners()
                if not listeners:
                    self._last_key = None
                    continue
                fb = feedback(self.coord.status(), self._cue_state())
                if fb.key != self._last_key:
                    self._last_key = fb.key
                    self._send(listeners, fb.messages)
            except Exception:  # noqa: BLE001 - show control keeps running; the log says what broke
                log.exception("OSC: the status check failed")
            await asyncio.sleep(0.05)       # at most 20 checks a second, however often it is woken
