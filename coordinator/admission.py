"""A memory budget for calls that carry no session: what a peer that has not proved the rig
token can make the coordinator hold.

gRPC receives a unary call's whole message (up to ``protos.version.MAX_REQUEST_BYTES``) and
parses it before a handler runs, so a budget checked in the handler comes too late: 400
concurrent 3 MiB Hellos held hundreds of MiB. The gRPC edge (``coordinator/wire/admission_interceptor.py:
Admission``) therefore asks :meth:`Budget.admit` before any byte of the message is read. An
admitted call reserves the largest message it may send until its message arrived, then holds
the message's real size until it ends. A call over the budget is refused at once, unread, and
counted in the rig's refusals; its bytes are never taken from the connection beyond gRPC's
receive window.

The budget counts per peer address (an IPv6 peer: per /64, see :func:`budget_key`) and in all:
calls in flight and bytes reserved or held.
After a burst the freed memory stays in glibc's arenas unless it is handed back
(:func:`trim_memory`); :meth:`Budget.should_trim` says when a burst ended.
"""
from __future__ import annotations

import asyncio
import ctypes
import ctypes.util
import logging
import time
from dataclasses import dataclass, field
from typing import Callable

from coordinator.address_owner import address_owner
from coordinator.api import AdmissionFigures
from coordinator.refusals import peer_address

log = logging.getLogger(__name__)

MIB = 1024 * 1024
#: calls without a session in flight, from all peers / from one address
MAX_CALLS = 64
MAX_CALLS_PER_ADDRESS = 16
#: bytes reserved (a message not yet received counts as the largest allowed) or held, all peers / one address
MAX_BYTES = 16 * MIB
MAX_BYTES_PER_ADDRESS = 4 * MIB
#: calls over the budget that wait for room (their bytes stay in gRPC's receive window, at most
#: protos.version.COORDINATOR_WINDOW_BYTES each), per address and in all, and for how long: a host
#: whose nodes all start at once is served in turn, not refused; beyond these a call is refused
MAX_WAITING_PER_ADDRESS = 8
MAX_WAITING = 16
WAIT_S = 2.0
#: seconds an admitted call has to deliver its message: one that sends headers and then nothing
#: would otherwise hold its room (a slow-loris) until its connection died
READ_TIMEOUT_S = 5.0
#: the largest message a call without a session may bring: handshakes (Hello, Join, Login) and
#: health checks are a few hundred bytes; a larger one is refused without being parsed
MAX_MESSAGE_BYTES = 64 * 1024
#: a burst that moved this much (received, or reserved by refused calls) is followed by a trim
TRIM_AFTER_BYTES = 16 * MIB
#: seconds the budget must have been idle before the trim (gRPC frees its buffers in its own threads)
TRIM_IDLE_S = 1.0

REFUSED_OVER_BUDGET = ("over the budget for calls before authentication (too many calls or bytes in flight "
                       "from this address or in all): retry in a moment")


def budget_key(peer: str) -> str:
    """Whose budget a call from ``peer`` (a gRPC peer string) draws on: its address, or for IPv6 its
    /64 (:func:`coordinator.address_owner.address_owner`)."""
    return address_owner(peer_address(peer))


@dataclass
class _Use:
    calls: int = 0
    bytes: int = 0


@dataclass
class Ticket:
    """One admitted call: its address and the bytes it holds now."""

    address: str
    bytes: int
    released: bool = False


