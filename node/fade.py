"""A crossfade on the node: what was on screen mixed into a new frame, step by step, on the rig clock.

A frame that carries a fade (``FrameOrder.fade_ns`` > 0, :mod:`protos.fade`) is shown as
``fade_steps + 1`` steps: step ``k`` is swapped in at ``step_pts(pts, fade_ns, k, steps)`` on the
node's estimate of the rig clock and mixes ``step_mix(k, steps)`` of the new content with the
picture before (the shader's ``mix``, before gain, blend and LUT). Every node computes the same
instants and factors from the frame alone, so the rig fades as one. Step ``k`` is reported as
frame ``frame_id + k``; a step that would be late is dropped like any frame, except the last,
which is shown at once (the fade must end on the new picture).

What "before" is: the content of the frame on screen when the fade's frame arrives, if it is a
content-space picture (a still, a timeline frame, black); a projector-space picture (a pattern,
a slot's name card) cannot be mixed through the pose, so the fade is a cut then. A frame that
arrives during a fade, or a show's tick, ends it where it is.

This module keeps the fade's state and answers the presenter's questions (what to render for a
frame, which step is next); the presenter swaps and reports (:mod:`node.presenter`).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

from node.records import FrameOrder
from protos.fade import step_mix, step_pts


@dataclass
class Crossfade:
    """A fade under way: the frame that started it, the content before ("" black) and the next step."""

    frame: FrameOrder
    before_id: str
    #: forget the content before once the fade ends (a show's frame, or content the coordinator evicted)
    forget_before: bool = False
    next_k: int = 1

    @classmethod
    def start(cls, frame: FrameOrder, current: FrameOrder | None, has) -> "Crossfade | None":
        """The fade ``frame`` asks for from ``current`` (the frame on screen), or None for a cut
        (no fade asked, a projector-space picture on either side, a content that is gone)."""
        if frame.fade_ns <= 0 or frame.fade_steps <= 0 or frame.space != "content" or not frame.content_id:
            return None
        if current is None or not current.content_id:
            return cls(frame, "")
        if current.space != "content" or not has(current.content_id):
            return None
        if current.content_id == frame.content_id:
            return None
        return cls(frame, current.content_id)

    @property
    def steps(self) -> int:
        return self.frame.fade_steps

    @property
    def done(self) -> bool:
        return self.next_k > self.steps

    def covers(self, order: FrameOrder) -> bool:
        """Whether ``order`` is a step of this fade."""
        return order.content_id == self.frame.content_id and 0 <= order.frame_id - self.frame.frame_id <= self.steps

    def render_args(self, order: FrameOrder) -> tuple[bool, tuple[str, float] | None]:
        """``(apply_lut, fade)`` to render step ``order`` with: the steps before the last mix
        through the luminance pipeline (a blackout's own frame skips it); the last is the frame itself."""
        k = order.frame_id - self.frame.frame_id
        if k >= self.steps:
            return self.frame.apply_lut, None
        return True, (self.before_id, step_mix(k, self.steps))

    def next_order(self) -> FrameOrder:
        """The next step as a frame of its own (id ``frame_id + k``, its instant on the rig clock)."""
        k, f = self.next_k, self.frame
        return replace(f, frame_id=f.frame_id + k, pts_ns=step_pts(f.pts_ns, f.fade_ns, k, f.fade_steps))

    def is_last(self, order: FrameOrder) -> bool:
        return order.frame_id - self.frame.frame_id >= self.steps


@dataclass
class ShowFade:
    """A timeline show's crossfade in (``Timeline.fade_ns``): its ticks from ``anchor_ns`` on mix
    the picture on screen before the show into theirs, ``(pts - anchor) / fade`` of theirs, until
    ``anchor_ns + fade_ns``. The ticks are the steps: a video at its own rate."""

    revision: int
    anchor_ns: int
    fade_ns: int
    before_id: str = ""
    forget_before: bool = False
    started: bool = False

    @property
    def end_ns(self) -> int:
        return self.anchor_ns + self.fade_ns

    def covers(self, order: FrameOrder) -> bool:
        return self.started and order.tag == f"timeline:{self.revision}" and order.pts_ns < self.end_ns

    def render_args(self, order: FrameOrder) -> tuple[bool, tuple[str, float]]:
        m = min(1.0, max(0.0, (order.pts_ns - self.anchor_ns) / self.fade_ns))
        return True, (self.before_id, m)
