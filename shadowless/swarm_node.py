"""One protocol-level node of a swarm (:mod:`shadowless.swarm`): everything a node does on the
wire, nothing it does on a screen.

A :class:`SwarmNode` proves the rig token and joins like :mod:`node.app` (same
:class:`node.link.CoordinatorLink`, same :mod:`node.records`), keeps a
:class:`node.clock.ClockEstimator` from pings, follows its assignments, fetches its share of the
wanted assets, follows the show's timeline (:class:`protos.timeline.Schedule`) and receives live
frame packets. It does not render: it *reports* a swap at each timeline tick and at each live
frame's ``pts`` (on its estimate of the rig clock), through the swarm's shared
:class:`Ticker`, so the coordinator's sync statistics see what they would see from real nodes.
A tick the swarm wakes up for later than ``late_ms`` after its instant is reported as a late drop,
as a real node drops a frame it cannot show on time.
"""
from __future__ import annotations

import asyncio
import hashlib
import heapq
import logging
import os
import random
import socket
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import grpc

from node.clock import CLOCK_WINDOW_NS, SETTLE_SPAN_NS, ClockEstimator, ClockSample, LocalClock
from node.link import CoordinatorLink, LinkError
from node.records import (
    AssetProgressRecord,
    ClockStatus,
    DropReason,
    DropRecord,
    HeartbeatRecord,
    JoinRequest,
    NodeInfo,
    ReportBatch,
    SwapRecord,
)
from node.wire import packet_from_bytes
from protos import auth
from protos.asset_manifest import Manifest
from protos.discovery import NothingAdvertised
from protos.host import boot_id
from protos.timeline import Schedule
from protos.version import GRPC_OPTIONS, PROTOCOL_VERSION

if TYPE_CHECKING:  # pragma: no cover - types only
    from shadowless.swarm import SwarmConfig, SwarmStats

log = logging.getLogger("shadowless.swarm")

#: kinds of ticker entries
TICK, FRAME = 0, 1
#: the ticker fires every entry due within this much of the one it woke up for
COALESCE_NS = 1_000_000


class Ticker:
    """One timer for the whole swarm: entries ``(host_ns, node, generation, kind, frame_id, pts_ns)``
    fire in order of their host-clock instant (the event loop's clock is CLOCK_MONOTONIC)."""

    def __init__(self, loop: asyncio.AbstractEventLoop):
        self.loop = loop
        self._heap: list = []
        self._seq = 0
        self._handle: asyncio.TimerHandle | None = None
        self._armed_ns: int | None = None

    def at(self, host_ns: int, node: SwarmNode, gen: int, kind: int, frame_id: int, pts_ns: int) -> None:
        self._seq += 1
        heapq.heappush(self._heap, (host_ns, self._seq, node, gen, kind, frame_id, pts_ns))
        if self._armed_ns is None or host_ns < self._armed_ns:
            self._arm(host_ns)

    def _arm(self, host_ns: int) -> None:
        if self._handle is not None:
            self._handle.cancel()
        self._armed_ns = host_ns
        self._handle = self.loop.call_at(host_ns / 1e9, self._fire)

    def _fire(self) -> None:
        self._handle = self._armed_ns = None
        heap = self._heap
        now = time.monotonic_ns()
        # entries due within the next COALESCE_NS fire now too: nodes' estimates put the same tick
        # microseconds apart, and one wake-up for all of them is what lets one process drive hundreds
        # (each is still reported at its own instant)
        horizon = now + COALESCE_NS
        while heap and heap[0][0] <= horizon:
            host_ns, _, node, gen, kind, frame_id, pts_ns = heapq.heappop(heap)
            node.fire(now, host_ns, gen, kind, frame_id, pts_ns)
        if heap:
            self._arm(heap[0][0])

    def close(self) -> None:
        if self._handle is not None:
            self._handle.cancel()
        self._heap.clear()


