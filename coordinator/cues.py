"""The cue list's engine on the core: the show as a list of cues fired with GO, back and jump.

The list (:class:`protos.cues.CueList`) is stored in the rig directory as ``cues.json``
(atomically, with the current cue), so a restarted coordinator knows where the show was and
shows the current cue again (a still, a pattern or black; a timeline show of a video takes
itself back from ``show.json``). Firing a cue:

* ``still``: ``content`` is the rig's content; any other target is a still asset of the store
  (decoded and fitted off the event loop, kept for the next time). ``asset``: a still asset is
  shown as a still; a video or sequence plays as a timeline show (:mod:`coordinator.show`) on
  every projector, its first frames mixed with what was on screen during a fade. ``blackout``: black.
  ``pattern``: a test pattern (:mod:`coordinator.slot_tools`). A cue's ``slots`` show it, the
  others black.
* **Crossfades** (``fade_s``) are done by the nodes from what they show, every node from the same
  rig instant (a latency budget ahead) and with the same mix at every step (:mod:`protos.fade`,
  :mod:`node.fade`). Patterns are projector pixels and cut.
* **Auto-follow** (``follow_s``): the next cue fires that many seconds after this one reached the
  screen, on the rig clock. Any manual GO, back, jump or new list cancels it, and so does anything
  else taking the projectors meanwhile (a show, stop, blackout or job from elsewhere).
* Every fire is logged, and is one entry of the action log with who fired it. A GO, back or jump
  asked through an edge that writes its own entry for it (the console, OSC, the command line: they
  call inside :func:`edge_logs`) is that entry; the engine writes one (:attr:`CueEngine.on_fire`,
  attached by the console) for the fires nobody asked for through an edge (``follow`` for an
  auto-follow, a direct call on the core) and for a fire whose picture fails after the edge heard
  it fires (a still that does not decode, a pattern that cannot be drawn).

The functions at the end are the :class:`~coordinator.server.Coordinator`'s methods (attached in
its class body); ``self`` there is the core, typed Any: this module may not import it.
"""
from __future__ import annotations

import asyncio
import contextlib
import contextvars
import json
import logging
import time
import weakref
from collections import OrderedDict
from typing import Any, Callable, Iterator

from coordinator.api import CueState
from coordinator.errors import AssetError, CoordinatorError
from coordinator.rig import Content
from protos.cues import Cue, CueError, CueList
from protos.store import atomic_write_json

log = logging.getLogger(__name__)

CUES_FILE = "cues.json"
#: stills kept ready for the next fire (decoded, fitted and encoded; each one content-sized image)
KEEP_STILLS = 4


#: True while an edge that writes its own action-log entry for the call runs it (:func:`edge_logs`)
_EDGE_LOGS: contextvars.ContextVar[bool] = contextvars.ContextVar("cue_fire_logged_by_edge", default=False)


@contextlib.contextmanager
def edge_logs() -> Iterator[None]:
    """Run a GO, back or jump whose action-log entry the caller writes: the engine writes none for
    it then, unless its picture fails afterwards (one GO, one entry)."""
    token = _EDGE_LOGS.set(True)
    try:
        yield
    finally:
        _EDGE_LOGS.reset(token)


