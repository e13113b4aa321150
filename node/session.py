"""The protocol core of a node's life with a coordinator, shared by the real node and the swarm.

:class:`SessionCore` holds what outlives one session: the slot's credentials and the rig-clock
estimate. It proves the rig token both ways and joins (:meth:`SessionCore.join`), applies the
clock-id rule when a coordinator instance answers (:meth:`SessionCore.adopt`), exchanges clock
pings (:meth:`SessionCore.ping`, :meth:`SessionCore.pings`) and says what a heartbeat carries of
the clock (:meth:`SessionCore.clock_status`). :class:`ReportStream` is one session's report
stream: heartbeats and batched swaps and drops, decided by :class:`node.report_batch.ReportBatcher`.

Both take their transport (a :class:`node.link.CoordinatorLink`, or anything with its methods)
and their clock as parameters: :mod:`node.app` runs one session and renders, the swarm
(:mod:`shadowless.swarm_node`) runs hundreds in one process and renders nothing, and both keep
their clocks, ping and report by the same rules.
"""
from __future__ import annotations

import asyncio
import logging
import os
import random
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass, replace
from typing import Callable, Protocol

from node.clock import CLOCK_WINDOW_NS, SETTLE_SPAN_NS, ClockEstimate, ClockEstimator, ClockSample, LocalClock
from node.errors import CoordinatorNotTrusted
from node.link import LinkError
from node.records import (AssignmentBytes, ClockStatus, HeartbeatRecord, HelloReply, JoinReply, JoinRequest, NodeInfo,
                          PingReply, ReportBatch)
from node.report_batch import Report, ReportBatcher
from protos import auth
from protos.version import PROTOCOL_VERSION

log = logging.getLogger("node")

#: how long the Join that tells an untrusted coordinator why it is not joined may take
UNTRUSTED_JOIN_TIMEOUT_S = 2.5

#: clock exchanges right after a join, before anything else (a first estimate), and their spacing
BURST_PINGS = 8
BURST_SPACING_S = 0.01
#: ... and after a join that kept the estimate (the same rig clock: a coordinator restarted on its host,
#: a broken link): one exchange, to see the estimate still holds; the settled schedule does the rest
KEPT_BURST_PINGS = 1

#: a Hello proven while advertised coordinators were screened is the first half of the Join that
#: follows on the same target within this long (the coordinator honours its nonce for 30 s): a
#: rejoin found over mDNS makes one handshake, not two
PROVEN_HELLO_S = 10.0

#: the assignment revisions passed to the presenter that a heartbeat may still name (the newest)
KEPT_REVISIONS = 16


class Link(Protocol):
    """What the session core needs of its transport (:class:`node.link.CoordinatorLink` has it)."""

    target: str

    async def hello(self, *, protocol_version: int, client_nonce: bytes, slot: str,
                    timeout: float = 5.0) -> HelloReply: ...

    async def join(self, request: JoinRequest) -> JoinReply: ...

    async def ping(self, t0_local_ns: int) -> PingReply: ...


class ReportLink(Protocol):
    async def report(self, batches: AsyncIterator[ReportBatch]) -> None: ...


@dataclass(frozen=True)
class Joined:
    """A successful join: the coordinator's replies, and what became of the clock estimate."""

    reply: JoinReply
    hello: HelloReply
    previous_instance: str      # the coordinator instance joined before ("" the first time)
    clock_kept: bool            # the estimate (and the show) carried over: same instance, or same rig clock


