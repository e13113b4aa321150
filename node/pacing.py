"""When a frame is shown, and which frames are not: the presenter's drop rules.

Pure logic on a clock (anything with ``now()`` and ``from_host()`` in local ns, such
as :class:`node.clock.LocalClock`) and the presenter's estimate of the rig clock; no
GL, no pipes, no wall-clock reads of its own, so tests drive it with a clock they move.

The rules, in the order they are checked for each frame as it arrives:

1. **superseded**: its id is not newer than the frame shown last (since the last
   :meth:`FramePacer.reset`): frames are never shown out of order;
2. **late**: there is no rig-clock estimate yet, or its presentation time has passed
   by more than :data:`LATE_TOLERANCE_NS` (a frame is never shown late);
3. **missing content**: it names content the node does not hold;

then, once it is rendered, it is **late** if rendering took it past its time. A frame
that passes is shown at its presentation time (:meth:`FramePacer.deadline`) and
recorded with :meth:`FramePacer.shown`.
"""
from __future__ import annotations

from typing import Callable, Protocol

from node.clock import ClockEstimate
from node.records import DropReason, DropRecord, FrameOrder, SwapRecord

#: a frame may be shown this late (ns) before it counts as late and is dropped
LATE_TOLERANCE_NS = 500_000


class PacingClock(Protocol):
    def now(self) -> int: ...

    def from_host(self, host_ns: int) -> int: ...


class FramePacer:
    """The drop rules (see the module docstring) for one presenter.

    Parameters
    ----------
    clock : PacingClock
        The node's local clock.
    late_tolerance_ns : int
        How late a frame may still be shown.
    """

    def __init__(self, clock: PacingClock, *, late_tolerance_ns: int = LATE_TOLERANCE_NS):
        self.clock = clock
        self.late_tolerance_ns = int(late_tolerance_ns)
        #: the presenter's current estimate of the rig clock (None: frames cannot be timed)
        self.estimate: ClockEstimate | None = None
        #: id of the last frame shown since the last reset (0: none)
        self.last_shown_id = 0

    def reset(self) -> None:
        """A coordinator on a new rig clock: frame ids restart their ordering."""
        self.last_shown_id = 0

    def deadline(self, frame: FrameOrder) -> int:
        """The frame's presentation time on the local clock (needs an estimate)."""
        assert self.estimate is not None, "no clock estimate"
        return self.estimate.local_time(frame.pts_ns)

    def late_by(self, frame: FrameOrder) -> int:
        """How far (ns) the local clock is past the frame's presentation time (< 0: early)."""
        return self.clock.now() - self.deadline(frame)

    def admit(self, frame: FrameOrder, has_content: Callable[[str], bool]) -> DropRecord | None:
        """Check a frame as it arrives: the drop, or None if it is to be rendered."""
        if frame.frame_id <= self.last_shown_id:
            return DropRecord(frame.frame_id, DropReason.SUPERSEDED)
        if self.estimate is None:
            return DropRecord(frame.frame_id, DropReason.LATE)
        late_by = self.late_by(frame)
        if late_by > self.late_tolerance_ns:
            return DropRecord(frame.frame_id, DropReason.LATE, late_by)
        if frame.content_id and not has_content(frame.content_id):
            return DropRecord(frame.frame_id, DropReason.MISSING_CONTENT)
        return None

    def ready(self, frame: FrameOrder) -> DropRecord | None:
        """Check a rendered frame before waiting for its time: a late drop, or None."""
        late_by = self.late_by(frame)
        if late_by > self.late_tolerance_ns:
            return DropRecord(frame.frame_id, DropReason.LATE, late_by)
        return None

    def shown(self, frame: FrameOrder, host_ns: int) -> SwapRecord:
        """Record that ``frame`` was swapped in at host time ``host_ns``."""
        assert self.estimate is not None, "no clock estimate"
        self.last_shown_id = frame.frame_id
        swap_rig = self.estimate.rig_time(self.clock.from_host(host_ns))
        return SwapRecord(frame_id=frame.frame_id, pts_ns=frame.pts_ns, swap_rig_ns=swap_rig, host_monotonic_ns=host_ns)