class OwnConnectionLink(CoordinatorLink):
    """A :class:`~node.link.CoordinatorLink` on a TCP connection of its own.

    gRPC lets channels of one process to one target share a connection; real nodes, one process
    each, do not, and a coordinator serving 256 connections works more (reads, wake-ups) than one
    serving 256 nodes multiplexed on one. So each swarm node's channel gets a subchannel pool of its
    own (as the link's bulk channel already has). Replaces the link's channel attributes: keep in
    step with :mod:`node.link`.
    """

    def __init__(self, target: str):
        super().__init__(target)
        self._unused = self._channel      # never connected (channels connect on first use)
        self._channel = grpc.aio.insecure_channel(
            target, options=list(GRPC_OPTIONS) + [("grpc.use_local_subchannel_pool", 1)])
        self._stub = type(self._stub)(self._channel)
        self._frames_raw = self._channel.unary_stream(
            "/shadowless.v1.NodeLink/Frames", request_serializer=lambda msg: msg.SerializeToString(),
            response_deserializer=None)

    async def __aexit__(self, *exc) -> None:
        try:
            await self._unused.close()
        finally:
            await super().__aexit__(*exc)


def next_tick(schedule: Schedule, bases: dict[int, int], after_ns: int) -> tuple[int, int] | None:
    """``(frame_id, pts_ns)`` of the first timeline tick strictly after rig time ``after_ns``
    (None: nothing more is scheduled), as the coordinator expects it (:meth:`Schedule.ticks`)."""
    return next(schedule.ticks(bases, after_ns + 1), None)


