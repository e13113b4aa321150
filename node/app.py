"""A node: find the coordinator, prove the rig token, join, keep the clock in
step, feed the presenter, report swaps, and come back by itself after anything.

The network side runs on one asyncio loop (the coordinator link and mDNS); the GL
side runs in the presenter process. A session lives from a successful Join to
the first broken stream; then the node backs off (exponentially, with jitter,
never busy-looping) and starts over with discovery, while the projector keeps
showing the last frame.

After each join the node also follows the rig's wanted assets and fetches them into
its on-disk cache (:mod:`node.asset_fetch`), reporting its progress in every heartbeat; an asset
turning ready (or given up on) sends a heartbeat at once instead of waiting for the next one.

This module is the node's life cycle only: it speaks :mod:`node.records`
dataclasses; the gRPC client is :mod:`node.link`; the handshake, the clock estimate, pings and the
report stream are :mod:`node.session`'s, which the swarm shares.
"""
from __future__ import annotations

import asyncio
import logging
import math
import os
import random
import socket
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from node.asset_cache import default_cache_dir
from node.asset_fetch import AssetFetcher
from node.clock import ClockEstimate, LocalClock
from node.errors import CoordinatorNotTrusted, DiscoveryError, Refused
from node.link import CoordinatorLink, LinkError
from node.network_priority import yield_to_presenter
from node.presenter_process import PresenterProcess, PresenterSettings
from node.records import AssetFiles, DropRecord, HeartbeatRecord, NodeInfo, PreviewRecord, SwapRecord
from node.session import Joined, ReportStream, SessionCore
from node.systemd import NodeNotifier
from node.targets import Candidate, TargetBook, read_known_rig, write_known_rig
from protos.host import boot_id
from protos.version import PROTOCOL_VERSION, SOFTWARE_VERSION

if TYPE_CHECKING:
    from protos.discovery import Discovery

log = logging.getLogger("node")


@dataclass
class NodeConfig:
    slot: str
    token: bytes
    coordinator: str | None = None          # HOST:PORT; None = mDNS
    rig: str | None = None                  # rig name or id to pick among advertisements
    mdns_interfaces: list[str] | None = None
    output: str = "offscreen"
    snapshot_dir: Path | None = None
    clock_offset_ms: float = 0.0
    clock_drift_ppm: float = 0.0
    protocol_version: int = PROTOCOL_VERSION
    tls_ca: bytes | None = None
    tls_server_name: str | None = None
    ping_hz: float = 4.0                    # clock exchanges per second until the clock is settled ...
    ping_settled_s: float = 10.0            # ... then one every this many seconds
    realtime: bool = True
    backoff_min_s: float = 0.2
    backoff_max_s: float = 5.0
    refusal_backoff_s: float = 10.0
    cache_dir: Path | None = None           # None: default_cache_dir() / slot
    cache_max_bytes: int = 8 << 30
    fetch_rate: float | None = None         # bytes per second; None: unlimited
    discovery_timeout_s: float | None = None  # give up (DISCOVERY_GAVE_UP_EXIT) if mDNS finds nothing so long; None: never


#: the node's exit status when --discovery-timeout passed without a coordinator found over mDNS
DISCOVERY_GAVE_UP_EXIT = 4

#: how long one look over mDNS waits for a first advertisement
DISCOVERY_TIMEOUT_S = 3.0

#: after the first advertisement, how long the node waits for the others before choosing among
#: them (so that the rig it joined before goes first even when a rogue answers quicker)
DISCOVERY_SETTLE_S = 0.3

#: how long a Hello may take when several advertised coordinators are asked at once (one that never
#: answers, e.g. an advertiser pointing at nothing that speaks gRPC, costs this once per pass)
SCREEN_TIMEOUT_S = 2.5

#: the longest wait between attempts to rejoin a lost coordinator (the regular cap is backoff_max_s)
ALONE_BACKOFF_S = 1.0

#: preview requests reach the presenter at most this often (those in between coalesce into the next)
PREVIEW_EVERY_S = 0.5

#: how long a node that stops on purpose waits for the coordinator to take its goodbye
GOODBYE_S = 1.0


#: a session's tasks that are the node's own, not the coordinator's streams: their end is no loss
_NODE_TASKS = frozenset({"stopping", "presenter"})