class CueEngine:
    """The cue list of one core, where the show is in it, and its auto-follow (module docstring)."""

    def __init__(self, core: Any):
        self.core = core
        self.path = core.rig.path / CUES_FILE
        self.cues = CueList()
        self.current: int | None = None
        self.fired_at: float | None = None       # wall time of the current cue's fire
        self.shown_ns = 0                        # rig instant the current cue reaches the screen
        self.fade_until_ns = 0
        self.follow_at_ns: int | None = None
        #: called with an action-log entry (who, address, action, ok, result, params) at every fire
        self.on_fire: Callable[..., Any] | None = None
        self._follow: asyncio.Task | None = None
        self._follow_wall: float | None = None
        self._chain: asyncio.Task | None = None   # the last fire's asynchronous part (they run in order)
        self._screen: tuple[Any, int] | None = None
        self._stills: OrderedDict[str, Content] = OrderedDict()
        self._load()

    # ------------------------------------------------------------------ reading
    def state(self) -> CueState:
        now = self.core.clock_ns()
        follow_at = None
        if self.follow_at_ns is not None and self._follow is not None and not self._follow.done():
            follow_at = self._follow_wall
        return CueState(cues=self.cues.cues, current=self.current, next=self.next_index(), fired_at=self.fired_at,
                        fading=self.current is not None and now < self.fade_until_ns, follow_at=follow_at)

    def next_index(self) -> int | None:
        n = len(self.cues)
        if self.current is None:
            return 0 if n else None
        return self.current + 1 if self.current + 1 < n else None

    # ------------------------------------------------------------------ operations
    def set_cues(self, cues: CueList, *, who: str = "") -> str:
        """Store a new list (CueError, one line, for one that cannot be fired; nothing changes then).
        The current cue stays current when its id is still in the list."""
        cues.validate()
        cues.check_slots(self.core.rig.slots)
        self._check_patterns(cues)
        self._check_assets(cues)
        current_id = self.cues.cues[self.current].id if self.current is not None else None
        self._cancel_follow()
        self.cues = cues
        ids = [c.id for c in cues.cues]
        self.current = ids.index(current_id) if current_id in ids else None
        if self.current is None:
            self.fired_at = None
        self._save()
        n = len(cues)
        log.info("cues: %d cue%s stored by %s", n, "" if n == 1 else "s", who or "-")
        return f"{n} cue{'' if n == 1 else 's'} stored"

    def go(self, *, who: str = "") -> str:
        nxt = self.next_index()
        if nxt is None:
            if not self.cues.cues:
                raise CueError("the cue list is empty: add cues first (`shadowless cue add`)")
            raise CueError(f"cue {self.cues.cues[-1].id} is the last cue: jump to a cue or go back")
        return self.fire(nxt, who=who)

    def back(self, *, who: str = "") -> str:
        if self.current is None or self.current == 0:
            raise CueError("no cue before this one: GO fires the first cue")
        return self.fire(self.current - 1, who=who, fade=False)

    def jump(self, cue_id: str, *, who: str = "") -> str:
        return self.fire(self.cues.index(str(cue_id)), who=who)

    def fire(self, index: int, *, who: str = "", fade: bool = True, follow: bool = True,
             restoring: bool = False) -> str:
        """Fire cue ``index``: what can be refused is refused here (one line, nothing changed). A cue
        whose picture is ready goes to the nodes in this call; what takes time (a still's first
        decoding, a pattern) runs on after it, and fires follow in the order they were asked."""
        cue = self.cues.cues[index]
        core = self.core
        job = core.running_job()
        if job is not None:
            raise CoordinatorError(f"a {job} job is running on this rig (its patterns hold the projectors); wait "
                                   "for it or cancel it before firing a cue")
        fade_ns = int(round(cue.fade_s * 1e9)) if fade else 0
        action = self._prepare(cue, fade_ns)
        prev = self._chain
        now = prev is None or prev.done()
        shown = action() if now else None      # a refusal here changes nothing
        self._cancel_follow()
        self.current = index
        self.fired_at = time.time()
        self.shown_ns = core.clock_ns() + core.latency_ns
        self.fade_until_ns = self.shown_ns + fade_ns
        if not restoring:
            self._save()
        who = who or "-"
        logged = _EDGE_LOGS.get()      # the caller's own entry says it fires: only a later failure is written here
        nxt = self.next_index()
        follow_s = cue.follow_s if follow and nxt is not None else None

        def done(shown_ns: int | None, error: Exception | None = None) -> None:
            ok, result = error is None, f"cue {cue.label} fired"
            if error is not None:
                result = f"cue {cue.label} failed: {error}"
                log.error("cues: %s", result)
            elif self.current == index:
                self.shown_ns = shown_ns or self.shown_ns
                self.fade_until_ns = self.shown_ns + fade_ns
                self._screen = self._on_screen()
                if follow_s is not None:
                    self._start_follow(index, self.shown_ns + int(follow_s * 1e9))
            if not (ok and logged):
                self._record(who, ok, result, cue, restoring)

        if now and not asyncio.iscoroutine(shown):
            done(shown)
        else:
            async def run() -> None:
                if prev is not None and not prev.done():
                    await asyncio.gather(prev, return_exceptions=True)
                try:
                    got = shown if now else action()
                    done(await got if asyncio.iscoroutine(got) else got)
                except Exception as exc:   # noqa: BLE001 - the operator hears why in the log and the action log
                    done(None, exc)

            self._chain = task = asyncio.get_running_loop().create_task(run(), name=f"cue:{cue.id}")
            self._keep(task)
        what = f", fading over {cue.fade_s:g} s" if fade_ns else ""
        then = f"; cue {self.cues.cues[nxt].id} follows in {follow_s:g} s" if follow_s is not None else ""
        upcoming = f"next: {self.cues.cues[nxt].label}" if nxt is not None else "that was the last cue"
        log.info("cues: %s fires cue %s%s", who, cue.label, what)
        return f"cue {cue.label} fires{what}{then}; {upcoming}"

    def start(self) -> None:
        """Show the current cue again after a restart (a still, a pattern or black; no fade, no follow)."""
        if self.current is None:
            return
        cue = self.cues.cues[self.current]
        if cue.kind == "asset" and self._asset_kind(cue.target) not in ("still", None):
            return      # a video's timeline show takes itself back (show.json)
        try:
            self.fire(self.current, who="restart", fade=False, follow=False, restoring=True)
        except (CoordinatorError, ValueError) as exc:
            log.warning("cues: cannot show cue %s again after the restart: %s", cue.label, exc)

    # ------------------------------------------------------------------ what a cue does
    def _prepare(self, cue: Cue, fade_ns: int) -> Callable[[], Any]:
        """Check cue ``cue`` can be fired now; return the function that shows it and returns the
        rig instant it is on screen from (None: about a latency budget from now), or a coroutine
        that does when it must wait (a still decoded the first time, a pattern)."""
        core = self.core
        others = {s: None for s in core.rig.slots if s not in cue.slots} if cue.slots else None
        tag = f"show:cue:{cue.id}"
        if cue.kind == "blackout":
            def black():
                core.playback.stop()
                self._hand_over(fade_ns)
                core.playback.blackout(fade_ns=fade_ns, tag=tag)
                core.playback.showing = f"black (cue {cue.id})"
                return core.playback.current_frame.pts_ns
            return black
        if cue.kind == "pattern":
            self._check_patterns(CueList((cue,)))

            async def pattern():
                await core.show_test_pattern(cue.target, list(cue.slots) or None)
                return None
            return lambda: pattern()
        if cue.kind == "still" and cue.target == "content":
            content = core.rig.content
            if content is None:
                raise CueError(f"cue {cue.id}: the rig has no content yet (show an image with --persist first, "
                               "or name a still asset)")
            return self._show_still(f"content:{content.content_id}", lambda: content, tag, others, fade_ns)
        asset_id = core.distribution.store.resolve(cue.target)      # AssetError names what there is
        m = core._manifest(asset_id)
        if m.kind == "still":
            return self._show_still(asset_id, lambda: self._still(asset_id, m), tag, others, fade_ns)
        if cue.kind == "still":
            raise CueError(f"cue {cue.id}: asset {cue.target!r} is a {m.kind}, not a still: make it an asset cue")
        if cue.slots:
            raise CueError(f"cue {cue.id}: a {m.kind} plays on every projector; leave the cue's slots out")

        def play():
            return core.play_asset(asset_id, fade_ns=fade_ns).anchor_ns
        return play

    def _show_still(self, key: str, content: Callable[[], Content], tag: str, others, fade_ns: int):
        core = self.core

        def send(prepared: Content) -> int:
            self._stills.move_to_end(key)
            self._hand_over(fade_ns)
            return core.playback.show(prepared, tag=tag, slot_contents=others, fade_ns=fade_ns).pts_ns

        async def first_time() -> int:      # decoded, fitted and encoded once, off the event loop
            prepared = await asyncio.to_thread(lambda: core.prepare_still(content()))
            self._stills[key] = prepared
            while len(self._stills) > KEEP_STILLS:
                self._stills.popitem(last=False)
            return send(prepared)

        def show():
            prepared = self._stills.get(key)
            return send(prepared) if prepared is not None else first_time()
        return show

    def _hand_over(self, fade_ns: int) -> None:
        """A crossfade out of a timeline show fades from its frame on screen: the show plays on until
        the fade's first step (a still stops a show at once otherwise, and the nodes would go black)."""
        show = self.core.show_state
        if fade_ns and show.active:
            show.stop(at_ns=self.core.clock_ns() + self.core.latency_ns)

    def _still(self, asset_id: str, manifest) -> Content:
        """A still asset as content (blocking: called in a worker thread)."""
        from coordinator.image_decode import read_image_file

        path = self.core.distribution.store.blob_path(manifest.blobs[0].sha256)
        return Content(read_image_file(path), name=manifest.name or asset_id[:12])

    def _asset_kind(self, key: str) -> str | None:
        try:
            return self.core._manifest(self.core.distribution.store.resolve(key)).kind
        except Exception:  # noqa: BLE001 - an asset gone since: nothing to restore
            return None

    def _check_assets(self, cues: CueList) -> None:
        """Every asset a cue names is in the store now, and of a kind its cue can show (a refusal when the
        list is stored, not when the cue fires mid-show). A still cue of the rig's content is checked when
        it fires: the content may be shown with --persist after the list is made."""
        distribution = getattr(self.core, "distribution", None)
        if distribution is None:
            return
        for c in cues.cues:
            if c.kind not in ("still", "asset") or (c.kind == "still" and c.target == "content"):
                continue
            try:
                kind = self.core._manifest(distribution.store.resolve(c.target)).kind
            except AssetError as exc:
                raise CueError(f"cue {c.id!r}: {exc}") from None
            if c.kind == "still" and kind != "still":
                raise CueError(f"cue {c.id!r}: asset {c.target!r} is a {kind}, not a still: make it an asset cue")
            if kind != "still" and c.slots:
                raise CueError(f"cue {c.id!r}: a {kind} plays on every projector; leave the cue's slots out")

    def _check_patterns(self, cues: CueList) -> None:
        wanted = [c for c in cues.cues if c.kind == "pattern"]
        if not wanted:
            return
        if not hasattr(self.core, "show_test_pattern"):
            raise CueError("this coordinator shows no test patterns; leave pattern cues out")
        from coordinator.test_patterns import PATTERNS

        for c in wanted:
            if c.target not in PATTERNS:
                raise CueError(f"cue {c.id!r}: unknown test pattern {c.target!r} (choose one of {', '.join(PATTERNS)})")

    # ------------------------------------------------------------------ auto-follow
    def _on_screen(self) -> tuple[Any, int]:
        """What is on the projectors now, to tell later whether something else took them."""
        return self.core.playback.current_frame, self.core.show_state.revision

    def _start_follow(self, index: int, at_ns: int) -> None:
        self.follow_at_ns = at_ns
        self._follow_wall = round(time.time() + (at_ns - self.core.clock_ns()) / 1e9, 3)

        async def follow() -> None:
            _EDGE_LOGS.set(False)       # this task's own context: its fire is nobody's edge call, the engine logs it
            while (left := at_ns - self.core.clock_ns()) > 0:
                await asyncio.sleep(min(left / 1e9, 0.5))
            if self.current != index or self._on_screen() != self._screen:
                log.info("cues: the auto-follow after cue %s is cancelled: the projectors show something else",
                         self.cues.cues[index].id)
                return
            try:
                self.fire(index + 1, who="follow")
            except (CoordinatorError, ValueError) as exc:
                log.error("cues: the auto-follow after cue %s failed: %s", self.cues.cues[index].id, exc)
                self._record("follow", False, str(exc), self.cues.cues[index + 1], False)

        self._follow = asyncio.get_running_loop().create_task(follow(), name="cue-follow")
        self._keep(self._follow)

    def _cancel_follow(self) -> None:
        if self._follow is not None and not self._follow.done() and self._follow is not asyncio.current_task():
            self._follow.cancel()
        self._follow, self.follow_at_ns = None, None

    def _keep(self, task: asyncio.Task) -> None:
        """The core's tasks are cancelled and awaited when it stops."""
        tasks = self.core._tasks
        tasks[:] = [t for t in tasks if not t.done()]
        tasks.append(task)

    # ------------------------------------------------------------------ the log and the file
    def _record(self, who: str, ok: bool, result: str, cue: Cue, restoring: bool) -> None:
        if self.on_fire is None or restoring:
            return
        try:
            self.on_fire(who=who, address="cue", action="cue fire", ok=ok, result=result,
                         params={"cue": cue.id, "kind": cue.kind, "target": cue.target})
        except Exception:  # noqa: BLE001 - the fire happened; a log that fails must not undo it
            log.exception("cues: cannot write the action log")

    def _save(self) -> None:
        doc = {**self.cues.to_json(), "current": self.cues.cues[self.current].id if self.current is not None else None,
               "fired_at": self.fired_at}
        try:
            atomic_write_json(self.path, doc)
        except OSError as exc:
            log.error("cannot save the cue list to %s: %s (a restarted coordinator would not have it)", self.path, exc)

    def _load(self) -> None:
        try:
            doc = json.loads(self.path.read_text())
            cues = CueList.from_json(doc)
            cues.validate()
        except FileNotFoundError:
            return
        except (OSError, ValueError) as exc:
            log.warning("ignoring %s: %s", self.path, exc)
            return
        self.cues = cues
        current = doc.get("current") if isinstance(doc, dict) else None
        ids = [c.id for c in cues.cues]
        if current in ids:
            self.current = ids.index(current)
            fired = doc.get("fired_at")
            self.fired_at = float(fired) if isinstance(fired, (int, float)) else None
            log.info("cues: %d cues, cue %s current", len(cues), cues.cues[self.current].label)


