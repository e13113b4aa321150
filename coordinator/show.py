"""The timeline show: an asset of the rig's store played by every node from a timeline.

The coordinator holds one :class:`~protos.timeline.Timeline` (or none, or a stop) and sends
only it and its changes to the nodes (the NodeLink ``Show`` stream: the state at once, every
change, a beacon every BEACON_S seconds); each node decodes the asset from its own cache and swaps
frame ``k`` at ``anchor_ns + k / rate`` on its estimate of the rig clock. No frame data travels.

Rules, as built:

* **Changes at an instant.** Every change (start, pause, resume, seek, stop) takes effect at a
  rig-clock instant at least ``lead_ns`` ahead (default: the latency budget, at least 150 ms),
  so every node hears of it before it happens. ``revision`` orders every change, stops
  included; it keeps growing across stops, shows and coordinator restarts.
* **Frame ids.** Tick ``k`` of a revision (the ``k``-th frame period from its anchor) is
  reported by the nodes as frame ``frame_id_base + k``. Each revision's base is taken above
  every id of the coordinator's frame counter and above every tick id its predecessor can show
  before the change, so ids grow strictly along the show and the coordinator's out-of-order
  check and sync tracker work on them as on any frame. The coordinator expects (sync tracker)
  the ids of the ticks a little ahead of their time, for the live nodes that hold the asset.
* **Readiness.** A show does not start while a live node lacks the asset (the error names the
  nodes and their progress) unless the request says ``start_without``.
* **Precedence.** A still, a job's pattern or a played sequence stops the show at once
  (:meth:`Show.takeover`, which also moves the coordinator's frame counter above every tick id
  that may still be shown); nodes likewise suspend a timeline when a coordinator frame reaches
  them, until a newer revision arrives. A show's start stops a played sequence.
* **Persistence.** The current state is written to ``show.json`` in the rig directory (atomic)
  at every change; a restarted coordinator takes the running show back (its anchors are on the
  rig clock, the host's monotonic clock: after a reboot they are moved by the wall clock).
"""
from __future__ import annotations

import asyncio
import itertools
import json
import logging
import time
from dataclasses import dataclass, replace
from fractions import Fraction
from pathlib import Path
from typing import Callable, Iterable, Mapping, Protocol

from coordinator.api import AssetProgress, ShowState
from coordinator.errors import CoordinatorError
from protos.store import atomic_write_json
from protos.asset_manifest import Manifest
from protos.host import boot_id
from protos.timeline import Schedule, Timeline, TimelineError, as_rate

log = logging.getLogger(__name__)

SHOW_FILE = "show.json"
MIN_LEAD_NS = 150_000_000
#: seconds between beacons repeating the timeline on each node's Show stream. Every change is sent at
#: once on a reliable stream, so a beacon is only a reminder; each costs the coordinator a stream
#: message per node (~0.2 ms of CPU with grpc.aio), which at 1 s was 40 % of the 0.5 ms per node
#: and second a timeline show may cost (measured with `shadowless bench swarm`)
BEACON_S = 5.0
#: how far ahead of their time tick ids are given to the sync tracker
EXPECT_AHEAD_NS = 600_000_000
#: ids reserved past a takeover (ticks a node may still swap in before it hears of it)
TAKEOVER_MARGIN_NS = 2_000_000_000


class ShowError(CoordinatorError):
    """A show operation is refused; the message says why and what to do."""


class FrameIds(Protocol):
    """The coordinator's frame id counter (:class:`coordinator.playback.Playback`)."""

    def new_frame_id(self) -> int: ...

    def reserve_ids_through(self, last_id: int) -> None: ...


@dataclass(frozen=True)
class ShowUpdate:
    """One message of the Show stream: a timeline and its tick-0 frame id, or a stop."""

    timeline: Timeline | None = None
    frame_id_base: int = 0
    stop_at_ns: int = 0
    stop_revision: int = 0
    beacon: bool = False

    @property
    def revision(self) -> int:
        return self.timeline.revision if self.timeline is not None else self.stop_revision


def ticks_before(tl: Timeline, t_ns: int) -> int:
    """How many frame periods of ``tl`` begin before ``t_ns`` (a paused timeline has one)."""
    if t_ns <= tl.anchor_ns:
        return 0
    if tl.paused:
        return 1
    return tl.tick_at(t_ns - 1) + 1


def manifest_rate(m: Manifest) -> Fraction:
    """An asset's exact frame rate: the manifest's ``extra.rate`` ("num/den") or its fps."""
    text = str(m.extra.get("rate", ""))
    try:
        num, _, den = text.partition("/")
        rate = Fraction(int(num), int(den or 1))
        if 0 < rate <= 1000:
            return rate
    except (ValueError, ZeroDivisionError):
        pass
    return as_rate(m.fps if m.fps > 0 else 1)


