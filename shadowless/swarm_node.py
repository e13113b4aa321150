"""One protocol-level node of a swarm (:mod:`shadowless.swarm`): everything a node does on the
wire, nothing it does on a screen.

A :class:`SwarmNode` runs the real node's protocol core, :class:`node.session.SessionCore`, on
the node's own client, :class:`node.link.CoordinatorLink`: the same handshake, the same clock-id
rule across coordinator restarts, the same pings, heartbeats and report batching
(:class:`node.session.ReportStream`). Around it, it follows its assignments, fetches its share of
the wanted assets, follows the show's timeline (:class:`protos.timeline.Schedule`) and receives
live frame packets. It does not render: it *reports* a swap at each timeline tick and at each live
frame's ``pts`` (on its estimate of the rig clock), through the swarm's shared :class:`Ticker`, so
the coordinator's sync statistics see what they would see from real nodes. A tick the swarm wakes
up for later than ``late_ms`` after its instant is reported as a late drop, as a real node drops a
frame it cannot show on time.
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

from node.clock import ClockEstimate, LocalClock
from node.errors import CoordinatorNotTrusted
from node.link import CoordinatorLink, LinkError
from node.records import (
    AssetProgressRecord,
    DropReason,
    DropRecord,
    HeartbeatRecord,
    NodeInfo,
    ReportBatch,
    SwapRecord,
)
from node.session import ReportStream, SessionCore
from node.wire import packet_from_bytes
from protos.asset_manifest import Manifest
from protos.discovery import NothingAdvertised
from protos.host import boot_id
from protos.timeline import Schedule
from shadowless.swarm_config import SwarmConfig, SwarmStats

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
        # the real node's protocol core: handshake, clock estimate (kept by the clock-id rule), pings
        clock = LocalClock(offset_ns=int(offset * 1e6), drift_ppm=drift)
        self.session = SessionCore(slot=slot, token=cfg.token, clock=clock, info=self._info, ping_hz=cfg.ping_hz,
                                   ping_settled_s=cfg.ping_settled_s, quiet=True)
        self.loop = ticker.loop
        self.joined = False
        self.reports: ReportStream | None = None   # the session's report stream, while joined
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
            except CoordinatorNotTrusted as exc:
                self.stats.errors += 1
                log.warning("%s: %s", self.slot, exc)
                backoff = max(backoff, self.cfg.refusal_backoff_s)
            except Exception as exc:  # noqa: BLE001 - one node's failure is counted, the swarm goes on
                self.stats.errors += 1
                log.warning("%s: %s", self.slot, exc)
            backoff = min(self.cfg.backoff_max_s, backoff * 2)
            try:    # not wait_for: on 3.11 it drops a cancel that meets the set stopping event
                async with asyncio.timeout(backoff * random.uniform(0.8, 1.2)):
                    await stopping.wait()
            except TimeoutError:
                pass

    async def _session(self, target: str, stopping: asyncio.Event) -> bool:
        async with CoordinatorLink(target, own_connection=self.cfg.own_connections) as link:
            async with self._join_gate:
                joined = await self.session.join(link)
                await self.session.ping_burst(link, self._pinged)   # a first estimate, as a real node's
            self._reset_session()
            self.session_no += 1
            cfg = self.cfg
            self.reports = ReportStream(
                self._heartbeat, (cfg.heartbeat_ms or joined.reply.heartbeat_interval_ms) / 1000.0,
                batch_s=cfg.report_batch_ms / 1000.0,
                timeline_batch_s=None if cfg.timeline_batch_ms is None else cfg.timeline_batch_ms / 1000.0,
                now=self.loop.time, sent=self._sent)
            self.joined = True
            self.stats.joins += 1
            tasks = [asyncio.create_task(c) for c in (
                self._assignments(link), self._frames(link), self.reports.run(link),
                self.session.pings(link, self._pinged), self._wanted(link), self._show(link), stopping.wait())]
            try:
                await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
            finally:
                self.joined = False
                self.reports = None
                self.gen += 1
                for t in tasks:
                    t.cancel()
                done = await asyncio.gather(*tasks, return_exceptions=True)
            broken = [exc for exc in done if isinstance(exc, LinkError)]
            if broken and not stopping.is_set():     # one loss, however many of its streams broke with it
                self.stats.sessions_lost += 1
                log.info("%s lost the coordinator (%s: %s); rejoining", self.slot, broken[0].code, broken[0].details)
            for exc in done:
                if isinstance(exc, Exception) and not isinstance(exc, (LinkError, asyncio.CancelledError)):
                    self.stats.errors += 1
                    log.warning("%s: session ended by %r", self.slot, exc)
            return True

    def _info(self) -> NodeInfo:
        return NodeInfo(hostname=socket.gethostname(), host_boot_id=boot_id(), pid=os.getpid(),
                        software_version="swarm", output="swarm")

    # ---------------------------------------------------------------- clock
    def _pinged(self, est: ClockEstimate | None) -> None:
        self.stats.pings += 1

    def _host_of_rig(self, rig_ns: int) -> int | None:
        return self.session.host_time(rig_ns)

    def _rig_now(self) -> int | None:
        return self.session.rig_time(self.session.clock.host_now())

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
        timeline = kind == TICK
        if frame_id <= self.last_frame:
            self.reports.add(DropRecord(frame_id, DropReason.SUPERSEDED, timeline=timeline))
            self.dropped += 1
            self.stats.superseded += 1
        elif late_ns > self.cfg.late_ms * 1e6:   # the swarm woke up too late: it did not keep up
            self.last_frame = frame_id
            self.stats.woke_late += 1
            self._drop(frame_id, late_ns, timeline)
        else:
            self.last_frame = frame_id
            rig = self.session.rig_time(host_ns)
            self.reports.add(SwapRecord(frame_id=frame_id, pts_ns=pts_ns, swap_rig_ns=pts_ns if rig is None else rig,
                                        host_monotonic_ns=host_ns, timeline=timeline))
            self.shown += 1
            self.stats.swaps += 1
            self.stats.lateness(late_ns)
        if timeline:
            self._reschedule()

    def _drop(self, frame_id: int, late_ns: int, timeline: bool) -> None:
        self.reports.add(DropRecord(frame_id, DropReason.LATE, late_by_ns=int(late_ns), timeline=timeline))
        self.late += 1
        self.stats.late += 1

    # ---------------------------------------------------------------- reports
    def _sent(self, batch: ReportBatch) -> None:
        """Count a message of the report stream: its heartbeat, and whether it carries swaps or drops."""
        if batch.heartbeat is not None:
            self.stats.heartbeats += 1
        if batch.swaps or batch.drops:
            self.stats.reports += 1

    def _heartbeat(self) -> HeartbeatRecord:
        host, clock = self.session.clock_status()
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
        if self.reports is not None:      # news for the operator: a heartbeat at once, as a real node's
            self.reports.heartbeat_now()