class SwarmNode:
    """One slot of the swarm: a session with the coordinator at a time, rejoining after a loss."""

    def __init__(self, slot: str, index: int, cfg: SwarmConfig, stats: SwarmStats, ticker: Ticker,
                 targets: Callable[[], asyncio.Future[list[str]]], join_gate: asyncio.Semaphore,
                 fetch_gate: asyncio.Semaphore):
        self.slot, self.index, self.cfg, self.stats, self.ticker = slot, index, cfg, stats, ticker
        self._targets, self._join_gate, self._fetch_gate = targets, join_gate, fetch_gate
        offset = cfg.clock_offset_ms * (2.0 * random.random() - 1.0) if cfg.clock_offset_ms else 0.0
        drift = cfg.clock_drift_ppm * (2.0 * random.random() - 1.0) if cfg.clock_drift_ppm else 0.0
        self.clock = LocalClock(offset_ns=int(offset * 1e6), drift_ppm=drift)
        self.estimator = ClockEstimator(window_ns=CLOCK_WINDOW_NS)
        self.loop = ticker.loop
        self.joined = False
        self._instance = ""
        self.gen = 0                  # ticker entries of an older generation (timeline ticks) are stale
        self.session_no = 0           # ticker entries of an older session (live frames) are stale
        self._reset_session()

    def _reset_session(self) -> None:
        self.schedule = Schedule()
        self.bases: dict[int, int] = {}
        self.last_tick_pts = 0
        self.suspended_rev = -1       # a streamed frame suspends the timeline until a newer revision
        self.last_frame = 0
        self.revision = 0
        self.shown = self.late = self.dropped = 0
        self.assets: dict[str, AssetProgressRecord] = {}
        self._pending: list = []      # swaps and drops not yet batched
        self._outbox: list[ReportBatch] = []
        self._flush_handle: asyncio.TimerHandle | None = None
        self._flush_at = 0.0
        self._next_hb = 0.0
        self._heartbeat_s = 1.0
        self._wake = asyncio.Event()
        self._hb_now = False

    # ---------------------------------------------------------------- life cycle
    async def run(self, stopping: asyncio.Event) -> None:
        backoff = self.cfg.backoff_min_s
        while not stopping.is_set():
            try:
                for target in await self._targets():
                    if await self._session(target, stopping):
                        backoff = self.cfg.backoff_min_s
                        break
            except NothingAdvertised as exc:
                self.stats.discovery_waits += 1
                log.warning("%s: %s", self.slot, exc)
            except LinkError as exc:
                self.stats.errors += 1
                log.warning("%s: %s: %s", self.slot, exc.code, exc.details)
                if exc.refused:
                    backoff = max(backoff, self.cfg.refusal_backoff_s)
            except Exception as exc:  # noqa: BLE001 - one node's failure is counted, the swarm goes on
                self.stats.errors += 1
                log.warning("%s: %s", self.slot, exc)
            backoff = min(self.cfg.backoff_max_s, backoff * 2)
            try:
                await asyncio.wait_for(stopping.wait(), backoff * random.uniform(0.8, 1.2))
            except TimeoutError:
                pass

    async def _session(self, target: str, stopping: asyncio.Event) -> bool:
        async with (OwnConnectionLink(target) if self.cfg.own_connections else CoordinatorLink(target)) as link:
            async with self._join_gate:
                hb_ms = await self._handshake(link, target)
                for _ in range(8):   # a first clock estimate, as a real node does before anything else
                    await self._ping(link)
                    await asyncio.sleep(0.01)
            self._reset_session()
            self.session_no += 1
            self.joined = True
            self.stats.joins += 1
            tasks = [asyncio.create_task(c) for c in (
                self._assignments(link), self._frames(link), self._report(link, (self.cfg.heartbeat_ms or hb_ms) / 1000.0),
                self._pings(link), self._wanted(link), self._show(link), stopping.wait())]
            try:
                await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
            finally:
                self.joined = False
                self.gen += 1
                if self._flush_handle is not None:
                    self._flush_handle.cancel()
                for t in tasks:
                    t.cancel()
                done = await asyncio.gather(*tasks, return_exceptions=True)
            for exc in done:
                if isinstance(exc, LinkError) and not stopping.is_set():
                    self.stats.sessions_lost += 1
                    log.info("%s lost the coordinator (%s: %s); rejoining", self.slot, exc.code, exc.details)
                elif isinstance(exc, Exception) and not isinstance(exc, asyncio.CancelledError):
                    self.stats.errors += 1
                    log.warning("%s: session ended by %r", self.slot, exc)
            return True

    async def _handshake(self, link: CoordinatorLink, target: str) -> int:
        nonce = auth.new_nonce()
        hello = await link.hello(protocol_version=PROTOCOL_VERSION, client_nonce=nonce, slot=self.slot)
        if not auth.verify(auth.coordinator_proof(self.cfg.token, hello.rig_id, nonce, hello.server_nonce),
                           hello.server_proof):
            raise LinkError("UNAUTHENTICATED", f"the coordinator at {target} could not prove it knows the rig token",
                            refused=True)
        proof = auth.client_proof(self.cfg.token, "node", hello.rig_id, self.slot, nonce, hello.server_nonce)
        info = NodeInfo(hostname=socket.gethostname(), host_boot_id=boot_id(), pid=os.getpid(),
                        software_version="swarm", output="swarm")
        reply = await link.join(JoinRequest(protocol_version=PROTOCOL_VERSION, slot=self.slot, client_nonce=nonce,
                                            server_nonce=hello.server_nonce, client_proof=proof, info=info))
        if reply.instance_id != self._instance:
            self._instance = reply.instance_id
            self.estimator.reset()
        return reply.heartbeat_interval_ms

    # ---------------------------------------------------------------- clock
    async def _ping(self, link: CoordinatorLink) -> None:
        t0 = self.clock.now()
        rep = await link.ping(t0)
        t3 = self.clock.now()
        self.estimator.add(ClockSample(t0, rep.t1_rig_ns, rep.t2_rig_ns, t3))
        self.stats.pings += 1

    async def _pings(self, link: CoordinatorLink) -> None:
        cfg = self.cfg
        settled = False     # as node.app: once the drift is fitted over SETTLE_SPAN_NS (sticky)
        while True:
            est = self.estimator.estimate
            settled = settled or (cfg.ping_settled_s is not None and est is not None and est.drift_fitted
                                  and est.span_ns >= SETTLE_SPAN_NS)
            period = cfg.ping_settled_s if settled else 1.0 / cfg.ping_hz
            await asyncio.sleep(random.uniform(0.8, 1.2) * period)
            await self._ping(link)

    def _host_of_rig(self, rig_ns: int) -> int | None:
        est = self.estimator.estimate
        return None if est is None else self.clock.to_host(est.local_time(rig_ns))

    def _rig_now(self) -> int | None:
        est = self.estimator.estimate
        return None if est is None else est.rig_time(self.clock.now())

    # ---------------------------------------------------------------- what the coordinator sends
    async def _assignments(self, link: CoordinatorLink) -> None:
        async for a in link.assignments():
            self.revision = a.revision
            self.stats.assignments += 1

    async def _frames(self, link: CoordinatorLink) -> None:
        async for data in link.frame_packets():
            pkt = packet_from_bytes(data, self.slot, known=lambda cid: True)   # no image is decoded
            self.stats.packets += 1
            f = pkt.frame
            if f is None:
                continue
            self.stats.live_frames += 1
            self.suspended_rev = self.schedule.revision     # a streamed frame suspends the timeline
            self.gen += 1
            host = self._host_of_rig(f.pts_ns)
            now = time.monotonic_ns()
            if host is None or host < now:   # arrived after its time: the coordinator or the link was late
                self.stats.arrived_late += 1
                self._drop(f.frame_id, now - (host or now), False)
                continue
            self.ticker.at(host, self, self.session_no, FRAME, f.frame_id, f.pts_ns)

    async def _show(self, link: CoordinatorLink) -> None:
        try:
            async for upd in link.show():
                self.stats.show_updates += 1
                if upd.timeline is not None:
                    self.bases[upd.timeline.revision] = upd.frame_id_base
                    new = self.schedule.offer(upd.timeline)
                else:
                    new = self.schedule.offer_stop(upd.stop_at_ns, upd.stop_revision)
                if new:
                    self._reschedule()
        except LinkError as exc:
            if exc.code != "UNIMPLEMENTED":
                raise
            await asyncio.Event().wait()

    def _reschedule(self) -> None:
        """Schedule the next timeline tick after the last one reported (or now)."""
        self.gen += 1
        if self.suspended_rev >= self.schedule.revision:
            return
        now = self._rig_now()
        if now is None:
            return
        self.schedule.forget_before(now)
        live = {tl.revision for _, tl in self.schedule.pending if tl is not None}
        self.bases = {r: b for r, b in self.bases.items() if r in live}
        nxt = next_tick(self.schedule, self.bases, max(self.last_tick_pts, now))
        if nxt is None:
            return
        frame_id, pts = nxt
        host = self._host_of_rig(pts)
        if host is not None:
            self.ticker.at(host, self, self.gen, TICK, frame_id, pts)

    # ---------------------------------------------------------------- swaps (called by the ticker)
    def fire(self, now_ns: int, host_ns: int, gen: int, kind: int, frame_id: int, pts_ns: int) -> None:
        if not self.joined:
            return
        if kind == FRAME and gen != self.session_no:
            return
        if kind == TICK:
            if gen != self.gen:
                return
            self.last_tick_pts = pts_ns
            self.stats.ticks += 1
        late_ns = max(0, now_ns - host_ns)
        if frame_id <= self.last_frame:
            self._pending.append(DropRecord(frame_id, DropReason.SUPERSEDED))
            self.dropped += 1
            self.stats.superseded += 1
            self._schedule_flush(kind == TICK)
        elif late_ns > self.cfg.late_ms * 1e6:   # the swarm woke up too late: it did not keep up
            self.last_frame = frame_id
            self.stats.woke_late += 1
            self._drop(frame_id, late_ns, kind == TICK)
        else:
            self.last_frame = frame_id
            est = self.estimator.estimate
            local = self.clock.from_host(host_ns)
            self._pending.append(SwapRecord(frame_id=frame_id, pts_ns=pts_ns,
                                            swap_rig_ns=est.rig_time(local) if est is not None else pts_ns,
                                            host_monotonic_ns=host_ns))
            self.shown += 1
            self.stats.swaps += 1
            self.stats.lateness(late_ns)
            self._schedule_flush(kind == TICK)
        if kind == TICK:
            self._reschedule()

    def _drop(self, frame_id: int, late_ns: int, timeline: bool) -> None:
        self._pending.append(DropRecord(frame_id, DropReason.LATE, late_by_ns=int(late_ns)))
        self.late += 1
        self.stats.late += 1
        self._schedule_flush(timeline)

    def _schedule_flush(self, timeline: bool) -> None:
        """As node.app: a streamed frame's report goes within report_batch_ms (with what waits), a
        timeline tick's waits up to timeline_batch_ms (default: the heartbeat interval), or until
        the heartbeat if that is due first."""
        now = self.loop.time()
        if timeline:
            wait = self._heartbeat_s if self.cfg.timeline_batch_ms is None else self.cfg.timeline_batch_ms / 1000.0
            due = self._next_hb if self._next_hb <= now + wait else now + wait
        else:
            due = now + self.cfg.report_batch_ms / 1000.0
        if self._flush_handle is not None and self._flush_at <= due:
            return
        if self._flush_handle is not None:
            self._flush_handle.cancel()
        self._flush_at = due
        self._flush_handle = self.loop.call_at(due, self._flush)

    def _flush(self) -> None:
        self._flush_handle = None
        items, self._pending = self._pending, []
        if items:
            self._outbox.append(ReportBatch(swaps=tuple(i for i in items if isinstance(i, SwapRecord)),
                                            drops=tuple(i for i in items if isinstance(i, DropRecord))))
            self._wake.set()

    # ---------------------------------------------------------------- reports
    async def _report(self, link: CoordinatorLink, heartbeat_s: float) -> None:
        self._heartbeat_s = heartbeat_s

        async def batches():
            self._next_hb = 0.0
            while True:
                now = self.loop.time()
                if self._outbox:
                    self.stats.reports += 1
                    batch = self._outbox.pop(0)
                    if now >= self._next_hb - 0.005:     # a due heartbeat rides along with the swaps
                        self._next_hb = now + heartbeat_s
                        self.stats.heartbeats += 1
                        batch = ReportBatch(heartbeat=self._heartbeat(), swaps=batch.swaps, drops=batch.drops)
                    yield batch
                    continue
                if now >= self._next_hb or self._hb_now:
                    self._hb_now = False
                    self._next_hb = now + heartbeat_s
                    self.stats.heartbeats += 1
                    items, self._pending = self._pending, []      # what waited for the heartbeat goes with it
                    if self._flush_handle is not None:
                        self._flush_handle.cancel()
                        self._flush_handle = None
                    if items:
                        self.stats.reports += 1
                    yield ReportBatch(heartbeat=self._heartbeat(),
                                      swaps=tuple(i for i in items if isinstance(i, SwapRecord)),
                                      drops=tuple(i for i in items if isinstance(i, DropRecord)))
                    continue
                self._wake.clear()
                try:
                    async with asyncio.timeout(self._next_hb - now):
                        await self._wake.wait()
                except TimeoutError:
                    pass

        await link.report(batches())

    def _heartbeat(self) -> HeartbeatRecord:
        est = self.estimator.estimate
        host = self.clock.host_now()
        local = self.clock.from_host(host)
        clock = None
        if est is not None:
            rig = est.rig_time(local)
            clock = ClockStatus(offset_ns=rig - local, drift_ppm=est.drift * 1e6, rtt_ns=est.best_rtt_ns,
                                samples=est.samples, rig_estimate_ns=rig)
        return HeartbeatRecord(assignment_revision=self.revision, frames_shown=self.shown, frames_late=self.late,
                               frames_dropped=self.dropped, render_ms_p50=0.0, host_monotonic_ns=host, clock=clock,
                               assets=tuple(self.assets.values()))

    # ---------------------------------------------------------------- assets
    async def _wanted(self, link: CoordinatorLink) -> None:
        async for wanted in link.wanted():
            self.assets = {a: p for a, p in self.assets.items() if a in wanted.asset_ids}
            for aid in wanted.asset_ids:
                if aid not in self.assets or not self.assets[aid].ready:
                    await self._fetch(link, aid)

    async def _fetch(self, link: CoordinatorLink, aid: str) -> None:
        """The manifest (checked against the asset id), then this node's share of the blobs, each
        streamed and checked against its SHA-256 and thrown away (a swarm keeps no cache)."""
        async with self._fetch_gate:
            try:
                m = Manifest.from_bytes(await link.get_manifest(aid), asset_id=aid)
                blobs = list(m.blobs)
                if self.cfg.fetch == "one" and blobs:
                    blobs = [blobs[self.index % len(blobs)]]
                elif self.cfg.fetch == "manifest":
                    blobs = []
                for b in blobs:
                    h, n = hashlib.sha256(), 0
                    async for chunk in link.fetch_blob(b.sha256, 0):
                        h.update(chunk.data)
                        n += len(chunk.data)
                    if h.hexdigest() != b.sha256:
                        raise ValueError(f"blob {b.sha256[:12]}… of asset {aid[:12]}… does not match its SHA-256")
                    self.stats.blobs_verified += 1
                    self.stats.bytes_fetched += n
                self.assets[aid] = AssetProgressRecord(asset_id=aid, have_bytes=m.total_bytes,
                                                       total_bytes=m.total_bytes, ready=True, name=m.name)
                self.stats.assets_ready += 1
            except ValueError as exc:
                self.stats.errors += 1
                self.assets[aid] = AssetProgressRecord(asset_id=aid, error=str(exc))
                log.warning("%s: %s", self.slot, exc)
        self._hb_now = True
        self._wake.set()
