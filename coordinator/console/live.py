"""The console's live view of the rig: a JSON snapshot pushed over server-sent events.

The snapshot is derived from :meth:`Coordinator.status` (and the rig's slots, for gains and
footprints), rounded so that only real changes change it: figures that move every instant
(ages, uptime, the show's current frame) are left out or sent as instants. While a page is
open it is recomputed at most :data:`MAX_HZ` times a second and pushed only when it changed.
Once a second, page open or not, one sample goes into a ring buffer of :data:`HISTORY_S`
seconds for the plots: the swap skew p50/p99 of the frames finished in that second, the late
frames, the worst node clock error and the coordinator's CPU time.
"""
from __future__ import annotations

import asyncio
import json
import logging
import math
import time
from collections import deque
from typing import TYPE_CHECKING, Any, Callable

import numpy as np
from aiohttp import web

from coordinator.api import BlendStatus, NodeState, NodeStatus, RigStatus
from coordinator.console.health import health_view
from coordinator.console.page_wording import job_for_the_page
from coordinator.jobs.registry import JOBS
from coordinator.rig import HomographyPose, SlotState
from coordinator.sync import FrameResult, percentile
from protos.spaces import output_outline

if TYPE_CHECKING:  # pragma: no cover - types only
    from coordinator.console.audit import ActionLog
    from coordinator.ports import ConsoleRig

log = logging.getLogger(__name__)

#: snapshots pushed at most this often (per second)
MAX_HZ = 4.0
#: seconds of samples kept for the plots (one a second)
HISTORY_S = 600
#: a comment line keeps idle event streams open through proxies (seconds)
KEEPALIVE_S = 15.0


def _num(x: float, digits: int = 2) -> float | None:
    """JSON has no NaN: None for a figure not measured."""
    return round(float(x), digits) if x is not None and math.isfinite(x) else None


def footprint(st: SlotState, content_size: tuple[int, int]) -> list[list[float]] | None:
    """Where a slot's projector output lands in content pixels: its output rectangle's four
    corners (pixel edges) mapped back through the inverse homography, or None without a
    homography pose or when a corner lies beyond the horizon (it cannot be drawn)."""
    if not isinstance(st.pose, HomographyPose):
        return None
    xy = output_outline(st.pose.matrix, (st.width, st.height), content_size)
    if xy is None or np.abs(xy).max() > 1e6:
        return None
    return [[round(float(x), 1), round(float(y), 1)] for x, y in xy]