class Node:
    def __init__(self, config: NodeConfig):
        self.cfg = config
        self.clock = LocalClock(offset_ns=int(config.clock_offset_ms * 1e6), drift_ppm=config.clock_drift_ppm)
        # the handshake, the clock estimate (kept across sessions by the clock-id rule) and pings
        self.session = SessionCore(slot=config.slot, token=config.token, clock=self.clock, info=self._info,
                                   protocol_version=config.protocol_version, ping_hz=config.ping_hz,
                                   ping_settled_s=config.ping_settled_s)
        self.presenter: PresenterProcess | None = None
        # systemd: readiness, status, and a watchdog fed by the network loop and the presenter
        self.notifier = NodeNotifier(lambda: self.presenter.seconds_since_alive() if self.presenter else math.inf)
        self._stream: ReportStream | None = None   # the session's report stream, while it runs
        self._loop: asyncio.AbstractEventLoop | None = None
        self._alone_since: float | None = None   # time.monotonic() when the coordinator was lost
        self._alone_ms = 0.0                       # how long the last time without it lasted
        self._stopping = asyncio.Event()
        self._stop_reason = ""                     # why the node stops on purpose (its goodbye)
        self.joins = 0
        self._assets_passed: set[str] = set()    # assets whose files the presenter has
        self._show_asset: str | None = None      # the asset the current show plays
        cache_dir = config.cache_dir or default_cache_dir() / config.slot
        self.fetcher = AssetFetcher(cache_dir, config.cache_max_bytes, rate=config.fetch_rate,
                                    on_change=self._fetch_news)
        # the rig this node joined last is tried first (kept beside the asset cache, across restarts)
        self._rig_file = cache_dir / "joined-rig"
        self.book = TargetBook(known_rig=read_known_rig(self._rig_file), unreachable_min_s=config.backoff_min_s,
                               unreachable_max_s=config.backoff_max_s, refusal_s=config.refusal_backoff_s)
        self._advertised: set[tuple[str, str]] = set()

    # ---------------------------------------------------------------- reports
    def _report(self, rep: SwapRecord | DropRecord | PreviewRecord) -> None:
        """A swap, drop or preview from the presenter: into the session's report stream (between
        sessions there is none: what happens then is stale by the next one)."""
        if self._stream is not None:
            self._stream.add(rep)

    def _fetch_news(self) -> None:
        """An asset turned ready (or was given up on): tell the coordinator at once (a session's first
        heartbeat goes at once anyway), and hand the show's asset to the presenter as soon as it is
        there (not at the next beacon, a second later)."""
        if self._stream is not None:
            self._stream.heartbeat_now()
        if self._show_asset is not None and self.presenter is not None:
            self._pass_asset(self._show_asset)

    def _news(self) -> None:
        """Other blend maps on the projector: the coordinator hears of it in a heartbeat at once."""
        if self._stream is not None:
            self._stream.heartbeat_now()

    def _estimate(self, est: ClockEstimate | None) -> None:
        if est is not None and self.presenter is not None:
            self.presenter.submit("clock", est)

    def _info(self) -> NodeInfo:
        """What this node says about itself when it joins (its output's size once the presenter knows it)."""
        size = (self.presenter.native_size if self.presenter is not None else None) or (0, 0)
        return NodeInfo(hostname=socket.gethostname(), host_boot_id=boot_id(), pid=os.getpid(),
                        software_version=SOFTWARE_VERSION, output=self.cfg.output.split("?")[0],
                        native_size=(size[0], size[1]), gl=self.presenter.gl_info if self.presenter is not None else "")

    # ---------------------------------------------------------------- main loop
    async def run(self) -> int:
        self._loop = asyncio.get_running_loop()
        self._looking_since = time.monotonic()
        discovery, early = None, None
        if self.cfg.coordinator is None:
            from protos.discovery import Discovery, DiscoveryError as MdnsUnusable   # zeroconf: only a node that browses
            discovery = Discovery(interfaces=self.cfg.mdns_interfaces)
            try:
                await discovery.start()
            except MdnsUnusable as exc:    # a wrong --mdns-interface: waiting will not mend it
                log.error("%s", exc)
                return 2
        self.presenter = PresenterProcess(PresenterSettings(
            slot=self.cfg.slot, output_spec=self.cfg.output, clock_offset_ns=self.clock.offset_ns,
            clock_drift_ppm=self.clock.drift_ppm, clock_anchor_ns=self.clock.anchor_ns,
            snapshot_dir=self.cfg.snapshot_dir, realtime=self.cfg.realtime,
            log_level=logging.getLogger().getEffectiveLevel(), log_name=f"node {self.cfg.slot}"))
        self.presenter.start()
        yield_to_presenter()        # from now on the presenter has the node's CPU first
        # the coordinator is looked for while the presenter starts (a new interpreter, the GL context)
        if discovery is not None:
            early = asyncio.ensure_future(self._candidates(discovery))
        ok = await asyncio.get_running_loop().run_in_executor(None, self.presenter.wait_ready, 120.0)
        if not ok:
            log.error("cannot open output %r: %s", self.cfg.output, self.presenter.failed)
            if early is not None:
                early.cancel()
                await asyncio.gather(early, return_exceptions=True)
                await discovery.close()
            self.presenter.stop()
            return 3
        self.presenter.attach(self._loop, self._report)
        self.presenter.on_blend_change = self._news
        self.notifier.ready(f"{self.cfg.slot}: output {self.cfg.output} open, looking for the coordinator")
        watchdog = asyncio.create_task(self.notifier.run(), name="watchdog")
        backoff = self.cfg.backoff_min_s
        try:
            while not self._stopping.is_set():
                if not self.presenter.is_alive():
                    log.error("the renderer stopped (%s); exiting so the service manager restarts the node",
                              self.presenter.failed)
                    return 3
                delay = backoff
                generation = discovery.generation if discovery is not None else 0
                try:
                    if early is not None:
                        found, early = early, None
                        candidates = await found
                    else:
                        candidates = await self._candidates(discovery)
                    if self._stopping.is_set():
                        break
                    self.book.forget_absent(candidates)
                    tried, joined = await self._pass(candidates, discovery)
                    if joined:
                        backoff = self.cfg.backoff_min_s
                        delay = backoff
                    elif not tried:     # every target is backing off: wait for the first one due
                        delay = max(0.05, min(backoff, self.book.next_due(candidates, time.monotonic())))
                except DiscoveryError as exc:
                    if self._gives_up(exc):
                        return DISCOVERY_GAVE_UP_EXIT
                    log.warning("%s; still looking (or pass --coordinator HOST:PORT)", exc)
                # a node that lost its coordinator (and plays on alone) looks for it again at least
                # every ALONE_BACKOFF_S: the show's changes (pause, stop) wait for it to rejoin
                cap = self.cfg.backoff_max_s
                if self._alone_since is not None:
                    cap = min(cap, ALONE_BACKOFF_S)
                backoff = min(cap, backoff * 2)
                await self._pause(delay * random.uniform(0.8, 1.2), discovery, generation)
        finally:
            self.notifier.stopping()
            watchdog.cancel()
            await asyncio.gather(watchdog, return_exceptions=True)
            if early is not None:
                early.cancel()
                await asyncio.gather(early, return_exceptions=True)
            if discovery is not None:
                await discovery.close()
            self.presenter.detach(self._loop)
            await asyncio.get_running_loop().run_in_executor(None, self.presenter.stop)
            self.fetcher.close()
        return 0

    async def _pause(self, seconds: float, discovery: Discovery | None, generation: int) -> None:
        """Wait ``seconds`` between passes, or less: until the node is stopped or, with mDNS, until an
        advertisement comes or goes (a coordinator that starts is tried at once, whatever the backoff)."""
        waits = [asyncio.ensure_future(self._stopping.wait())]
        if discovery is not None:
            waits.append(asyncio.ensure_future(discovery.wait_change(generation, seconds)))
        try:
            await asyncio.wait(waits, timeout=seconds, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for w in waits:
                w.cancel()
            await asyncio.gather(*waits, return_exceptions=True)

    async def _pass(self, candidates: list[Candidate], discovery: Discovery | None = None) -> tuple[int, bool]:
        """Try the due candidates in the book's order until one takes this node and its session
        ends. A refusal or an unreachable target never ends the pass: the next one is tried.
        Returns (targets tried, whether one was joined)."""
        due = self.book.order(candidates, time.monotonic())
        tried = 0
        if self.cfg.coordinator is None and due:
            # advertised coordinators: ask them all at once which can prove the token, so that one
            # that never answers (or an impostor) costs one short timeout, not a turn each
            tried, due = await self._screen(due, len(candidates), discovery)
        for cand in due:
            if self._stopping.is_set():
                break
            tried += 1
            try:
                if await self._session(cand):
                    return tried, True
                self._unreachable(cand, "no answer to the handshake")
            except (Refused, CoordinatorNotTrusted, LinkError) as exc:
                self._judged(cand, exc, len(candidates))
        return tried, False

    def _judged(self, cand: Candidate, exc: Exception, advertised: int) -> None:
        """Book and log why ``cand`` was not joined (``exc``: Refused, CoordinatorNotTrusted or LinkError)."""
        if isinstance(exc, Refused):
            news = self.book.refused(cand, str(exc), time.monotonic())
            log.log(logging.ERROR if news else logging.INFO, "refused by %s: %s (asking it again in %.0f s%s)",
                    cand.label(), exc, self.cfg.refusal_backoff_s,
                    ", trying the other coordinators meanwhile" if advertised > 1 else "")
        elif isinstance(exc, CoordinatorNotTrusted):
            news = self.book.refused(cand, "not trusted", time.monotonic())
            if news:
                log.warning("%s; not joining it (trying the other coordinators; again there in %.0f s)",
                            exc, self.cfg.refusal_backoff_s)
            else:
                log.info("%s still cannot prove the rig token; skipped", cand.label())
        elif isinstance(exc, LinkError):
            self._unreachable(cand, f"{exc.code}: {exc.details}")

    async def _prove(self, cand: Candidate) -> Candidate:
        """``cand`` if it answers a Hello within SCREEN_TIMEOUT_S and proves the rig token; raises
        Refused, CoordinatorNotTrusted or LinkError otherwise."""
        async with CoordinatorLink(cand.target, tls_ca=self.cfg.tls_ca,
                                   tls_server_name=self.cfg.tls_server_name) as link:
            try:
                await self.session.hello(link, timeout=SCREEN_TIMEOUT_S)
            except LinkError as exc:
                if exc.refused:
                    raise Refused(exc.details) from exc
                raise
        return cand

    async def _screen(self, due: list[Candidate], advertised: int,
                      discovery: Discovery | None) -> tuple[int, list[Candidate]]:
        """Send a Hello to every candidate in ``due`` at once, and to every coordinator advertised while
        they answer (a rogue that answers mDNS first must not have the pass to itself); as soon as one
        proves the token, return it (the others are left unjudged: still due next pass). The ones that
        answered otherwise by then are booked (refused, not trusted, unreachable). Returns (targets
        judged, candidates to join: the proven one, or none)."""
        async def verdict(c: Candidate) -> tuple[Candidate, Exception | None]:
            try:
                return await self._prove(c), None
            except (Refused, CoordinatorNotTrusted, LinkError) as exc:
                return c, exc

        pending = {asyncio.ensure_future(verdict(c)) for c in due}
        started = {c.target for c in due}
        watch: asyncio.Future | None = None
        judged = 0
        try:
            while pending:
                if discovery is not None and watch is None:
                    # what answered since the candidates were listed (the list may be seconds old)
                    fresh = [Candidate(a.target, a.rig_id, a.name) for a in discovery.current(self.cfg.rig)
                             if a.target not in started]
                    for c in self.book.order(fresh, time.monotonic()):
                        log.info("also asking %s, advertised meanwhile", c.label())
                        started.add(c.target)
                        pending.add(asyncio.ensure_future(verdict(c)))
                    watch = asyncio.ensure_future(discovery.wait_change(discovery.generation, SCREEN_TIMEOUT_S))
                done, _ = await asyncio.wait(pending | ({watch} if watch is not None else set()),
                                             return_when=asyncio.FIRST_COMPLETED)
                if watch is not None and watch in done:
                    done.discard(watch)
                    watch = None
                for t in done:
                    pending.discard(t)
                    cand, exc = t.result()
                    if exc is None:
                        return judged, [cand]
                    judged += 1
                    self._judged(cand, exc, advertised)
            return judged, []
        finally:
            for t in [*pending, *([watch] if watch is not None else [])]:
                t.cancel()
            await asyncio.gather(*pending, *([watch] if watch is not None else []), return_exceptions=True)

    def _unreachable(self, cand: Candidate, reason: str) -> None:
        # a node playing on alone asks again at least every ALONE_BACKOFF_S (the show waits for it)
        self.book.unreachable_max_s = (min(ALONE_BACKOFF_S, self.cfg.backoff_max_s) if self._alone_since is not None
                                       else self.cfg.backoff_max_s)
        self.book.unreachable(cand, reason, time.monotonic())
        log.warning("could not reach the coordinator at %s (%s)", cand.label(), reason)

    def stop(self, why: str = "stopped") -> None:
        """Stop on purpose (a signal, Ctrl-C): a joined node tells its coordinator why before it goes,
        which then says the node left instead of lost (and still hands its light to the others)."""
        self._stop_reason = self._stop_reason or why
        self._stopping.set()

    def _gives_up(self, exc: DiscoveryError) -> bool:
        """True (having said so in one line) once --discovery-timeout has passed since the node began
        looking, without any coordinator found; a node that has joined once keeps looking."""
        limit = self.cfg.discovery_timeout_s
        if limit is None or self.joins or time.monotonic() - self._looking_since < limit:
            return False
        log.error("%s; gave up after --discovery-timeout %g s: start the coordinator, check that this machine "
                  "is on its network (multicast reaches it), or pass --coordinator HOST:PORT", exc, limit)
        return True

    async def _candidates(self, discovery: Discovery | None) -> list[Candidate]:
        """The coordinators to try: the one given by --coordinator, or every advertised one (of the
        rig named by --rig when given). Several rigs on one network are fine: only a coordinator
        that proves it knows this node's token is joined."""
        if discovery is None:
            return [Candidate(self.cfg.coordinator)]
        look = asyncio.ensure_future(discovery.find(rig=self.cfg.rig, timeout=DISCOVERY_TIMEOUT_S,
                                                    settle=DISCOVERY_SETTLE_S))
        stopping = asyncio.ensure_future(self._stopping.wait())
        try:        # a node stopped on purpose ends its look at once, not when the look times out
            await asyncio.wait((look, stopping), return_when=asyncio.FIRST_COMPLETED)
        finally:
            stopping.cancel()
            if not look.done():
                look.cancel()
            await asyncio.gather(look, stopping, return_exceptions=True)
        if not look.done() or look.cancelled():
            return []       # stopped during the look: nothing to try (the loop ends)
        ads = look.result()
        if not ads:
            raise DiscoveryError(discovery.nothing_found(DISCOVERY_TIMEOUT_S, self.cfg.rig))
        seen = {(a.target, a.rig_id) for a in ads}
        if seen != self._advertised:
            self._advertised = seen
            log.info("advertised coordinators: %s", ", ".join(sorted(f"{a.name} ({a.rig_id}) at {a.target}"
                                                                    for a in ads)))
            for a in ads:
                if a.protocol and a.protocol != str(self.cfg.protocol_version):
                    log.warning("rig %s at %s advertises protocol %s, this node speaks %d", a.name, a.target,
                                a.protocol, self.cfg.protocol_version)
        return [Candidate(a.target, a.rig_id, a.name) for a in ads]

    # ---------------------------------------------------------------- one session
    async def _session(self, cand: Candidate) -> bool:
        """Join ``cand`` and serve until a stream breaks. True if the join succeeded."""
        target = cand.target
        async with CoordinatorLink(target, tls_ca=self.cfg.tls_ca, tls_server_name=self.cfg.tls_server_name) as link:
            try:
                joined = await self.session.join(link)
            except LinkError as exc:
                if exc.refused:
                    raise Refused(exc.details) from exc
                log.debug("cannot join %s: %s", target, exc.code)
                return False
            self.joins += 1
            hello = joined.hello
            if self.book.joined(cand, hello.rig_id):
                write_known_rig(self._rig_file, hello.rig_id)
            session, hb_ms = joined.reply.session, joined.reply.heartbeat_interval_ms
            self._new_instance(joined)
            if self._alone_since is not None:
                self._alone_ms = (time.monotonic() - self._alone_since) * 1e3
                self._alone_since = None
                log.info("coordinator back after %.1f s alone", self._alone_ms / 1e3)
            log.info("joined rig %r (id %s) at %s as %s (session %s…)", hello.rig_name, hello.rig_id, target,
                     self.cfg.slot, session[:6])
            self.notifier.status(f"{self.cfg.slot}: joined rig {hello.rig_name} at {target}")
            # a first clock estimate before any frame can be scheduled
            await self.session.ping_burst(link, self._estimate)
            tasks = [
                asyncio.create_task(self._assignments(link), name="assignments"),
                asyncio.create_task(self._frames(link), name="frames"),
                asyncio.create_task(self._report_stream(link, hb_ms / 1000.0), name="report"),
                asyncio.create_task(self.session.pings(link, self._estimate), name="pings"),
                asyncio.create_task(self._stopping.wait(), name="stopping"),
                asyncio.create_task(self._watch_presenter(), name="presenter"),
                asyncio.create_task(self.fetcher.run(link), name="assets"),
                asyncio.create_task(self._show(link), name="show"),
                asyncio.create_task(self._previews(link), name="previews"),
            ]
            done, pending = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
            report = tasks[2]
            if self._stopping.is_set() and report in pending and self._stream is not None:
                # the last report says goodbye, then the stream ends (the coordinator answers at once)
                self._stream.goodbye(self._stop_reason)
                said, _ = await asyncio.wait({report}, timeout=GOODBYE_S)
                pending -= said
                done |= said
                if said:
                    log.info("told the coordinator at %s this node leaves (%s)", target, self._stop_reason)
            for t in pending:
                t.cancel()
            await asyncio.gather(*pending, return_exceptions=True)
            why = self._why_lost([t for t in tasks if t in done])
            if why and not self._stopping.is_set():
                # one line a loss, whichever streams broke and however many (a coordinator killed, a
                # cable pulled: every stream fails at once; one stopped on purpose: they all end)
                log.warning("lost the coordinator at %s (%s); will rejoin", target, why)
                self._alone_since = time.monotonic()
                self.notifier.status(f"{self.cfg.slot}: lost the coordinator at {target}; rejoining")
                show = self.presenter.stats.show
                if show.state in ("playing", "paused"):
                    log.warning("the show (r%d, %s) goes on without the coordinator, on this node's clock estimate",
                                show.revision, show.state)
            return True

    @staticmethod
    def _why_lost(done: list[asyncio.Task]) -> str:
        """Why a session's tasks that ended (``done``, in the order they were made) say the coordinator
        was lost: the first broken stream's code and details, or that the coordinator ended its streams
        (one that stops on purpose closes them); "" when none of them was the coordinator's (the node
        stops, its presenter died). A task that failed otherwise is logged here as an error."""
        why = ""
        for t in done:
            exc = t.exception() if not t.cancelled() else None
            if isinstance(exc, LinkError):
                why = why or f"{exc.code}: {exc.details}"
            elif exc is not None:
                log.error("session ended by %s: %r", t.get_name(), exc)
            elif not t.cancelled() and t.get_name() not in _NODE_TASKS:
                why = why or f"it closed the session: its {t.get_name()} stream ended"
        return why

    def _new_instance(self, joined: Joined) -> None:
        """A join's coordinator instance, after the session core's clock-id rule: the same rig clock
        keeps the clock estimate and the show (a coordinator restarted on its host); another clock
        starts both afresh, in the presenter too."""
        instance = joined.reply.instance_id
        if joined.previous_instance and joined.previous_instance != instance:
            log.info("coordinator instance changed (%s -> %s): %s", joined.previous_instance, instance,
                     "same rig clock, keeping the clock estimate and the show" if joined.clock_kept
                     else "a new rig clock, resyncing the clock and the show")
        if not joined.clock_kept:
            self.presenter.submit("clock", None)
            self.presenter.submit("reset")

    async def _watch_presenter(self) -> None:
        while self.presenter.is_alive():
            await asyncio.sleep(0.5)

    async def _assignments(self, link: CoordinatorLink) -> None:
        async for assignment in link.assignments():
            if self.session.assignment_news(assignment):    # a rejoin's unchanged one is not passed again
                self.presenter.submit("assignment", assignment)

    async def _frames(self, link: CoordinatorLink) -> None:
        # The packets go to the presenter as received bytes: parsing (and copying the images)
        # happens once, in the process that uses them.
        async for data in link.frame_packets():
            self.presenter.submit("packet", data)

    async def _show(self, link: CoordinatorLink) -> None:
        """Forward the show's timeline to the presenter, with the asset's files once they are cached
        (and as soon as the fetcher completes it, see _fetch_news)."""
        try:
            async for update in link.show():
                if update.timeline is not None:
                    self._show_asset = update.timeline.asset_id
                    self._pass_asset(update.timeline.asset_id)
                self.presenter.submit("show", update)
        except LinkError as exc:
            if exc.code != "UNIMPLEMENTED":
                raise
            log.warning("this coordinator plays no timeline shows (an older version); stills and sequences only")
            await asyncio.Event().wait()    # the session goes on without

    async def _previews(self, link: CoordinatorLink) -> None:
        """Pass the coordinator's preview requests to the presenter, at most one per PREVIEW_EVERY_S
        whatever it asks (those in between coalesce: the presenter answers the newest)."""
        latest, sent_at = 0, -math.inf
        flush: asyncio.TimerHandle | None = None

        def send() -> None:
            nonlocal flush, sent_at
            flush, sent_at = None, time.monotonic()
            self.presenter.submit("preview", latest)

        try:
            async for request_id in link.previews():
                latest = request_id
                if flush is None:
                    wait = sent_at + PREVIEW_EVERY_S - time.monotonic()
                    if wait <= 0:
                        send()
                    else:
                        flush = asyncio.get_running_loop().call_later(wait, send)
        except LinkError as exc:
            if exc.code != "UNIMPLEMENTED":
                raise
            log.info("this coordinator asks for no previews (an older version): no console thumbnail")
            await asyncio.Event().wait()    # the session goes on without
        finally:
            if flush is not None:
                flush.cancel()

    def _pass_asset(self, asset_id: str) -> None:
        cache = self.fetcher.cache
        if asset_id in self._assets_passed or cache is None or not cache.ready(asset_id):
            return
        m = cache.manifest(asset_id)
        paths = {b.sha256: str(cache.blob_path(b.sha256)) for b in m.blobs}
        self.presenter.submit("asset", AssetFiles(asset_id=asset_id, manifest=m.canonical(), blob_paths=paths))
        self._assets_passed.add(asset_id)
        log.info("asset %s (%s) passed to the presenter for the show", asset_id[:12], m.name)

    async def _report_stream(self, link: CoordinatorLink, heartbeat_s: float, *, batch_s: float = 0.05,
                             timeline_batch_s: float | None = None) -> None:
        """The session's reports (:class:`node.session.ReportStream`): heartbeats every ``heartbeat_s``
        and at once when the fetcher has news; swaps and drops of streamed frames within ``batch_s``,
        those of the show's timeline ticks with the heartbeat (or within ``timeline_batch_s``); the
        rules are :mod:`node.report_batch`'s."""
        self._stream = ReportStream(self._heartbeat, heartbeat_s, batch_s=batch_s, timeline_batch_s=timeline_batch_s)
        try:
            await self._stream.run(link)
        finally:
            self._stream = None

    def _heartbeat(self) -> HeartbeatRecord:
        host, clock = self.session.clock_status()
        st = self.presenter.stats
        return HeartbeatRecord(assignment_revision=self.session.assignment_revision(st.revision),
                               frames_shown=st.shown, frames_late=st.late,
                               frames_dropped=st.dropped, render_ms_p50=st.render_ms_p50, host_monotonic_ns=host,
                               clock=clock, assets=self.fetcher.progress(),
                               show=replace(st.show, alone_ms=self._alone_ms), blend_id=st.blend_id,
                               blend_since_rig_ns=st.blend_since_rig_ns, decoder=st.decoder,
                               decoder_note=st.decoder_note, assignment_refused=self.session.refused)