class Show:
    """The show state and its operations (see the module docstring).

    Parameters
    ----------
    rig_dir : Path
        Where ``show.json`` lives.
    resolve : callable
        ``resolve(key) -> asset_id`` for an id, a unique prefix or a unique name
        (:class:`~coordinator.errors.AssetError` otherwise).
    manifest : callable
        ``manifest(asset_id) -> Manifest``.
    ids : FrameIds
        The coordinator's frame id counter.
    progress : callable
        ``progress(asset_id) -> {slot: AssetProgress or None}`` over the live nodes (None: the
        node reported nothing about it yet).
    clock_ns : callable
        The rig clock.
    lead_ns : int
        How far ahead of now a change takes effect by default.
    """

    def __init__(self, rig_dir: Path, *, resolve: Callable[[str], str], manifest: Callable[[str], Manifest],
                 ids: FrameIds, progress: Callable[[str], Mapping[str, AssetProgress | None]],
                 clock_ns: Callable[[], int] = time.monotonic_ns, lead_ns: int = MIN_LEAD_NS):
        self.path = Path(rig_dir) / SHOW_FILE
        self._resolve, self._manifest, self.ids, self._progress = resolve, manifest, ids, progress
        self.clock_ns = clock_ns
        self.lead_ns = int(lead_ns)
        self.timeline: Timeline | None = None
        self.frame_id_base = 0
        self.name = ""
        self.stop_at_ns: int | None = None
        self.stop_revision = 0
        self.revision = 0
        self.schedule = Schedule()
        self._bases: dict[int, int] = {}
        self._expected_until: int | None = None
        self._subscribers: set[asyncio.Event] = set()
        self._load()

    # ------------------------------------------------------------------ reading
    @property
    def active(self) -> bool:
        """A timeline is in force or scheduled and no stop is (the show may have ended)."""
        return self.timeline is not None and self.stop_at_ns is None

    def update(self, *, beacon: bool = False) -> ShowUpdate | None:
        """What the Show stream sends now (None: there never was a show)."""
        if self.stop_at_ns is not None:
            return ShowUpdate(stop_at_ns=self.stop_at_ns, stop_revision=self.stop_revision, beacon=beacon)
        if self.timeline is None:
            return None
        return ShowUpdate(timeline=self.timeline, frame_id_base=self.frame_id_base, beacon=beacon)

    def state(self) -> ShowState:
        """The operator's view at the rig clock's now."""
        now = self.clock_ns()
        tl = self.timeline
        if tl is None:
            return ShowState(now_ns=now, revision=self.revision)
        governing = self.schedule.at(now)
        frame = governing.frame_at(now) if governing is not None else None
        if self.stop_at_ns is not None and now >= self.stop_at_ns:
            state, frame = "stopped", None
        elif now < tl.anchor_ns and governing is None:
            state = "scheduled"
        elif governing is not None and governing.paused:
            state = "paused"
        elif frame is None and governing is not None:
            state = "ended"
        else:
            state = "paused" if tl.paused else "playing"
        change = self.stop_at_ns if self.stop_at_ns is not None else tl.anchor_ns
        return ShowState(state=state, asset_id=tl.asset_id, name=self.name, frames=tl.frames,
                         rate_num=tl.rate.numerator, rate_den=tl.rate.denominator, anchor_ns=tl.anchor_ns,
                         anchor_frame=tl.anchor_frame, loop=tl.loop, paused=tl.paused, revision=self.revision,
                         frame_id_base=self.frame_id_base, frame=-1 if frame is None else frame, now_ns=now,
                         change_at_ns=change)

    def describe(self) -> str:
        """One line for ``status``'s "showing"."""
        st = self.state()
        if st.state == "none":
            return "nothing"
        what = f"asset {st.name or st.asset_id[:12]}"
        if st.state in ("playing", "paused"):
            return (f"{what} {st.state}{' looping' if st.loop else ''} at frame {st.frame}/{st.frames} "
                    f"({st.fps:.3g} fps)")
        return f"{what} {st.state}"

    # ------------------------------------------------------------------ operations
    def _when(self, at_ns: int | None, delay_ns: int | None) -> int:
        now = self.clock_ns()
        if at_ns:
            if at_ns < now:
                raise ShowError(f"rig time {at_ns} is {(now - at_ns) / 1e6:.0f} ms in the past")
            return int(at_ns)
        return now + (int(delay_ns) if delay_ns and delay_ns > 0 else self.lead_ns)

    def _next_revision(self) -> int:
        self.revision += 1
        return self.revision

    def _missing_nodes(self, asset_id: str) -> list[str]:
        out = []
        for slot, p in sorted(self._progress(asset_id).items()):
            if p is not None and p.ready:
                continue
            if p is None or not p.total_bytes:
                out.append(f"{slot} (nothing fetched yet)")
            else:
                why = f"; gave up: {p.error}" if p.error else ""
                out.append(f"{slot} ({100.0 * p.have_bytes / p.total_bytes:.0f}%, {p.have_bytes / 1e6:.1f} of "
                           f"{p.total_bytes / 1e6:.1f} MB{why})")
        return out

    def play(self, key: str, *, at_ns: int | None = None, delay_ns: int | None = None, loop: bool = False,
             fps: float | None = None, start_without: bool = False, fade_ns: int = 0) -> ShowState:
        """Start asset ``key`` (id, prefix or name) at ``at_ns`` (or ``delay_ns`` / the lead from now);
        ``fade_ns``: the nodes crossfade into it from what they show (a cue's fade, :mod:`protos.fade`).

        Raises :class:`~coordinator.errors.AssetError` for an unknown asset, :class:`ShowError`
        when a live node lacks it (unless ``start_without``), ValueError for a bad ``fps``.
        """
        asset_id = self._resolve(key)
        m = self._manifest(asset_id)
        rate = as_rate(fps) if fps else manifest_rate(m)
        if not start_without:
            missing = self._missing_nodes(asset_id)
            if missing:
                raise ShowError(f"asset {m.name or asset_id[:12]} is not on every live node yet: "
                                f"{', '.join(missing)}; wait for them (`shadowless status`) or start without them "
                                "(--start-without)")
        t = self._when(at_ns, delay_ns)
        tl = Timeline(asset_id=asset_id, frames=m.frames, rate=rate, anchor_ns=t, anchor_frame=0, loop=loop,
                      paused=False, revision=self._next_revision(), fade_ns=max(0, int(fade_ns)))
        self.name = m.name
        self._apply(tl)
        log.info("show: asset %s (%s) plays at %s fps%s from rig time %d (revision %d)", asset_id[:12], m.name,
                 rate, ", looping" if loop else "", t, tl.revision)
        return self.state()

    def _current(self, verb: str) -> Timeline:
        if self.timeline is None or self.stop_at_ns is not None:
            raise ShowError(f"nothing to {verb}: no show is playing (start one with `shadowless play ASSET`)")
        return self.timeline

    def pause(self, *, at_ns: int | None = None, delay_ns: int | None = None) -> ShowState:
        """Hold the frame on the projectors at the change's instant."""
        cur = self._current("pause")
        if cur.paused:
            return self.state()
        t = self._when(at_ns, delay_ns)
        self._apply(replace(cur.paused_at(max(t, cur.anchor_ns)), revision=self._next_revision()))
        return self.state()

    def resume(self, *, at_ns: int | None = None, delay_ns: int | None = None) -> ShowState:
        """Go on from the held frame."""
        cur = self._current("resume")
        if not cur.paused:
            return self.state()
        t = self._when(at_ns, delay_ns)
        self._apply(replace(cur.resumed_at(max(t, cur.anchor_ns)), revision=self._next_revision()))
        return self.state()

    def seek(self, frame: int, *, at_ns: int | None = None, delay_ns: int | None = None) -> ShowState:
        """Show ``frame`` at the change's instant and go on from there (a paused show stays paused)."""
        cur = self._current("seek")
        t = self._when(at_ns, delay_ns)
        try:
            tl = cur.seeked(int(frame), max(t, cur.anchor_ns))
        except TimelineError as exc:
            raise ShowError(str(exc)) from None
        self._apply(replace(tl, revision=self._next_revision()))
        return self.state()

    def stop(self, *, at_ns: int | None = None, delay_ns: int | None = None) -> ShowState:
        """End the show at the change's instant (the projectors go black)."""
        if self.timeline is None or self.stop_at_ns is not None:
            return self.state()
        self._stop_at(self._when(at_ns, delay_ns))
        return self.state()

    def takeover(self) -> None:
        """A still, a pattern or a played sequence takes the projectors: the show stops now and the
        frame counter moves above every tick id a node may still swap in."""
        if self.active:
            log.info("show: stopped by a still, a pattern or a sequence")
            self._stop_at(self.clock_ns())

    def _stop_at(self, t: int) -> None:
        tl = self.timeline
        assert tl is not None
        self.stop_revision = self._next_revision()
        self.stop_at_ns = t
        self.schedule.offer_stop(t, self.stop_revision)
        self.ids.reserve_ids_through(self.frame_id_base + ticks_before(tl, t + TAKEOVER_MARGIN_NS) + 1)
        self._changed()

    def _apply(self, tl: Timeline) -> None:
        base = self.ids.new_frame_id() + 1
        prev = self.timeline
        if prev is not None:
            base = max(base, self.frame_id_base + ticks_before(prev, tl.anchor_ns) + 1)
        self.timeline, self.frame_id_base, self.stop_at_ns = tl, base, None
        self.schedule.offer(tl)
        self._bases[tl.revision] = base
        self._changed()

    def _changed(self) -> None:
        self.schedule.forget_before(self.clock_ns())
        live = {tl.revision for _, tl in self.schedule.pending if tl is not None}
        self._bases = {r: b for r, b in self._bases.items() if r in live}
        self._save()
        for ev in list(self._subscribers):
            ev.set()

    # ------------------------------------------------------------------ following
    def subscribe(self, event: asyncio.Event) -> Callable[[], None]:
        """``event`` is set at every change; returns the call that unsubscribes it."""
        self._subscribers.add(event)
        return lambda: self._subscribers.discard(event)

    @property
    def followers(self) -> int:
        """How many followers (the nodes' Show streams) are subscribed now: one per open stream, none
        left by a stream that ended."""
        return len(self._subscribers)

    def upcoming_ticks(self, *, ahead_ns: int = EXPECT_AHEAD_NS) -> list[tuple[int, int]]:
        """``(frame_id, pts_ns)`` of the ticks due up to ``ahead_ns`` from now not listed before
        (each tick is listed once; ticks of a change the coordinator did not know yet are not)."""
        now = self.clock_ns()
        lo = now if self._expected_until is None else max(self._expected_until, now - ahead_ns)
        hi = now + ahead_ns
        self._expected_until = hi
        return list(itertools.islice(self.schedule.ticks(self._bases, lo, hi), 10_000))

    def ready_slots(self, slots: Iterable[str]) -> set[str]:
        """Of ``slots``, those that hold the show's asset."""
        if self.timeline is None:
            return set()
        progress = self._progress(self.timeline.asset_id)
        return {s for s in slots if (p := progress.get(s)) is not None and p.ready}

    # ------------------------------------------------------------------ persistence
    def _save(self) -> None:
        doc = {"version": 1, "revision": self.revision, "name": self.name, "frame_id_base": self.frame_id_base,
               "timeline": self.timeline.to_json() if self.timeline is not None else None,
               "stop_at_ns": self.stop_at_ns, "stop_revision": self.stop_revision,
               "mono_ns": self.clock_ns(), "wall_ns": time.time_ns(), "boot_id": boot_id()}
        try:
            atomic_write_json(self.path, doc)
        except OSError as exc:
            log.error("cannot save the show to %s: %s (a restarted coordinator would not take it back)",
                      self.path, exc)

    def _load(self) -> None:
        try:
            doc = json.loads(self.path.read_text())
        except FileNotFoundError:
            return
        except (OSError, ValueError) as exc:
            log.warning("ignoring %s: %s", self.path, exc)
            return
        try:
            self.revision = int(doc.get("revision", 0))
            self.name = str(doc.get("name", ""))
            shift = 0
            if doc.get("boot_id") != boot_id():   # another boot: the monotonic clock restarted
                shift = (self.clock_ns() - time.time_ns()) - (int(doc["mono_ns"]) - int(doc["wall_ns"]))
            if doc.get("timeline") is not None:
                tl = Timeline.from_json(doc["timeline"])
                tl = replace(tl, anchor_ns=tl.anchor_ns + shift)
                self.timeline, self.frame_id_base = tl, int(doc["frame_id_base"])
                self.schedule.offer(tl)
                self._bases[tl.revision] = self.frame_id_base
                self.ids.reserve_ids_through(self.frame_id_base)
            if doc.get("stop_at_ns") is not None:
                self.stop_at_ns, self.stop_revision = int(doc["stop_at_ns"]) + shift, int(doc["stop_revision"])
                self.schedule.offer_stop(self.stop_at_ns, self.stop_revision)
        except (KeyError, TypeError, ValueError) as exc:
            log.warning("ignoring %s: %s", self.path, exc)
            self.timeline, self.stop_at_ns = None, None
            self.schedule = Schedule()
            return
        if self.active:
            log.info("show: took back the running show (asset %s, revision %d)", self.timeline.asset_id[:12],
                     self.revision)