def snapshot(status: RigStatus, coord: "ConsoleRig", actions: list[dict[str, Any]],
             footprints: dict[tuple, list[list[float]] | None] | None = None,
             logins: dict[str, Any] | None = None) -> dict[str, Any]:
    """The page's view of the rig (JSON-able, stable while nothing changes). ``footprints`` caches
    each slot's footprint by its assignment (slot, revision, size); ``logins`` is the console's
    login figures (``ConsoleApp.login_figures``)."""
    rig = coord.rig
    footprints = {} if footprints is None else footprints
    content = (rig.config.content_width, rig.config.content_height)
    now = time.time()
    refused_slots: dict[str, Any] = {}
    refusals = []
    for r in status.refusals:
        item = {"peer": r.peer, "slot": r.slot, "reason": r.reason, "count": r.count, "at": round(now - r.age_s)}
        refusals.append(item)
        refused_slots.setdefault(r.slot, item)      # newest first
    slots = []
    for n in status.nodes:
        st = rig.slots.get(n.slot)
        state = n.state.value
        if n.state not in (NodeState.LIVE, NodeState.JOINED) and n.slot in refused_slots:
            state = "refused"
        slots.append({
            "slot": n.slot, "state": state, "node_state": n.state.value, "host": n.hostname, "pid": n.pid,
            "output": n.output, "gl": n.gl, "decoder": n.decoder, "software": n.software_version,
            **_clock(n),
            "frames_shown": n.frames_shown, "frames_late": n.frames_late, "frames_dropped": n.frames_dropped,
            "assets_ready": n.assets_ready, "assets_wanted": n.assets_wanted, "joins": n.joins,
            "pose_kind": n.pose_kind, "gain": st.gain if st is not None else None,
            "size": [st.width, st.height] if st is not None else None,
            "footprint": _cached_footprint(footprints, st, content) if st is not None else None,
            "refusal": refused_slots.get(n.slot),
        })
    s, sh = status.sync, status.show
    return {
        "rig": {"name": status.rig_name, "id": status.rig_id, "instance": status.instance_id,
                "protocol": status.protocol_version, "content_size": list(content),
                "latency_budget_ms": _num(status.latency_budget_ms, 1)},
        "showing": status.showing,
        "show": {"state": sh.state, "name": sh.name, "asset_id": sh.asset_id, "frames": sh.frames,
                 "fps": _num(sh.fps, 3), "loop": sh.loop, "paused": sh.paused},
        "sync": {"frames": s.frames, "skew_p50_ms": _num(s.skew_p50_ms, 3), "skew_p99_ms": _num(s.skew_p99_ms, 3),
                 "skew_max_ms": _num(s.skew_max_ms, 3), "skew_source": s.skew_source,
                 "clock_error_p99_ms": _num(s.clock_error_p99_ms, 3), "frames_late": s.frames_late,
                 "frames_dropped": s.frames_dropped},
        "slots": slots,
        "blend": _blend(status),
        "cues": coord.cue_state().to_json() if hasattr(coord, "cue_state") else None,   # console/cues.py
        "health": health_view(status, now=now),
        "refusals": refusals,
        "before_auth": _before_auth(status),
        "logins": logins or {},
        "assets": [{"id": aid, "name": m.name, "kind": m.kind, "frames": m.frames}
                   for aid, m in sorted(coord.asset_manifests().items(), key=lambda t: (t[1].name, t[0]))],
        "actions": actions,
        "job": job_for_the_page(coord.job_snapshot()),      # refusals in the form's words, not flags
        "job_kinds": list(JOBS),
    }


def _clock(n: NodeStatus) -> dict[str, float | None]:
    """A node's clock figures for the page: None ("–") unless they are current, that is it is
    joined or live and made a clock exchange; a lost or departed node's figures are its last
    report's and an expected slot has none (the rule of `shadowless status`,
    :func:`rigctl.commands.clock_current`)."""
    if n.state not in (NodeState.LIVE, NodeState.JOINED) or n.clock_rtt_ms <= 0:
        return {"clock_offset_ms": None, "clock_drift_ppm": None, "clock_rtt_ms": None, "clock_error_ms": None}
    return {"clock_offset_ms": _num(n.clock_offset_ms, 1), "clock_drift_ppm": _num(n.clock_drift_ppm, 1),
            "clock_rtt_ms": _num(n.clock_rtt_ms, 1), "clock_error_ms": _num(n.clock_error_ms, 2)}


def _blend(status: RigStatus) -> dict[str, Any]:
    """The blend and any failover: instants as unix times (the page counts the time since itself,
    so the snapshot does not change every second), and of the coordinator's line only what does
    not count time (:func:`stable_message`)."""
    b = status.blend
    return {"state": b.state, "blend_id": b.blend_id, "created_at": _num(b.created_at, 3) if b.created_at else None,
            "headroom": _num(b.headroom, 4), "brightness_cost": _num(b.brightness_cost, 4), "lost": list(b.lost),
            "since": _num(b.since, 3) if b.since else None, "covered": b.covered,
            "lamps": [{"slot": s, "gain": _num(g, 3)} for s, g in b.lamps], "message": stable_message(b)}


