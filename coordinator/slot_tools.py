"""Tools for chosen projectors of a running rig: test patterns on some slots (the others black),
and solo (only some slots go on showing the rig's still, the others black, until solo ends).

The functions are the :class:`~coordinator.server.Coordinator`'s methods ``show_test_pattern``
and ``solo`` (attached in its class body), so the console, the command line and cues call the
same code. Both hold the projectors as a still does: a node joining later is sent what it
should show, and the next show, stop or blackout ends them.
"""
from __future__ import annotations

import asyncio
import logging
import weakref
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from coordinator.errors import CoordinatorError
from coordinator.fanout import Frame
from coordinator.rig import Content, Rig
from coordinator.test_patterns import PATTERNS, test_pattern

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class _Solo:
    """A solo in force: the frame it put on screen, and the still it was taken from."""

    frame: Frame
    base: Frame
    contents: Mapping[str, Content]
    showing: str


#: each coordinator's solo in force (none: no solo); a solo whose frame is no longer on screen is
#: over. (``self`` below is the coordinator, typed Any: this module may not import the core's.)
_SOLOS: "weakref.WeakKeyDictionary[Any, _Solo]" = weakref.WeakKeyDictionary()


def choose_slots(rig: Rig, slots: Sequence[str] | None) -> list[str]:
    """The named slots in the rig's order (None: every slot); ValueError naming an unknown one
    and the rig's slots, or an empty choice."""
    if slots is None:
        return list(rig.slots)
    if isinstance(slots, str):
        slots = [slots]
    unknown = [s for s in slots if s not in rig.slots]
    if unknown:
        raise ValueError(f"no slot {', '.join(map(repr, unknown))} in rig {rig.config.name!r} "
                         f"(slots: {', '.join(rig.slots)})")
    chosen = set(slots)
    out = [s for s in rig.slots if s in chosen]
    if not out:
        raise ValueError("name at least one slot")
    return out


def describe_slots(chosen: Sequence[str], total: int) -> str:
    """"every projector", "r1c1", "r1c1, r1c2 (2 of 25 projectors)"."""
    if len(chosen) == total:
        return f"every projector ({total})" if total != 1 else "the projector"
    if len(chosen) == 1:
        return chosen[0]
    shown = ", ".join(chosen[:6]) + (f" and {len(chosen) - 6} more" if len(chosen) > 6 else "")
    return f"{shown} ({len(chosen)} of {total} projectors)"


def pattern_images(rig: Rig, name: str, slots: Sequence[str] | None = None) -> dict[str, np.ndarray]:
    """Test pattern ``name`` for each chosen slot at its projector's size, labelled with the slot's
    name: slot -> (height, width, 3) uint8 (see :func:`coordinator.test_patterns.test_pattern`)."""
    if name not in PATTERNS:
        raise ValueError(f"unknown test pattern {name!r}: choose one of {', '.join(PATTERNS)}")
    out = {}
    for s in choose_slots(rig, slots):
        st = rig.slots[s]
        out[s] = test_pattern(name, (st.width, st.height), label=s)
    return out


async def show_test_pattern(self: Any, name: str, slots: Sequence[str] | None = None) -> str:
    """Test pattern ``name`` on the chosen slots (None: all), the others black, until the next show,
    stop or blackout. Returns what the rig shows now. ValueError for an unknown pattern or slot,
    CoordinatorError while a job holds the projectors."""
    self._refuse_while_job("cancel it first")
    chosen = choose_slots(self.rig, slots)
    images = pattern_images(self.rig, name, chosen)     # checks the name before any work

    def contents() -> dict[str, Content]:
        out = {s: Content(img, name=f"pattern {name} {s}") for s, img in images.items()}
        self.fanout.prepare(list(out.values()))
        return out

    prepared = await asyncio.to_thread(contents)      # packed for the wire off the event loop
    self._refuse_while_job("cancel it first")         # a job may have started meanwhile
    showing = f"test pattern {name} on {describe_slots(chosen, len(self.rig.slots))}"
    if len(chosen) < len(self.rig.slots):
        showing += ", the others black"
    self.playback.show_per_slot(prepared, tag="show:pattern", showing=showing)
    log.info("%s", showing)
    return showing


def solo(self: Any, slots: Sequence[str]) -> str:
    """Only the chosen slots go on showing the still on screen, the others black; ``solo([])``
    ends it (every slot shows the still again). Choosing again replaces the choice. Returns what
    the rig shows now. Refused with one line while a job holds the projectors, while a timeline
    show or a sequence plays (a solo holds a still), or with nothing on screen."""
    self._refuse_while_job("cancel it first")
    pb = self.playback
    held = _SOLOS.get(self)
    if held is not None and pb.current_frame is not held.frame:
        held = None                 # something else was shown since: that solo is over
        _SOLOS.pop(self, None)
    if not slots:
        if held is None:
            return f"no solo to end: showing {pb.showing}"
        pb.reshow_slots(held.base, held.contents, held.base.slot_content, showing=held.showing)
        _SOLOS.pop(self, None)
        log.info("solo ended: showing %s", pb.showing)
        return pb.showing
    chosen = choose_slots(self.rig, slots)
    if self.show_state.active:
        raise CoordinatorError("a timeline show is playing: solo holds a still; stop the show first "
                               "(or show a still), then solo")
    if pb.playing:
        raise CoordinatorError("a sequence is playing: solo holds a still; stop it first, then solo")
    base = held.base if held is not None else pb.current_frame
    if base is None:
        raise CoordinatorError("nothing on screen to solo: show a picture first")
    contents = held.contents if held is not None else dict(pb.current_contents)
    base_showing = held.showing if held is not None else pb.showing
    picked = set(chosen)
    mapping = {s: (base.content_for(s) if s in picked else "") for s in self.rig.slots}
    showing = f"solo {describe_slots(chosen, len(self.rig.slots))}: {base_showing}"
    frame = pb.reshow_slots(base, contents, mapping, showing=showing)
    _SOLOS[self] = _Solo(frame=frame, base=base, contents=contents, showing=base_showing)
    log.info("%s", showing)
    return showing
