"""The rig's blend as the coordinator holds it: the stored blend, what the slots show of it, and
the failover state, with the one-line status operators read.

:class:`BlendState` belongs to the core (:class:`coordinator.server.Coordinator`). When the
coordinator opens the rig it reads the stored blend and contributions
(:mod:`coordinator.blend_store`) and gives each slot its maps; it reloads them when a ``blend``
job succeeds (it follows the :class:`~coordinator.jobs.tracker.JobTracker`). The core tells it
when a node is lost and when one is live again, and the watchdog when a lamp changed; each
changes the wanted *variant* (:mod:`coordinator.blending.failover`), and the slots switch to it
together: every changed slot gets its maps with one common rig-clock instant, a lead ahead (rig.toml's
``[blend] switch_lead_ms``; by default :func:`auto_lead_ns`: what pushing the maps to every node and
a node's taking them take, far less than the content's latency budget for small maps, more for
1080p maps to 25 nodes), so every node shows the new maps from the same swap on; a node that hears
of them after that instant shows them from its next frame. One log line per switch.

The automatic lead of a switch while no show plays (a still on screen, which every node must render
again) also learns what the rig's nodes need: each node reports the pts of its first frame
with the maps (its heartbeat), and a switch that some node showed more than :data:`LATE_SLACK_NS` after
its instant (it received the maps, or had its frame rendered again, too late) makes the next switch's
lead that switch's lead plus the latest node's delay, at most the content's latency budget (rig.toml's
``latency_ms``, what a frame is given to reach every projector); each switch every node showed in time
makes the next lead a part (:data:`LEARNED_DECAY`) shorter than its own. A rig whose nodes are quick
keeps the short lead, and a lead longer than the nodes need shrinks: it would only delay the new maps,
since a node that is late shows them as soon as it has them whatever the lead. The blend job's own
push, at once to every node, teaches the first such failover: how far apart the nodes put that same
redraw on screen; that stays the least a still's switch leads by until the next blend job, since a
switch every node showed in time cannot tell how much of its lead it needed (decaying below it made
the second failover of a P25 room rig late where the first was in time). While a show plays, each node renders its ticks anyway and a
switch costs it no redraw of its own: the lead is the maps' own, and a show's late ticks (the CPU's,
not the lead's) teach nothing.
A variant not computed ahead is computed in a worker thread, never on the event loop (and one held
compressed is inflated there).
"""
from __future__ import annotations

import asyncio
import logging
import time
from typing import Any, Callable, Mapping

from coordinator.api import BlendStatus
from coordinator.blend_store import BlendStoreError, StoredBlend, load_blend, load_contributions
from coordinator.blending.failover import DEAD_GAIN, MAX_PRECOMPUTED_BYTES, Variant, VariantKey, Variants, variant_key
from coordinator.blending.geometry_check import changed_since
from coordinator.rig import Rig
from imaging.blending.contributions import Contributions
from imaging.blending.errors import BlendError

__all__ = ["BlendState", "DEAD_GAIN", "age_text", "auto_lead_ns", "wire_bytes"]

log = logging.getLogger(__name__)

#: the kept fraction of the affected footprints above which the status says "uniformity kept"
KEPT_ENOUGH = 0.99
#: after a switch's instant, how long before the variants one more loss away are computed (s)
AHEAD_AFTER_SWITCH_S = 0.5
#: the automatic switch lead: a node's share (the assignment through its session core and presenter,
#: one texture upload, the frame on screen rendered again), and the link the maps are pushed over
AUTO_LEAD_BASE_NS = 20_000_000
AUTO_LEAD_LINK_BITS_PER_S = 1e9
#: a node that shows a switch's maps more than this after its instant was late (a swap's own jitter, and
#: the slack a slow node's single redraw is given, stay below it)
LATE_SLACK_NS = 40_000_000
#: the part of the learned lead a switch shown in time by every node gives back
LEARNED_DECAY = 0.1


def auto_lead_ns(wire_bytes: int) -> int:
    """The switch lead when rig.toml does not set one: :data:`AUTO_LEAD_BASE_NS` plus the time the
    switch's maps (``wire_bytes``, float16, every changed slot's) take on a 1 Gbit/s link from the
    coordinator (a 1080p rig's maps are about 1 MB a projector: 25 of them add 200 ms)."""
    return AUTO_LEAD_BASE_NS + int(wire_bytes * 8 / AUTO_LEAD_LINK_BITS_PER_S * 1e9)