@dataclass
class Budget:
    """Admission of calls without a session (see the module docstring).

    Parameters
    ----------
    reserve_bytes : int
        What a call holds before its message arrived: the largest message the server accepts.
    max_calls, max_calls_per_address, max_bytes, max_bytes_per_address : int
        The caps (in all, and per peer address).
    max_waiting, max_waiting_per_address : int
        Calls :meth:`enter` lets wait for room (at most ``WAIT_S``) before it refuses.
    clock : callable
        Seconds, monotonic (the host's: an injected rig clock may stand still).
    """

    reserve_bytes: int
    max_calls: int = MAX_CALLS
    max_calls_per_address: int = MAX_CALLS_PER_ADDRESS
    max_bytes: int = MAX_BYTES
    max_bytes_per_address: int = MAX_BYTES_PER_ADDRESS
    max_waiting: int = MAX_WAITING
    max_waiting_per_address: int = MAX_WAITING_PER_ADDRESS
    clock: Callable[[], float] = time.monotonic
    waiting: dict[str, int] = field(default_factory=dict)
    waited: int = 0
    total: _Use = field(default_factory=_Use)
    by_address: dict[str, _Use] = field(default_factory=dict)
    admitted: int = 0
    refused: int = 0
    malformed: int = 0
    peak_bytes: int = 0
    _burst_bytes: int = 0
    _idle_since: float = 0.0
    _wakers: list[asyncio.Event] = field(default_factory=list)

    def _fits(self, address: str) -> bool:
        mine = self.by_address.get(address) or _Use()
        need = self.reserve_bytes
        return not (self.total.calls + 1 > self.max_calls or mine.calls + 1 > self.max_calls_per_address
                    or self.total.bytes + need > self.max_bytes or mine.bytes + need > self.max_bytes_per_address)

    def admit(self, peer: str) -> Ticket | None:
        """Reserve room for a new call from ``peer`` (a gRPC peer string) now; None: over the budget."""
        address = budget_key(peer)
        if not self._fits(address):
            self._refuse()
            return None
        return self._take(address)

    async def enter(self, peer: str, *, wait_s: float = WAIT_S) -> Ticket | None:
        """Like :meth:`admit`, but a call over the budget waits up to ``wait_s`` seconds for room
        while fewer than ``max_waiting`` calls (``max_waiting_per_address`` from its address) wait."""
        address = budget_key(peer)
        if self._fits(address):
            return self._take(address)
        queued = self.waiting.get(address, 0)
        if sum(self.waiting.values()) >= self.max_waiting or queued >= self.max_waiting_per_address:
            self._refuse()
            return None
        self.waiting[address] = queued + 1
        self.waited += 1
        loop = asyncio.get_running_loop()
        deadline = loop.time() + wait_s
        try:
            while True:
                waker = asyncio.Event()
                self._wakers.append(waker)
                try:    # not wait_for: on 3.11 it drops a cancel that meets the set waker
                    async with asyncio.timeout(max(0.0, deadline - loop.time())):
                        await waker.wait()
                except TimeoutError:
                    self._refuse()
                    return None
                if self._fits(address):
                    return self._take(address)
        finally:
            self.waiting[address] -= 1
            if not self.waiting[address]:
                del self.waiting[address]

    def _refuse(self) -> None:
        self.refused += 1
        self._burst_bytes += self.reserve_bytes

    def _take(self, address: str) -> Ticket:
        mine = self.by_address.get(address) or _Use()
        need = self.reserve_bytes
        self.by_address[address] = mine
        mine.calls += 1
        mine.bytes += need
        self.total.calls += 1
        self.total.bytes += need
        self.peak_bytes = max(self.peak_bytes, self.total.bytes)
        self.admitted += 1
        return Ticket(address, need)

    def received(self, ticket: Ticket, nbytes: int) -> None:
        """The call's message arrived: it holds ``nbytes`` from now on, not the reservation."""
        if ticket.released:
            return
        delta = nbytes - ticket.bytes
        ticket.bytes = nbytes
        self.total.bytes += delta
        self.by_address[ticket.address].bytes += delta
        self._burst_bytes += nbytes
        if delta < 0:
            self._wake()

    def release(self, ticket: Ticket) -> None:
        """The call ended (answered, refused, cancelled): its room is free again."""
        if ticket.released:
            return
        ticket.released = True
        mine = self.by_address[ticket.address]
        mine.calls -= 1
        mine.bytes -= ticket.bytes
        self.total.calls -= 1
        self.total.bytes -= ticket.bytes
        if mine.calls == 0:
            del self.by_address[ticket.address]
        if self.total.calls == 0:
            self._idle_since = self.clock()
        self._wake()

    def _wake(self) -> None:
        wakers, self._wakers = self._wakers, []
        for waker in wakers:          # each waiting call looks again whether it fits now
            waker.set()

    def should_trim(self) -> bool:
        """Whether a burst of unauthenticated bytes just ended (idle for TRIM_IDLE_S): then the
        memory it freed should go back to the system (:func:`trim_memory`). Resets the burst."""
        if self._burst_bytes < TRIM_AFTER_BYTES or self.total.calls or self.clock() - self._idle_since < TRIM_IDLE_S:
            return False
        self._burst_bytes = 0
        return True

    def figures(self) -> AdmissionFigures:
        return AdmissionFigures(in_flight_calls=self.total.calls, in_flight_bytes=self.total.bytes,
                                peak_bytes=self.peak_bytes, admitted=self.admitted, refused=self.refused,
                                malformed=self.malformed, max_calls=self.max_calls, max_bytes=self.max_bytes,
                                max_calls_per_address=self.max_calls_per_address,
                                max_bytes_per_address=self.max_bytes_per_address, waited=self.waited)


def _malloc_trim():
    name = ctypes.util.find_library("c")
    try:
        fn = ctypes.CDLL(name).malloc_trim if name else None
    except (OSError, AttributeError):    # not glibc: nothing to trim this way
        return None
    if fn is not None:
        fn.argtypes, fn.restype = [ctypes.c_size_t], ctypes.c_int
    return fn


_TRIM = _malloc_trim()


def resident_bytes() -> int:
    """This process's resident memory (``VmRSS``), 0 where /proc does not say."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def trim_memory() -> int:
    """Hand the heap's free pages back to the system (glibc ``malloc_trim(0)``, every arena);
    the resident bytes that went (0 where there is no glibc).

    After a burst of large messages the freed buffers stay in the process's malloc arenas and
    count as resident; this returns them. Blocks for milliseconds: call it off the event loop."""
    if _TRIM is None:
        return 0
    before = resident_bytes()
    _TRIM(0)
    return max(0, before - resident_bytes())