#: each core's engine (made at first use)
_ENGINES: "weakref.WeakKeyDictionary[Any, CueEngine]" = weakref.WeakKeyDictionary()


def cue_engine(self) -> CueEngine:
    """The core's cue engine (the console attaches its action log to it)."""
    eng = _ENGINES.get(self)
    if eng is None:
        eng = _ENGINES[self] = CueEngine(self)
    return eng


def start_cues(self) -> None:
    """At the core's start: show the current cue again (see :meth:`CueEngine.start`)."""
    cue_engine(self).start()


def cue_state(self) -> CueState:
    """The cue list, the current and next cue, when the current one fired and whether it fades."""
    return cue_engine(self).state()


def set_cues(self, cues: CueList, *, who: str = "") -> str:
    """Store a new cue list (CueError, one line, when a cue cannot be fired; nothing stored then)."""
    return cue_engine(self).set_cues(cues, who=who)


def cue_go(self, *, who: str = "") -> str:
    """Fire the next cue; returns one line saying what fires and what is next."""
    return cue_engine(self).go(who=who)


def cue_back(self, *, who: str = "") -> str:
    """Fire the cue before the current one (a cut: going back does not fade)."""
    return cue_engine(self).back(who=who)


def cue_jump(self, cue_id: str, *, who: str = "") -> str:
    """Fire cue ``cue_id`` (with its fade)."""
    return cue_engine(self).jump(cue_id, who=who)