def wire_bytes(maps) -> int:
    """What a slot's maps weigh on the wire: float16 alpha (3 channels) and beta per texel."""
    w, h = maps.size
    return w * h * 8


def age_text(seconds: float) -> str:
    """``12 s``, ``5 min``, ``3 h``, ``2 d``."""
    s = max(0.0, float(seconds))
    if s < 120:
        return f"{s:.0f} s"
    if s < 7200:
        return f"{s / 60:.0f} min"
    if s < 172800:
        return f"{s / 3600:.0f} h"
    return f"{s / 86400:.0f} d"


class BlendState:
    """The stored blend, the failover state and the switches between them.

    Parameters
    ----------
    rig : Rig
    update_slot : callable
        ``update_slot(slot, blend=..., blend_at_ns=..., source=...)``: the core's, which pushes the
        slot's new assignment to its node.
    clock_ns : callable
        The rig clock (ns).
    lead_ns : int or None
        How far ahead of now a switch takes effect (rig.toml's ``[blend] switch_lead_ms``); None:
        :func:`auto_lead_ns` of the maps each switch pushes, or what the nodes showed they need (learned).
    node_session : callable, optional
        ``node_session(slot)``: the slot's node session (its ``blend_id`` and ``blend_since_rig_ns``, what
        its heartbeat says is on screen since when), or None; the automatic lead learns from it.
    show_active : callable, optional
        Whether a show's timeline plays (its ticks are rendered anyway: a switch redraws nothing more).
    wall_clock : callable
        Unix seconds (the status's times).
    budget_bytes : int
        What the variants computed ahead may hold.
    """

    def __init__(self, rig: Rig, *, update_slot: Callable[..., Any], clock_ns: Callable[[], int], lead_ns: int | None,
                 wall_clock: Callable[[], float] = time.time, budget_bytes: int = MAX_PRECOMPUTED_BYTES,
                 node_session: Callable[[str], Any] | None = None, show_active: Callable[[], bool] | None = None):
        self.rig = rig
        self._update_slot = update_slot
        self.clock_ns = clock_ns
        self.lead_ns = None if lead_ns is None else int(lead_ns)
        self.node_session = node_session
        self.show_active = show_active
        self.last_lead_ns = 0                  # the lead of the last switch
        #: the automatic lead's parts at the last switch (ns): "auto" (maps and link), "learned", "redraw", "cap"
        self.last_lead_parts: dict[str, int] = {}
        self.learned_lead_ns = 0               # the lead the nodes showed they need (0: nothing learned)
        self.redraw_lead_ns = 0                # what the blend job's push showed a redraw on every node needs
        self.last_late_ns = 0                  # how late the latest node showed the last switch learned from
        self._pushed: tuple[int, int, dict[str, str]] | None = None   # the last switch: (instant, lead, slot -> id)
        self.wall_clock = wall_clock
        self.budget_bytes = budget_bytes
        self.stored: StoredBlend | None = None
        self.contributions: Contributions | None = None
        self.variants: Variants | None = None
        self.problem = ""                      # why there is no blend (a store that cannot be read), or ""
        self.lost_nodes: dict[str, float] = {}     # slot -> unix time its node was lost
        self.lost_at_ns: dict[str, int] = {}       # slot -> rig instant the core declared its node lost
        self.loss_counts: dict[str, int] = {}      # slot -> how often its node was lost in this run (likely again)
        self.lamp_gains: dict[str, float] = {}     # slot -> the watchdog's estimate (named lamps only)
        self.lamps_since: dict[str, float] = {}    # slot -> unix time the lamp was named
        self.applied: VariantKey = variant_key(())
        self.switched_at_ns = 0                # the rig instant of the last switch
        #: the last switch's way on the rig clock (ns): "wanted" (the state changed), "ready" (its maps at
        #: hand: held ready, or inflated or computed), "set" (every slot's assignment changed), "instant"
        self.last_switch: dict[str, int] = {}
        self._wanted_ns = 0
        self.switches = 0
        self._pending: asyncio.Task | None = None
        self._suspended = False                # a blend job measures: nothing is pushed
        self._closed = False
        self._job_seen: object | None = None
        self._unsubscribe: Callable[[], None] | None = None
        #: called after each switch with (key, variant, at_ns): tests and benchmarks follow it
        self.on_switch: Callable[[VariantKey, Variant, int], None] | None = None

    # ------------------------------------------------------------------ loading
    def load(self) -> None:
        """Read the stored blend and contributions (blocking, small) and give each slot its maps
        at once. A store that cannot be read is logged in one line and leaves the rig unblended."""
        try:
            stored = load_blend(self.rig.path)
            contrib = load_contributions(self.rig.path) if stored is not None else None
            contributions = Contributions.from_arrays(*contrib) if contrib is not None else None
        except (BlendStoreError, BlendError) as exc:
            self.problem = str(exc)
            log.warning("blend: %s; the rig runs unblended until `shadowless blend` measures again", exc)
            stored, contributions = None, None
        self._take(stored, contributions)
        if stored is not None:
            for slot, maps in stored.maps.items():
                if slot in self.rig.slots and self.rig.slot(slot).blend is not maps:
                    self._update_slot(slot, blend=maps, blend_at_ns=0, source="blend")
            log.info("blend %s loaded: %d projectors%s", self.blend_id[:8], len(stored.maps),
                     "" if contributions is not None else " (no contributions stored: no failover)")

    def _take(self, stored: StoredBlend | None, contributions: Contributions | None) -> None:
        if self.variants is not None:
            self.variants.stop_ahead()
        self.stored = stored
        self.contributions = contributions
        blended = {s: m for s, m in (stored.maps.items() if stored else ()) if s in self.rig.slots}
        self.variants = Variants(contributions, blended, budget_bytes=self.budget_bytes) \
            if stored is not None and contributions is not None and blended else None
        self.applied = variant_key(())
        if stored is not None:
            self.problem = ""

    @property
    def blend_id(self) -> str:
        if self.stored is None:
            return ""
        return str(self.stored.info.get("blend_id") or self.stored.blend_id)

    @property
    def slots(self) -> list[str]:
        """The slots of the blend (present in the rig)."""
        return [s for s in (self.stored.maps if self.stored else ()) if s in self.rig.slots]

    # ------------------------------------------------------------------ life
    def start(self, jobs=None) -> None:
        """Follow the job tracker (a blend job's end reloads) and compute the variants one loss
        away in a worker thread (call from the event loop)."""
        if jobs is not None and self._unsubscribe is None:
            self._unsubscribe = jobs.subscribe(lambda: self._job_changed(jobs))
        self._ahead()

    def close(self) -> None:
        self._closed = True
        if self._unsubscribe is not None:
            self._unsubscribe()
            self._unsubscribe = None
        if self.variants is not None:
            self.variants.stop_ahead()
        if self._pending is not None:
            self._pending.cancel()

    def _ahead(self) -> None:
        if self.variants is None or self._closed:
            return
        try:
            asyncio.get_running_loop()
        except RuntimeError:
            return

        def done(made: int, seconds: float) -> None:
            if made and self.variants is not None:
                n = self.variants.ahead_counts()
                log.info("blend: %d failover variants computed ahead in %.1f s: of the %d one change away, %d ready, "
                         "%d compressed, %d left to compute when needed (%.0f MiB)", made, seconds, n["planned"],
                         n["ready"], n["compressed"], n["not_held"], self.variants.held_bytes() / 2 ** 20)
        self.variants.start_ahead(self.applied, likely=self.loss_counts, on_done=done)

    def _job_changed(self, jobs) -> None:
        job = jobs.current
        if job is None or job.kind != "blend":
            return
        if job.state == "running":
            self._suspended = True
            return
        if job is self._job_seen:
            return
        self._job_seen = job
        self._suspended = False
        asyncio.get_running_loop().create_task(self.reload(measured=job.state == "done"), name="blend-reload")

    async def reload(self, *, measured: bool = True) -> None:
        """After a blend job: read what it stored (``measured``) and switch to the state the rig is
        in (lost nodes, named lamps); after a job that failed, put the maps back as they were."""
        if measured:
            def read():
                stored = load_blend(self.rig.path)
                contrib = load_contributions(self.rig.path) if stored is not None else None
                return stored, Contributions.from_arrays(*contrib) if contrib is not None else None
            try:
                stored, contributions = await asyncio.to_thread(read)
            except (BlendStoreError, BlendError) as exc:
                self.problem = str(exc)
                log.warning("blend: the new blend cannot be read (%s); keeping the maps on the projectors", exc)
                return
            self._take(stored, contributions)
            self._learn_from_job()
            # the measurement is the lamps' new reference: the watchdog's gains start again from 1
            self.lamp_gains.clear()
            self.lamps_since.clear()
            log.info("blend %s measured: %d projectors", self.blend_id[:8], len(self.slots))
        # the job set the new maps itself; after a failed job its maps may not be ours: push them again
        switches = self.switches
        self._want(force=not measured)
        if self.switches == switches:
            self._ahead()

    # ------------------------------------------------------------------ events
    def node_lost(self, slot: str) -> None:
        """The core declared ``slot``'s node lost: switch to the others' maps (not once closed: a
        coordinator that stops ends every session, and that is no loss to cover)."""
        if self._closed or slot not in self.slots or slot in self.lost_nodes:
            return
        self.lost_nodes[slot] = self.wall_clock()
        self.loss_counts[slot] = self.loss_counts.get(slot, 0) + 1
        self.lost_at_ns[slot] = self.clock_ns()
        self._want()

    def node_live(self, slot: str) -> None:
        """``slot``'s node is back and shows frames again (the core calls this on its swaps):
        switch back, from an instant the node has a frame on screen to show the maps with."""
        if self.lost_nodes.pop(slot, None) is None:
            return
        self.lost_at_ns.pop(slot, None)
        self._want()

    def set_lamps(self, gains: Mapping[str, float]) -> None:
        """The watchdog's named lamps (slot -> effective gain; absent: as measured): re-blend."""
        now = self.wall_clock()
        new = {s: round(float(g), 2) for s, g in gains.items() if s in self.slots}
        for s in new:
            self.lamps_since.setdefault(s, now)
        for s in list(self.lamps_since):
            if s not in new:
                del self.lamps_since[s]
        self.lamp_gains = new
        self._want()

    def wanted_key(self) -> VariantKey:
        """(lost nodes, named lamps' gains): the variant the rig should show now."""
        return variant_key(self.lost_nodes, self.lamp_gains)

    def _want(self, *, force: bool = False) -> None:
        """Switch to the wanted variant now if it is ready, else once a worker thread made it."""
        if self.variants is None or self._suspended:
            return
        key = self.wanted_key()
        if key == self.applied and not force:
            return
        self._wanted_ns = self.clock_ns()
        v = self.variants.get(key)
        if v is not None:
            self._switch(v, force=force)
            return
        if self.variants.failure(key) is not None:
            self._report_failure(key, self.variants.failure(key))
            return
        if self._pending is not None and not self._pending.done():
            self._pending.cancel()
        self._pending = asyncio.get_running_loop().create_task(self._compute_then_switch(key, force),
                                                               name="blend-variant")

    async def _compute_then_switch(self, key: VariantKey, force: bool) -> None:
        variants = self.variants
        t0 = time.perf_counter()
        how = "inflated" if variants.held(key) is not None else "computed on demand"
        try:
            v = await asyncio.to_thread(variants.compute, key)
        except BlendError as exc:
            self._report_failure(key, str(exc))
            return
        if variants is self.variants and key == self.wanted_key() and not self._suspended:
            log.info("blend: variant for %s %s in %.2f s", _describe_key(key), how, time.perf_counter() - t0)
            self._switch(v, force=force)

    async def settled(self) -> None:
        """Until a variant being computed on demand was switched to (or failed)."""
        if self._pending is not None:
            await asyncio.gather(self._pending, return_exceptions=True)

    def _report_failure(self, key: VariantKey, why: str) -> None:
        log.error("blend: cannot re-blend for %s: %s; the projectors keep their maps", _describe_key(key), why)

    def _switch(self, v: Variant, *, force: bool = False) -> None:
        ready = self.clock_ns()
        todo = []
        for slot, maps in v.maps.items():
            if slot not in self.rig.slots:
                continue
            st = self.rig.slot(slot)
            same = st.blend is not None and st.blend.blend_id == maps.blend_id
            if same and not force:
                continue
            todo.append((slot, maps))
        lead = self.lead_ns if self.lead_ns is not None else self._auto_lead(todo)
        self.last_lead_ns = lead
        at = self.clock_ns() + lead
        for slot, maps in todo:
            self._update_slot(slot, blend=maps, blend_at_ns=at, source="blend")
        out_now = set(v.key[0]) | {s for s, g in v.key[1] if g < DEAD_GAIN}     # they show nothing to learn from
        if todo and not self._playing():     # a show's late ticks are the CPU's, not the lead's
            self._pushed = (at, lead, {slot: maps.blend_id for slot, maps in todo if slot not in out_now})
        self.last_switch = {"wanted": self._wanted_ns or ready, "ready": ready, "set": self.clock_ns(), "instant": at}
        changed = len(todo)
        self.applied = v.key
        if changed:     # a switch that changed no slot puts nothing new on screen to wait for
            self.switched_at_ns = at
        self.switches += 1
        lost, gains = v.key
        if not lost and not gains:
            log.info("blend: every projector back in the blend; %d switch to the full blend from rig instant %d",
                     changed, at)
        else:
            out = set(lost) | {s for s, g in gains if g < DEAD_GAIN}
            taking_over = sum(1 for s in v.maps if s not in out)
            log.warning("blend: %s; %s take over with new maps from rig instant %d (%s)",
                        _describe_key(v.key), _projectors(taking_over), at,
                        "uniformity kept" if v.kept >= KEPT_ENOUGH else f"{v.kept:.0%} of the footprint kept")
        if self.on_switch is not None:
            self.on_switch(v.key, v, at)
        # the next variants are computed once the switch is on screen: until then the event loop
        # and the cores belong to sending the new maps
        delay = max(0.0, (at - self.clock_ns()) / 1e9) + AHEAD_AFTER_SWITCH_S
        asyncio.get_running_loop().call_later(delay, self._ahead)

    def _auto_lead(self, todo) -> int:
        """The automatic lead of a switch pushing ``todo`` ((slot, maps) pairs): :func:`auto_lead_ns` of
        its maps, or what the nodes showed the switches before needed, within the latency budget."""
        self._learn()
        auto = auto_lead_ns(sum(wire_bytes(m) for _, m in todo))
        cap = int(float(self.rig.config.latency_ms) * 1e6)
        if self._playing():     # each node renders its ticks anyway: only the maps' way there counts
            self.last_lead_parts = {"auto": auto, "learned": 0, "redraw": 0, "cap": cap}
            return auto
        learned = min(max(self.learned_lead_ns, self.redraw_lead_ns), cap)
        self.last_lead_parts = {"auto": auto, "learned": min(self.learned_lead_ns, cap), "redraw": self.redraw_lead_ns,
                                "cap": cap}
        return max(auto, learned)

    def _playing(self) -> bool:
        return self.show_active is not None and bool(self.show_active())

    def _learn_from_job(self) -> None:
        """The blend job pushed its maps to every node at once: how far apart the nodes put that same redraw
        on screen (their heartbeats) is what a switch of a still spreads over. Beyond :data:`LATE_SLACK_NS`,
        a switch while no show plays leads by :data:`AUTO_LEAD_BASE_NS` plus that spread (as if the quickest
        node had been just in time); within it, by nothing more."""
        if self.node_session is None or self.stored is None:
            return
        since = []                      # of the nodes that show the job's maps (the others tell nothing)
        for slot, maps in self.stored.maps.items():
            sess = self.node_session(slot)
            if sess is not None and not getattr(sess, "closed", False) and sess.blend_id == maps.blend_id \
                    and sess.blend_since_rig_ns > 0:
                since.append(sess.blend_since_rig_ns)
        if len(since) >= 2:
            spread = max(since) - min(since)
            self.redraw_lead_ns = AUTO_LEAD_BASE_NS + spread if spread > LATE_SLACK_NS else 0
            log.info("blend: the nodes showed the blend job's maps within %.0f ms of each other", spread / 1e6)

    def _learn(self) -> None:
        """What the last switch showed of the nodes: when the latest of them showed its maps (from their
        heartbeats; one that still shows others is as late as now). Late beyond :data:`LATE_SLACK_NS`: the
        learned lead becomes that switch's lead plus the delay; in time: it gives back a part (the lead itself
        stays at least what the blend job's push showed, :meth:`_auto_lead`)."""
        pushed, self._pushed = self._pushed, None
        if pushed is None or self.node_session is None:
            return
        at, lead, ids = pushed
        now, late, heard = self.clock_ns(), 0, 0
        for slot, blend_id in ids.items():
            sess = self.node_session(slot)
            if sess is None or getattr(sess, "closed", False):
                continue        # lost since: it tells nothing of the switch
            heard += 1
            since = sess.blend_since_rig_ns if sess.blend_id == blend_id else now
            late = max(late, since - at)
        if not heard:
            return
        self.last_late_ns = late
        # the blend job's push stays the floor: a switch every node showed in time cannot tell how much of its
        # lead it needed, so the decay below stops at what that push showed a redraw on every node needs
        cap = int(float(self.rig.config.latency_ms) * 1e6)
        if late > LATE_SLACK_NS:
            self.learned_lead_ns = min(lead + late, cap)
            log.info("blend: the last switch reached the last node's screen %.0f ms after its instant; the next "
                     "switches lead by up to %.0f ms", late / 1e6, self.learned_lead_ns / 1e6)
        else:       # in time: give back a part of the lead it had (a lead longer than needed only delays)
            self.learned_lead_ns = int(lead * (1.0 - LEARNED_DECAY))

    # ------------------------------------------------------------------ status
    def status(self) -> BlendStatus:
        """The blend and any failover, with one line for operators."""
        if self.stored is None:
            return BlendStatus(state="none", message=self.problem or "no blend: run `shadowless blend` to measure one")
        info = self.stored.info
        now = self.wall_clock()
        headroom = float(info.get("headroom", 0.0) or 0.0)
        cost = float(info.get("brightness_cost", 0.0) or 0.0)
        created = float(info.get("created_at", 0.0) or 0.0)
        lamps = tuple(sorted((s, float(g)) for s, g in self.lamp_gains.items()))
        common = dict(blend_id=self.blend_id, created_at=created, headroom=headroom, brightness_cost=cost, lamps=lamps)
        key = self.wanted_key()
        lost_nodes, gains = key
        dead = {s for s, g in gains if g < DEAD_GAIN}
        lost = set(lost_nodes) | dead
        if not lost and not gains:
            when = f"measured {age_text(now - created)} ago" if created else "measured"
            msg = f"blended ({when}): headroom {headroom:.0%} held for failover costs {cost:.0%} of brightness"
            if self.variants is None:
                msg += "; no contributions stored, so no failover"
            stale = changed_since(self.rig, info.get("slot_digests"))
            if stale:
                msg += (f"; the pose, LUT or gain of {', '.join(stale)} changed since it was measured: "
                        "run `shadowless blend` again")
            return BlendStatus(state="blended", message=msg, **common)
        since = min([*self.lost_nodes.values(), *(t for s, t in self.lamps_since.items())] or [now])
        v = self.variants.held(key) if self.variants is not None else None
        failure = self.variants.failure(key) if self.variants is not None else "no contributions stored"
        parts = []
        for s in sorted(lost):
            t = self.lost_nodes.get(s, self.lamps_since.get(s, now))
            what = f"{s} lost" if s in self.lost_nodes else f"lamp of {s} dead"
            parts.append(f"{what} {age_text(now - t)} ago")
        for s, g in gains:
            if s not in dead:
                parts.append(f"lamp of {s} at {g:.0%} for {age_text(now - self.lamps_since.get(s, now))}")
        head = ", ".join(parts)
        if failure is not None and v is None:
            return BlendStatus(state="failover", lost=tuple(sorted(lost)), since=since, covered=False,
                               message=f"{head}: cannot re-blend ({failure})", **common)
        if v is None or self.applied != key:
            return BlendStatus(state="failover", lost=tuple(sorted(lost)), since=since, covered=False,
                               message=f"{head}: computing the others' maps", **common)
        helpers = min(v.helpers.values()) if v.helpers else 0
        covered = v.kept >= KEPT_ENOUGH
        whose = "its footprint" if len(v.helpers) == 1 else "their footprints"
        cover = "covers" if helpers == 1 else "cover"
        tail = (f"{_projectors(helpers)} {cover} {whose}, uniformity kept" if covered else
                f"{_projectors(helpers)} {cover} {v.kept:.0%} of {whose}")
        return BlendStatus(state="failover", lost=tuple(sorted(lost)), since=since, covered=covered,
                           message=f"{head}: {tail}", **common)


def _describe_key(key: VariantKey) -> str:
    lost, gains = key
    parts = [f"{', '.join(sorted(lost))} lost"] if lost else []
    parts += [f"lamp of {s} dead" if g < DEAD_GAIN else f"lamp of {s} at {g:.0%}" for s, g in gains]
    return "; ".join(parts) or "full blend"


def _projectors(n: int) -> str:
    """"1 projector", "24 projectors"."""
    return f"{n} projector" if n == 1 else f"{n} projectors"
