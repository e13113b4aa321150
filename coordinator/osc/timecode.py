"""Chasing an external clock: OSC timecode read, and the seek that keeps the running show on it.

A show controller sends ``/shadowless/timecode`` with either a string ``"hh:mm:ss:ff"`` (frames
at the rig's ``timecode_fps``; ``hh:mm:ss;ff``, the drop-frame spelling, is read the same way,
without dropping frames, and ``hh:mm:ss.sss`` gives fractions of a second) or a number of seconds
(int or float). Minus ``timecode_offset_s``, that is where the show's timeline should be: second
0 is the asset's frame 0. The clock advances between messages by itself (each message is dated
on the rig clock when it arrives), so a controller may send it at any rate.

:func:`chase` compares it with the show's own position and, when the two are further apart than
the threshold, says which frame to show at which rig instant (a seek, at least a lead ahead so
that every node hears of it in time). It only moves a show that plays: a paused, scheduled,
ended or stopped show is left alone, and so is a timecode outside the asset (a show that does
not loop). A looping show is compared modulo its length.

MIDI timecode (:mod:`coordinator.osc.mtc`) gives the same clock in seconds, chased the same way.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

from coordinator.api import ShowState

NS = 1_000_000_000
_TC = re.compile(r"^\s*(\d{1,3}):(\d{1,2}):(\d{1,2})(?:[:;](\d{1,2}))?\s*$")
_TC_FRACTION = re.compile(r"^\s*(\d{1,3}):(\d{1,2}):(\d{1,2}(?:\.\d+)?)\s*$")
#: the latest a timecode may say (a day): anything beyond is a mistake
MAX_SECONDS = 86400.0


def timecode_seconds(value: object, fps: float) -> float:
    """An OSC timecode argument as seconds: ``"hh:mm:ss:ff"`` (``ff`` frames at ``fps``),
    ``"hh:mm:ss.sss"`` or a number of seconds. ValueError in one line for anything else."""
    if isinstance(value, bool):
        raise ValueError(f"timecode must be \"hh:mm:ss:ff\" or seconds, got {value!r}")
    if isinstance(value, (int, float)):
        s = float(value)
    elif isinstance(value, str):
        m = _TC_FRACTION.match(value)
        if m and "." in m.group(3):
            h, mi, sec = int(m.group(1)), int(m.group(2)), float(m.group(3))
            if mi >= 60 or sec >= 60:
                raise ValueError(f"timecode {value!r}: minutes and seconds must be below 60")
            s = 3600 * h + 60 * mi + sec
        else:
            m = _TC.match(value)
            if not m:
                raise ValueError(f"timecode must be \"hh:mm:ss:ff\" or seconds, got {value!r}")
            h, mi, sec, ff = int(m.group(1)), int(m.group(2)), int(m.group(3)), int(m.group(4) or 0)
            if mi >= 60 or sec >= 60 or ff >= math.ceil(fps):
                raise ValueError(f"timecode {value!r}: minutes and seconds must be below 60 and frames below "
                                 f"{math.ceil(fps)} (timecode_fps {fps:g})")
            s = 3600 * h + 60 * mi + sec + ff / fps
    else:
        raise ValueError(f"timecode must be \"hh:mm:ss:ff\" or seconds, got {value!r}")
    if not math.isfinite(s) or not 0 <= s <= MAX_SECONDS:
        raise ValueError(f"timecode must be 0..{MAX_SECONDS:g} s, got {value!r}")
    return s


@dataclass(frozen=True)
class Seek:
    """Show ``frame`` at rig time ``at_ns``; ``drift_s`` is how far the show was from the clock
    (positive: the show was behind)."""

    frame: int
    at_ns: int
    drift_s: float


def show_position(show: ShowState, t_ns: int) -> float:
    """The show's position in frames at rig time ``t_ns`` (fractional, not wrapped), from its
    latest timeline: ``anchor_frame + (t - anchor) * rate`` (held at ``anchor_frame`` when paused)."""
    if show.paused or not show.rate_num:
        return float(show.anchor_frame)
    return show.anchor_frame + (t_ns - show.anchor_ns) * show.rate_num / (show.rate_den * NS)


def chase(clock_s: float, clock_at_ns: int, show: ShowState, now_ns: int, *, threshold_s: float,
          lead_ns: int) -> Seek | None:
    """The seek that puts ``show`` back on an external clock, or None.

    ``clock_s`` is where the show should be (seconds from its frame 0) at rig time
    ``clock_at_ns`` (when the timecode arrived); ``now_ns`` the rig time now; ``lead_ns`` how far
    ahead the seek is set. None unless the show plays and is more than ``threshold_s`` off.
    """
    if show.state != "playing" or show.frames <= 0 or not show.rate_num:
        return None
    fps = show.rate_num / show.rate_den
    external_s = clock_s + (now_ns - clock_at_ns) / NS
    length_s = show.frames / fps
    pos_s = show_position(show, now_ns) / fps
    drift = external_s - pos_s
    if show.loop:
        drift = (drift + length_s / 2) % length_s - length_s / 2       # the shorter way round
    elif not 0 <= external_s < length_s:
        return None
    if abs(drift) <= threshold_s:
        return None
    # the first frame boundary of the external clock at least a lead ahead: the seek lands in phase
    k = math.ceil((external_s + lead_ns / NS) * fps - 1e-9)
    if not show.loop and k >= show.frames:
        return None
    at_ns = now_ns + round((k / fps - external_s) * NS)
    return Seek(frame=int(k % show.frames), at_ns=int(at_ns), drift_s=drift)