def stable_message(b: BlendStatus) -> str:
    """The part of the blend's line (``coordinator.blending.state``) that does not count time.

    In failover the line is ``WHO AND SINCE WHEN: VERDICT`` (``r2c3 lost 12 s ago: 24 projectors
    cover its footprint, uniformity kept``): the verdict. Blended, it is ``measured 2 h ago ...;
    NOTE``: the note, if any. With no blend it holds no age: all of it.
    """
    if b.state == "failover":
        return b.message.partition(": ")[2].strip()
    if b.state == "blended":
        return b.message.partition("; ")[2].strip()
    return b.message


def _before_auth(status: RigStatus) -> dict[str, Any]:
    """Calls without a session (coordinator/admission.py): the budget, what is in flight, what was
    refused over it or malformed since start."""
    a = status.admission
    return {"refused": a.refused, "malformed": a.malformed, "admitted": a.admitted,
            "in_flight_calls": a.in_flight_calls, "in_flight_mib": round(a.in_flight_bytes / 2**20, 1),
            "peak_mib": round(a.peak_bytes / 2**20, 1), "max_calls": a.max_calls,
            "max_mib": round(a.max_bytes / 2**20, 1), "max_calls_per_address": a.max_calls_per_address,
            "max_mib_per_address": round(a.max_bytes_per_address / 2**20, 1), "waited": a.waited}


def _cached_footprint(cache: dict, st: SlotState, content: tuple[int, int]) -> list[list[float]] | None:
    key = (st.name, st.revision, st.width, st.height, content)
    if key not in cache:
        if len(cache) > 4096:
            cache.clear()
        cache[key] = footprint(st, content)
    return cache[key]


