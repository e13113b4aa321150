"""What show control says back: the status messages, and what counts as a change of them.

Sent in reply to ``/shadowless/status`` and, on every change, to the feedback targets (rig.toml)
and the senders that subscribed. Each is one OSC message (no bundle, so that controllers that
read only messages get them too):

==============================  ============================================================
``/shadowless/cue/current``     ID, NAME of the cue fired last ("" "" before the first)
``/shadowless/cue/next``        ID, NAME of the cue GO fires ("" "" after the last)
``/shadowless/show``            STATE (none, scheduled, playing, paused, ended, stopped), ASSET
                                name, FRAME (-1: none), FRAMES of the timeline show
``/shadowless/showing``         what the projectors show, as ``shadowless status`` says it
``/shadowless/nodes``           LIVE, TOTAL: projectors whose node reports, of the rig's slots
``/shadowless/lost``            COUNT, SLOTS (comma-separated) of nodes lost
==============================  ============================================================

A change is any of these but the playing show's frame (which moves every frame period).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from coordinator.api import NodeState, RigStatus

PREFIX = "/shadowless"


@dataclass(frozen=True)
class Feedback:
    """The status as OSC messages (address, arguments) and the key a change is told by."""

    messages: tuple[tuple[str, tuple[Any, ...]], ...]
    key: tuple


def _cue(cues: Any, index: int | None) -> tuple[str, str]:
    if index is None or cues is None or not 0 <= index < len(cues):
        return "", ""
    c = cues[index]
    return str(getattr(c, "id", "")), str(getattr(c, "name", ""))


def feedback(status: RigStatus, cue_state: Any | None) -> Feedback:
    """The status messages for ``status`` and the core's ``cue_state()`` (None: no cue list)."""
    cues = getattr(cue_state, "cues", None) if cue_state is not None else None
    current = _cue(cues, getattr(cue_state, "current", None))
    nxt = _cue(cues, getattr(cue_state, "next", None))
    show = status.show
    live = sum(1 for n in status.nodes if n.state == NodeState.LIVE)
    lost = tuple(n.slot for n in status.nodes if n.state == NodeState.LOST)
    on = show.state in ("playing", "paused", "scheduled")
    messages = (
        (f"{PREFIX}/cue/current", current),
        (f"{PREFIX}/cue/next", nxt),
        (f"{PREFIX}/show", (show.state, show.name or show.asset_id[:12], int(show.frame), int(show.frames))),
        (f"{PREFIX}/showing", (status.showing,)),
        (f"{PREFIX}/nodes", (live, len(status.nodes))),
        (f"{PREFIX}/lost", (len(lost), ",".join(lost))),
    )
    key = (current, nxt, show.state, show.asset_id, show.revision, "" if on else status.showing, live,
           len(status.nodes), lost)
    return Feedback(messages=messages, key=key)