class SessionCore:
    """One slot's protocol state across sessions: token proofs, the clock estimate, pings.

    Parameters
    ----------
    slot, token : str, bytes
        The slot this node takes and the rig token it proves.
    clock : LocalClock
        This node's local clock (offset and drift hooks included).
    info : callable
        ``() -> NodeInfo``: what the node says about itself, asked at each join.
    protocol_version : int
    ping_hz : float
        Clock exchanges per second until the estimate is settled ...
    ping_settled_s : float, optional
        ... then one every this many seconds (kept within 1..60); None: ``ping_hz`` always.
    quiet : bool
        Log the clock's settling at debug level, not info (a swarm runs hundreds of these).
    """

    def __init__(self, *, slot: str, token: bytes, clock: LocalClock, info: Callable[[], NodeInfo],
                 protocol_version: int = PROTOCOL_VERSION, ping_hz: float = 4.0, ping_settled_s: float | None = 10.0,
                 quiet: bool = False):
        self.slot, self.token, self.clock, self.info = slot, token, clock, info
        self._news = logging.DEBUG if quiet else logging.INFO
        self.protocol_version = protocol_version
        self.ping_hz, self.ping_settled_s = ping_hz, ping_settled_s
        self.estimator = ClockEstimator(window_ns=CLOCK_WINDOW_NS)
        self.settled = False          # the estimate is good enough for sparse exchanges (until the clock changes)
        self.instance_id = ""         # the coordinator instance joined last
        self.clock_id = ""            # and its rig clock's identity
        self.kept = False             # the last join kept the clock estimate
        # a verified Hello not yet used by a Join: (target, reply, client nonce, time.monotonic())
        self._proven: tuple[str, HelloReply, bytes, float] | None = None
        # the assignment last passed to the presenter (kept across sessions: a rejoin sends it again),
        # and the revision heartbeats report for the one the presenter holds (see assignment_revision)
        self._held: AssignmentBytes | None = None
        self._revisions: dict[int, int] = {}
        #: the newest assignment's refusal, "rN: why" ("" it was taken)
        self.refused = ""

    # ---------------------------------------------------------------- handshake
    async def hello(self, link: Link, *, timeout: float = 5.0) -> tuple[HelloReply, bytes]:
        """The coordinator's half of the handshake, verified: ``(hello, client_nonce)``. A
        coordinator that cannot prove the rig token is told why it is not joined (a Join with a
        random proof) and :class:`CoordinatorNotTrusted` is raised; a failed call raises LinkError."""
        nonce = auth.new_nonce()
        hello = await link.hello(protocol_version=self.protocol_version, client_nonce=nonce, slot=self.slot,
                                 timeout=timeout)
        if not auth.verify(auth.coordinator_proof(self.token, hello.rig_id, nonce, hello.server_nonce),
                           hello.server_proof):
            await self._tell_not_trusted(link, hello, nonce)
            raise CoordinatorNotTrusted(
                f"the coordinator at {link.target} (rig {hello.rig_name!r}) could not prove it knows the rig token: "
                "this node has the wrong token file, or that advertiser is not our coordinator")
        self._proven = (link.target, hello, nonce, time.monotonic())
        return hello, nonce

    async def _tell_not_trusted(self, link: Link, hello: HelloReply, client_nonce: bytes) -> None:
        """Let a coordinator that failed the token proof see why this node does not join: a Join whose
        proof is random bytes, which a coordinator refuses as a token mismatch and lists in its status
        next to the slot (else the slot shows only as expected there). Never this node's real proof:
        the peer is unverified, and an impostor that relayed a real coordinator's server nonce (with a
        bad server proof) could replay a real proof to that coordinator and join as this slot. The
        answer changes nothing here (the node joins nowhere)."""
        try:
            async with asyncio.timeout(UNTRUSTED_JOIN_TIMEOUT_S):   # not wait_for (3.11 drops a cancel)
                await link.join(JoinRequest(
                    protocol_version=self.protocol_version, slot=self.slot, client_nonce=client_nonce,
                    server_nonce=hello.server_nonce, client_proof=os.urandom(auth.PROOF_BYTES), info=self.info()))
        except (LinkError, asyncio.TimeoutError, OSError):
            pass

    async def join(self, link: Link) -> Joined:
        """Prove the token both ways and join; then the clock-id rule (:meth:`adopt`). Raises
        CoordinatorNotTrusted or LinkError (``refused`` when the coordinator will not change its mind).

        A Hello this core verified on the same target less than PROVEN_HELLO_S ago (the node screens
        advertised coordinators with one, on a connection of its own) is not repeated: the Join uses
        its nonces. Should the coordinator refuse them (it restarted meanwhile: another instance's
        secret), the handshake is made again from its start, once."""
        proven, self._proven = self._proven, None
        reply = None
        if proven is not None and proven[0] == link.target and time.monotonic() - proven[3] < PROVEN_HELLO_S:
            hello, nonce = proven[1], proven[2]
            try:
                reply = await self._login(link, hello, nonce)
            except LinkError as exc:
                if not exc.refused:
                    raise
                log.info("%s: the coordinator at %s refused the handshake it answered %.1f s ago (%s); "
                         "shaking hands again", self.slot, link.target, time.monotonic() - proven[3], exc.code)
        if reply is None:
            hello, nonce = await self.hello(link)
            self._proven = None
            reply = await self._login(link, hello, nonce)
        previous = self.instance_id
        kept = self.adopt(reply)
        self.kept = kept and self.estimator.estimate is not None
        return Joined(reply=reply, hello=hello, previous_instance=previous, clock_kept=kept)

    async def _login(self, link: Link, hello: HelloReply, nonce: bytes) -> JoinReply:
        """The node's half of the handshake on a verified ``hello``: the Join with its proof."""
        proof = auth.client_proof(self.token, "node", hello.rig_id, self.slot, nonce, hello.server_nonce)
        return await link.join(JoinRequest(protocol_version=self.protocol_version, slot=self.slot,
                                           client_nonce=nonce, server_nonce=hello.server_nonce, client_proof=proof,
                                           info=self.info()))

    def adopt(self, reply: JoinReply) -> bool:
        """The clock-id rule, for a join's coordinator instance: the same instance, or another one on
        the same rig clock (a coordinator restarted on its host), keeps the clock estimate; another
        clock (or an older coordinator that names none) drops it and starts afresh. True when kept."""
        if reply.instance_id == self.instance_id:
            return True
        same_clock = bool(reply.clock_id) and reply.clock_id == self.clock_id
        self.instance_id, self.clock_id = reply.instance_id, reply.clock_id
        # the revisions the presenter's assignments had are the last instance's: none of them is
        # reported as this one's (which numbers its own; a restarted coordinator may reuse them)
        self._revisions = {}
        if not same_clock:
            self.estimator.reset()
            self.settled = False
            self._held = None       # another rig clock: a blend's instant means something else there
        return same_clock

    # ---------------------------------------------------------------- the presenter's assignment
    def assignment_news(self, a: AssignmentBytes) -> bool:
        """Whether assignment ``a`` must go to the presenter: not when it equals the one passed last
        but for its revision (what a rejoin is sent first: the presenter holds it already, and would
        only compare it again). Either way, heartbeats report ``a``'s revision for what the presenter
        holds from now on (:meth:`assignment_revision`). Nor when the presenter could not take it
        (``a.problem``): refused here in one log line (and :attr:`refused`), the one held is kept, and
        heartbeats go on reporting its revision."""
        if a.problem:       # the presenter could not take it: the one it holds stays, and its revision
            self.refused = f"r{a.revision}: {a.problem}"
            log.error("%s: assignment r%d refused (%s); the projector keeps %s", self.slot, a.revision, a.problem,
                      f"r{self._revisions.get(self._held.revision, self._held.revision)}" if self._held is not None else "none")
            return False
        self.refused = ""
        held = self._held
        if held is not None and held.data == a.data:     # the same message but for its revision
            self._revisions[held.revision] = a.revision
            if a.revision != held.revision:
                log.info("%s: assignment r%d is the one the presenter holds (r%d): not passed again",
                         self.slot, a.revision, held.revision)
            return False
        self._held = a
        self._revisions[a.revision] = a.revision
        while len(self._revisions) > KEPT_REVISIONS:   # the presenter applies them in order: the oldest are done
            del self._revisions[next(iter(self._revisions))]
        return True

    def assignment_revision(self, presenter_revision: int) -> int:
        """The assignment revision a heartbeat reports, from the one the presenter says it applied: the
        coordinator joined last numbers them (an unchanged one kept across a rejoin takes the new
        number), and until that coordinator's first assignment reached the presenter, 0 (the one it
        holds was numbered by another instance, whose numbers a restarted coordinator may reuse)."""
        return self._revisions.get(presenter_revision, 0)

    # ---------------------------------------------------------------- clock
    async def ping(self, link: Link) -> ClockEstimate | None:
        """One clock exchange; the estimate it gave (None: none yet)."""
        t0 = self.clock.now()
        rep = await link.ping(t0)
        t3 = self.clock.now()
        return self.estimator.add(ClockSample(t0, rep.t1_rig_ns, rep.t2_rig_ns, t3))

    async def ping_burst(self, link: Link, after: Callable[[ClockEstimate | None], None] = lambda est: None,
                         *, count: int = BURST_PINGS) -> None:
        """A first estimate right after a join, before anything can be scheduled on it; after a join
        that kept the estimate, KEPT_BURST_PINGS exchanges only (the estimate the node plays on is
        good: a burst would cost both sides for nothing, the coordinator most when every node rejoins
        its restart at once)."""
        if self.kept:
            count = min(count, KEPT_BURST_PINGS)
        t0 = time.monotonic()
        for _ in range(count):
            after(await self.ping(link))
            await asyncio.sleep(BURST_SPACING_S)
        log.log(self._news, "%s: clock burst of %d exchanges in %.0f ms", self.slot, count,
                (time.monotonic() - t0) * 1e3)

    async def pings(self, link: Link, after: Callable[[ClockEstimate | None], None] = lambda est: None) -> None:
        """Clock exchanges for the rest of the session, each ``ping_period()`` apart (±20 %, so that
        nodes started together spread out), calling ``after`` with each estimate."""
        while True:
            await asyncio.sleep(self.ping_period() * random.uniform(0.8, 1.2))
            after(await self.ping(link))

    def ping_period(self) -> float:
        """Seconds to the next clock exchange: ``1 / ping_hz`` until the estimate's drift is fitted over
        SETTLE_SPAN_NS, then ``ping_settled_s`` (each exchange costs the coordinator about half a
        millisecond; a settled drift carries the estimate between them). Settled stays settled until
        the rig clock changes."""
        est = self.estimator.estimate
        if (not self.settled and self.ping_settled_s is not None and est is not None and est.drift_fitted
                and est.span_ns >= SETTLE_SPAN_NS):
            self.settled = True
            log.log(self._news, "%s: clock settled (drift %.2f ppm, best round trip %.2f ms): exchanges every %.0f s",
                     self.slot, est.drift * 1e6, est.best_rtt_ns / 1e6, self.ping_settled_s)
        if self.settled:
            return min(60.0, max(1.0, self.ping_settled_s))
        return 1.0 / max(0.1, self.ping_hz)

    def clock_status(self) -> tuple[int, ClockStatus | None]:
        """``(host_ns, status)``: the host's monotonic clock now, and the estimate as a heartbeat
        carries it at that instant (None until there is one)."""
        host = self.clock.host_now()
        est = self.estimator.estimate
        if est is None:
            return host, None
        local = self.clock.from_host(host)
        rig = est.rig_time(local)
        return host, ClockStatus(offset_ns=int(rig - local), drift_ppm=est.drift * 1e6, rtt_ns=est.best_rtt_ns,
                                 samples=est.samples, rig_estimate_ns=rig)

    def rig_time(self, host_ns: int) -> int | None:
        """The rig clock at host instant ``host_ns``, by the estimate (None: no estimate yet)."""
        est = self.estimator.estimate
        return None if est is None else est.rig_time(self.clock.from_host(host_ns))

    def host_time(self, rig_ns: int) -> int | None:
        """The host instant at which the rig clock reads ``rig_ns``, by the estimate (None: none yet)."""
        est = self.estimator.estimate
        return None if est is None else self.clock.to_host(est.local_time(rig_ns))