class Live:
    """Keeps the snapshot and the plot samples; wakes the open event streams when either changes."""

    def __init__(self, coord: "ConsoleRig", audit: "ActionLog", *, max_hz: float = MAX_HZ,
                 history_s: int = HISTORY_S):
        self.coord, self.audit = coord, audit
        self.period_s = 1.0 / max_hz
        self.history: deque[dict[str, Any]] = deque(maxlen=history_s)
        self.samples_taken = 0
        self.snapshot_json = ""
        self.version = 0
        self.pushes = 0                 # snapshots computed that differed from the last (for tests, benchmarks)
        self._subscribers: set[asyncio.Event] = set()
        self._poke = asyncio.Event()
        self._closing = asyncio.Event()
        self._task: asyncio.Task | None = None
        self._frames: list[FrameResult] = []
        self._unlisten: Callable[[], None] | None = None
        self._cpu_last: tuple[float, float] | None = None
        self._footprints: dict[tuple, list[list[float]] | None] = {}
        self.logins: Callable[[], dict[str, Any]] = dict     # the console's login figures (set by the console)

    # ------------------------------------------------------------------ life cycle
    def start(self) -> None:
        self._unlisten = self.coord.listen_frames(self._frames.append)
        self._task = asyncio.create_task(self._run(), name="console-live")

    async def stop(self) -> None:
        self._closing.set()
        for ev in self._subscribers:
            ev.set()
        if self._unlisten is not None:
            self._unlisten()
            self._unlisten = None
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)

    def poke(self) -> None:
        """Recompute soon (an action changed the rig or the log)."""
        self._poke.set()

    # ------------------------------------------------------------------ sampling
    def _sample(self, status: RigStatus) -> None:
        frames, self._frames[:] = list(self._frames), []
        skews = [f.skew_ms for f in frames]
        errors = [abs(n.clock_error_ms) for n in status.nodes
                  if n.state == NodeState.LIVE and math.isfinite(n.clock_error_ms)]
        now_wall, cpu = time.time(), status.cpu_s
        cpu_ms = None
        if self._cpu_last is not None and now_wall > self._cpu_last[0]:
            cpu_ms = _num(1e3 * (cpu - self._cpu_last[1]) / (now_wall - self._cpu_last[0]), 1)
        self._cpu_last = (now_wall, cpu)
        self.history.append({
            "t": round(now_wall, 3), "frames": len(frames),
            "skew_p50_ms": _num(percentile(skews, 50), 3), "skew_p99_ms": _num(percentile(skews, 99), 3),
            "late": int(sum(f.late for f in frames)), "clock_error_ms": _num(max(errors), 3) if errors else None,
            "cpu_ms_per_s": cpu_ms,
        })
        self.samples_taken += 1

    def _refresh(self, status: RigStatus) -> bool:
        text = json.dumps(snapshot(status, self.coord, self.audit.recent(), self._footprints, self.logins()),
                          sort_keys=True, allow_nan=False)
        if text == self.snapshot_json:
            return False
        self.snapshot_json = text
        self.version += 1
        self.pushes += 1
        return True

    def current(self) -> str:
        """The snapshot now (computed if no stream keeps it fresh)."""
        if not self._subscribers or not self.snapshot_json:
            self._refresh(self.coord.status())
        return self.snapshot_json

    async def _run(self) -> None:
        next_sample = time.monotonic()
        last = 0.0
        while True:
            try:    # not wait_for: on 3.11 it drops a cancel that meets a poke, and stop() hung
                async with asyncio.timeout(self.period_s):
                    await self._poke.wait()
            except TimeoutError:
                pass
            self._poke.clear()
            wait = last + self.period_s - time.monotonic()
            if wait > 0:
                await asyncio.sleep(wait)       # at most max_hz pushes, however often it is poked
            last = time.monotonic()
            try:
                status = None
                changed = False
                if last >= next_sample:
                    next_sample = max(next_sample + 1.0, last - 1.0)
                    status = self.coord.status()
                    self._sample(status)
                    changed = True
                if self._subscribers:
                    changed = self._refresh(status or self.coord.status()) or changed
                    if changed:
                        for ev in self._subscribers:
                            ev.set()
            except Exception:  # noqa: BLE001 - the console must not take the coordinator down
                log.exception("console: cannot build the rig snapshot")

    # ------------------------------------------------------------------ the event stream
    async def stream(self, request: web.Request, alive: Callable[[], bool],
                     headers: dict[str, str] | None = None) -> web.StreamResponse:
        """``GET /api/events``: ``snapshot`` events (the whole view, when it changed), a ``history``
        event at the start and a ``sample`` event per second; ends when ``alive()`` turns false
        (logout, expiry) or the console stops."""
        resp = web.StreamResponse(headers={**(headers or {}), "Content-Type": "text/event-stream",
                                           "Cache-Control": "no-store", "X-Accel-Buffering": "no"})
        await resp.prepare(request)
        ev = asyncio.Event()
        self._subscribers.add(ev)
        try:
            sent_version = -1
            sent_samples = self.samples_taken
            await resp.write(_event("history", json.dumps(list(self.history), allow_nan=False)))
            self.poke()
            if not self.snapshot_json:
                self._refresh(self.coord.status())
            last_write = time.monotonic()
            while not self._closing.is_set() and alive():
                if self.version != sent_version and self.snapshot_json:
                    sent_version = self.version
                    await resp.write(_event("snapshot", self.snapshot_json))
                    last_write = time.monotonic()
                new = min(self.samples_taken - sent_samples, len(self.history))
                if new > 0:
                    for s in list(self.history)[-new:]:
                        await resp.write(_event("sample", json.dumps(s, allow_nan=False)))
                    last_write = time.monotonic()
                sent_samples = self.samples_taken
                if time.monotonic() - last_write > KEEPALIVE_S:
                    await resp.write(b": keepalive\n\n")
                    last_write = time.monotonic()
                ev.clear()
                try:    # not wait_for: on 3.11 it drops a cancel that meets a set event
                    async with asyncio.timeout(KEEPALIVE_S):
                        await ev.wait()
                except TimeoutError:
                    pass
        except ConnectionResetError:
            pass
        finally:
            self._subscribers.discard(ev)
        return resp


def _event(name: str, data: str) -> bytes:
    return f"event: {name}\ndata: {data}\n\n".encode()
