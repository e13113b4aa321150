"""A node's blend switch: which blend maps are next, from which rig instant, and when they first showed.

The presenter (:mod:`node.presenter`) owns the renderer and the frames; this holds what a switch of
blend maps needs between an assignment and the first swap with them: the next maps and their instant,
whether the renderer draws with maps no frame has shown yet, the maps on screen and the pts of the
first frame shown with them (what the node reports), and the maps' way to the screen (the host times
their assignment was received, decoded, reached the presenter and was uploaded, and the first frame
with them was rendered and finished, ready for its swap), logged with that first swap on the rig clock
so that a failover's time can be followed stage by stage: a node whose frame was ready before the
common instant only waited for it.
"""
from __future__ import annotations

import logging
from dataclasses import fields
from typing import Callable

import numpy as np

from node.clock import ClockEstimate
from node.records import NodeAssignment
from protos.blend import BlendMaps

log = logging.getLogger("node.presenter")

#: the fields of an assignment a blend switch alone changes
_BLEND_FIELDS = frozenset({"revision", "blend", "blend_at_ns", "blend_error", "received_host_ns", "decoded_host_ns"})


def same_but_blend(a: NodeAssignment, b: NodeAssignment) -> bool:
    """Whether two assignments differ in their revision and blend alone (arrays compared by value,
    a mesh by its id)."""
    for f in fields(NodeAssignment):
        if f.name in _BLEND_FIELDS:
            continue
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            if not (isinstance(x, np.ndarray) and isinstance(y, np.ndarray) and x.shape == y.shape
                    and np.array_equal(x, y)):
                return False
        elif f.name == "mesh":
            if (x is None) != (y is None) or (x is not None and x.mesh_id != y.mesh_id):
                return False
        elif x != y:
            return False
    return True


#: the stamps of the log line of a first swap with new maps, after ``instant`` (rig ns; 0 unknown)
TIMING_NAMES = ("received", "decoded", "presenter", "uploaded", "ready", "swapped")


class BlendSwitch:
    """The blend maps a node shows and the switch to the next ones.

    Parameters
    ----------
    host_now : callable
        The host's monotonic time (ns).
    to_rig : callable
        ``to_rig(host_ns, estimate)``: that host instant on the rig clock.
    """

    def __init__(self, host_now: Callable[[], int], to_rig: Callable[[int, ClockEstimate], int]):
        self.host_now = host_now
        self.to_rig = to_rig
        #: the next maps (None: none) and the rig instant from which they show; None: no change due
        self.next: tuple[BlendMaps | None, int] | None = None
        self.unshown = False            # the renderer switched maps; no frame shown with them yet
        self.on_screen = ""             # the id of the maps on screen ("" none)
        self.since_rig_ns = 0           # pts of the first frame shown with them
        self._stamps: tuple[int, ...] | None = None
        self._ready_host_ns = 0         # when the first frame with the next maps was ready for its swap
        self._drawn: BlendMaps | None = None    # the maps the renderer draws with (those the assignment holds)
        #: what :meth:`undo` restores, from a switch until a frame shows it: (maps drawn before, the
        #: switch's instant, whether those were still unshown)
        self._undo: tuple[BlendMaps | None, int, bool] | None = None

    def offer(self, renderer, a: NodeAssignment, rig_now: int | None, got_host_ns: int) -> bool:
        """Take the blend assignment ``a`` asks for (it reached the presenter at ``got_host_ns``):
        refused maps are logged and change nothing; new maps are uploaded ahead and wait for their
        instant, or are switched to at once (instant 0, or at or before ``rig_now``, the rig clock now;
        None: unknown). Whether the renderer switched now."""
        if a.blend_error:
            log.error("assignment r%d: blend maps refused (%s); the blend on screen stays", a.revision, a.blend_error)
            return False
        maps, at = a.blend, a.blend_at_ns
        want = maps.blend_id if maps is not None else ""
        nxt = self.next
        if nxt is not None and (nxt[0].blend_id if nxt[0] is not None else "") == want:
            self.next = (nxt[0], at)
        elif want == renderer.blend_id:
            self.next = None      # what is on screen already (a switch back before the instant)
            return False
        else:
            if maps is not None:
                try:
                    renderer.load_blend(maps)
                except ValueError as exc:
                    log.error("assignment r%d: blend maps refused (%s); the blend on screen stays", a.revision, exc)
                    return False
            self.next = (maps, at)
            log.info("assignment r%d: blend %s %s", a.revision, want or "none",
                     "at once" if at <= 0 else f"from rig instant {at}")
        self._stamps = (at, a.received_host_ns, a.decoded_host_ns, got_host_ns, self.host_now())
        if at <= 0 or (rig_now is not None and at <= rig_now):
            self.switch(renderer)
            return True
        return False

    def due_for(self, pts_ns: int) -> bool:
        """Whether a frame of this pts is the first to show the next maps (at or after their instant)."""
        return self.next is not None and pts_ns >= self.next[1]

    def switch(self, renderer) -> None:
        """The renderer draws with the next maps from now on; the first frame swapped in stamps them."""
        maps, at = self.next
        self.next = None
        renderer.set_blend(maps)
        self._undo = (self._drawn, at, self.unshown)
        self._drawn = maps
        self.unshown = True
        self._ready_host_ns = 0

    def undo(self, renderer) -> None:
        """Call off the last switch before any frame showed it (a still held for the maps' instant when a
        message came that changes what is shown): the renderer draws with the maps before it again, and
        the maps switched to are next again, for the same instant, uploaded ahead again."""
        if self._undo is None:
            return
        before, at, unshown = self._undo
        maps, self._undo = self._drawn, None
        renderer.set_blend(before)
        if maps is not None:
            renderer.load_blend(maps)
        self._drawn, self.next, self.unshown = before, (maps, at), unshown

    def ready(self) -> None:
        """The frame that first shows the maps switched to is rendered and finished: it waits only for its
        swap (stamped once per switch; a frame rendered again keeps the first stamp)."""
        if self.unshown and not self._ready_host_ns:
            self._ready_host_ns = self.host_now()

    def shown(self, blend_id: str, pts_ns: int, estimate: ClockEstimate | None) -> None:
        """A frame of ``pts_ns`` was swapped in: the first with maps ``blend_id`` (the renderer's) when it
        switched since, logged with the maps' way there."""
        if self.unshown:
            self.unshown, self._undo = False, None
            self.on_screen = blend_id
            self.since_rig_ns = pts_ns
            log.info("blend %s on screen from rig instant %d%s", blend_id or "none", pts_ns, self._timing(estimate))

    def _timing(self, estimate: ClockEstimate | None) -> str:
        """"; timing instant=.. received=.. decoded=.. presenter=.. uploaded=.. ready=.. swapped=.." (rig
        ns; 0 unknown: an assignment made in a test), or "" when the clock is unknown."""
        stamps, self._stamps = self._stamps, None
        if stamps is None or estimate is None:
            return ""
        at, *hosts = stamps
        rig = [self.to_rig(h, estimate) if h else 0 for h in (*hosts, self._ready_host_ns, self.host_now())]
        return f"; timing instant={at} " + " ".join(f"{n}={v}" for n, v in zip(TIMING_NAMES, rig))