class ReportStream:
    """One session's report stream: what :class:`ReportBatcher` decides, sent when it is due.

    ``add`` and ``heartbeat_now`` may be called at any time on the loop that runs :meth:`run`;
    ``heartbeat`` builds the heartbeat when one goes; ``now`` is the monotonic clock in seconds
    (the event loop's)."""

    def __init__(self, heartbeat: Callable[[], HeartbeatRecord], heartbeat_s: float, *, batch_s: float = 0.05,
                 timeline_batch_s: float | None = None, now: Callable[[], float] = time.monotonic,
                 sent: Callable[[ReportBatch], None] = lambda batch: None):
        self.batcher = ReportBatcher(heartbeat_s, batch_s=batch_s, timeline_batch_s=timeline_batch_s)
        self._heartbeat, self._now, self._sent = heartbeat, now, sent
        self._wake = asyncio.Event()
        self._goodbye = ""

    def add(self, report: Report) -> None:
        if self.batcher.add(report, self._now()):
            self._wake.set()

    def heartbeat_now(self) -> None:
        self.batcher.want_heartbeat()
        self._wake.set()

    def goodbye(self, why: str) -> None:
        """The node stops on purpose: the next message is the last, carrying a heartbeat, whatever
        waits and ``why``; then the stream ends (:meth:`run` returns once the coordinator has it)."""
        self._goodbye = why or "stopping"
        self.batcher.want_heartbeat()
        self._wake.set()

    async def run(self, link: ReportLink) -> None:
        """Stream reports until the call breaks (LinkError), the task is cancelled, or a
        :meth:`goodbye` went."""
        await link.report(self._batches())

    async def _batches(self) -> AsyncIterator[ReportBatch]:
        batcher = self.batcher
        while True:
            now = self._now()
            batch = batcher.poll(now, self._heartbeat)
            if batch is not None and self._goodbye:
                batch = replace(batch, goodbye=self._goodbye)
                self._sent(batch)
                yield batch
                return
            if batch is not None:
                self._sent(batch)
                yield batch
                continue
            self._wake.clear()
            try:
                async with asyncio.timeout(batcher.next_due() - now):
                    await self._wake.wait()
            except TimeoutError:
                pass

