"""The show's timeline, as every process computes it: which frame of which asset is on the
projectors at a given instant of the rig clock.

A :class:`Timeline` is a tiny, immutable description: frame ``anchor_frame`` of asset
``asset_id`` is shown at rig time ``anchor_ns``, and from there one frame per ``1 / rate``
seconds (``rate`` an exact fraction, so 29.97 fps is 30000/1001 and nothing drifts over a
long show), wrapping around with ``loop``, held while ``paused``. The coordinator sends it
(start, pause, seek, stop, and a low-rate beacon), never per-frame data; a node that joins
mid-show computes where the show is from it and the rig clock alone.

Changes take effect at a rig-clock instant in the future (every node switches at the same
instant): :class:`Schedule` keeps the timeline in force and those waiting for their instant.

All arithmetic is on integers (nanoseconds, frame indices): frame ``n`` after the anchor is
shown at ``anchor_ns + ceil(n * 1e9 / rate)``, and :meth:`Timeline.frame_at` inverts that
exactly, so ``frame_at(pts(k)) == k`` for every frame.

Only the standard library: every install computes timelines, the edge node's included.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from fractions import Fraction
from typing import Iterator, Mapping

__all__ = ["Timeline", "Schedule", "TimelineError", "as_rate"]

NS = 1_000_000_000


class TimelineError(ValueError):
    """A timeline or a change to it is impossible; the message says why."""


def as_rate(fps: float | Fraction | str) -> Fraction:
    """A frame rate as an exact fraction: ``29.97`` -> 30000/1001, ``"25"`` -> 25, ``23.976`` -> 24000/1001."""
    if isinstance(fps, Fraction):
        rate = fps
    else:
        rate = Fraction(str(fps)) if isinstance(fps, str) else Fraction(fps).limit_denominator(1001)
        for ntsc in (24, 30, 48, 60, 120):
            if abs(rate - Fraction(ntsc * 1000, 1001)) < Fraction(1, 10_000):
                rate = Fraction(ntsc * 1000, 1001)
    if not 0 < rate <= 1000:
        raise TimelineError(f"frame rate must be in (0, 1000] fps, got {float(rate):g}")
    return rate


@dataclass(frozen=True)
class Timeline:
    """Frame ``anchor_frame`` of ``asset_id`` at rig time ``anchor_ns``, then ``rate`` frames per second.

    ``frames`` is the asset's frame count; ``loop`` wraps around at the end (otherwise the show
    has ended after the last frame); ``paused`` holds ``anchor_frame`` from ``anchor_ns`` on.
    ``revision`` orders changes (a node keeps the newest it has seen). ``fade_ns`` > 0: the show
    crossfades in from what the projectors showed before, over that long from ``anchor_ns``
    (:mod:`protos.fade`; a start's own, which no later change carries).
    """

    asset_id: str
    frames: int
    rate: Fraction
    anchor_ns: int
    anchor_frame: int = 0
    loop: bool = False
    paused: bool = False
    revision: int = 0
    fade_ns: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.frames, int) or self.frames < 1:
            raise TimelineError(f"an asset on the timeline has at least one frame, got {self.frames}")
        if not 0 <= self.anchor_frame < self.frames:
            raise TimelineError(f"frame {self.anchor_frame} is not in the asset's 0..{self.frames - 1}")
        if not isinstance(self.rate, Fraction) or not 0 < self.rate <= 1000:
            raise TimelineError(f"rate must be a Fraction in (0, 1000] fps, got {self.rate!r}")

    # ------------------------------------------------------------------ reading
    def _elapsed_frames(self, t_ns: int) -> int:
        """Whole frame periods from the anchor to ``t_ns`` (``t_ns >= anchor_ns``)."""
        return ((t_ns - self.anchor_ns) * self.rate.numerator) // (NS * self.rate.denominator)

    def frame_at(self, t_ns: int) -> int | None:
        """The asset frame on the projectors at rig time ``t_ns``; None before the anchor or after the end."""
        if t_ns < self.anchor_ns:
            return None
        if self.paused:
            return self.anchor_frame
        k = self.anchor_frame + self._elapsed_frames(t_ns)
        if k >= self.frames:
            return k % self.frames if self.loop else None
        return k

    def tick_at(self, t_ns: int) -> int | None:
        """The index of the frame period ``t_ns`` falls in, counted from the anchor (None before it)."""
        if t_ns < self.anchor_ns:
            return None
        return 0 if self.paused else self._elapsed_frames(t_ns)

    def pts(self, tick: int) -> int:
        """Rig time at which frame period ``tick`` (counted from the anchor) begins."""
        num, den = self.rate.numerator, self.rate.denominator
        return self.anchor_ns + -((-tick * NS * den) // num)    # ceil(tick * 1e9 / rate)

    def frame_of_tick(self, tick: int) -> int | None:
        """The asset frame shown during period ``tick``; None after the end of a show that does not loop."""
        if self.paused:
            return self.anchor_frame
        k = self.anchor_frame + tick
        if k >= self.frames:
            return k % self.frames if self.loop else None
        return k

    def end_ns(self) -> int | None:
        """Rig time at which a show that does not loop has shown its last frame (None: never ends)."""
        if self.loop or self.paused:
            return None
        return self.pts(self.frames - self.anchor_frame)

    # ------------------------------------------------------------------ changing (at an instant)
    def paused_at(self, t_ns: int) -> "Timeline":
        """Hold the frame shown at ``t_ns`` from then on."""
        k = self.frame_at(max(t_ns, self.anchor_ns))
        if k is None:
            k = self.frames - 1
        return replace(self, anchor_ns=t_ns, anchor_frame=k, paused=True, revision=self.revision + 1, fade_ns=0)

    def resumed_at(self, t_ns: int) -> "Timeline":
        """Go on from the held frame at ``t_ns`` (it is shown for one more period first)."""
        return replace(self, anchor_ns=t_ns, paused=False, revision=self.revision + 1, fade_ns=0)

    def seeked(self, frame: int, t_ns: int) -> "Timeline":
        """Show ``frame`` at ``t_ns`` and go on from there (paused stays paused)."""
        if not 0 <= frame < self.frames:
            raise TimelineError(f"cannot seek to frame {frame}: the asset has frames 0..{self.frames - 1}")
        return replace(self, anchor_ns=t_ns, anchor_frame=frame, revision=self.revision + 1, fade_ns=0)

    # ------------------------------------------------------------------ on the wire
    def to_json(self) -> dict:
        return {"asset_id": self.asset_id, "frames": self.frames, "rate": [self.rate.numerator, self.rate.denominator],
                "anchor_ns": self.anchor_ns, "anchor_frame": self.anchor_frame, "loop": self.loop,
                "paused": self.paused, "revision": self.revision, "fade_ns": self.fade_ns}

    @classmethod
    def from_json(cls, doc: dict) -> "Timeline":
        try:
            num, den = (int(v) for v in doc["rate"])
            return cls(asset_id=str(doc["asset_id"]), frames=int(doc["frames"]), rate=Fraction(num, den),
                       anchor_ns=int(doc["anchor_ns"]), anchor_frame=int(doc.get("anchor_frame", 0)),
                       loop=bool(doc.get("loop", False)), paused=bool(doc.get("paused", False)),
                       revision=int(doc.get("revision", 0)), fade_ns=max(0, int(doc.get("fade_ns", 0))))
        except (KeyError, TypeError, ValueError, ZeroDivisionError) as exc:
            if isinstance(exc, TimelineError):
                raise
            raise TimelineError(f"bad timeline: {exc}") from exc


class Schedule:
    """The timeline in force at each instant: changes wait for their anchor, the newest revision wins.

    A node keeps one: :meth:`offer` every timeline the coordinator sends (a start, a change, a
    beacon repeating the current one), :meth:`at` asks which timeline governs rig time ``t_ns``.
    A stop is a timeline of ``None`` at an instant (:meth:`offer_stop`).
    """

    def __init__(self) -> None:
        # (anchor_ns, revision, timeline or None for a stop), ordered by anchor
        self._entries: list[tuple[int, int, Timeline | None]] = []
        self.revision = -1

    def offer(self, timeline: Timeline) -> bool:
        """Take ``timeline`` unless an equal or newer revision is known; whether it was new."""
        return self._add(timeline.anchor_ns, timeline.revision, timeline)

    def offer_stop(self, at_ns: int, revision: int) -> bool:
        """The show stops at ``at_ns`` (revision ordered with the timelines')."""
        return self._add(at_ns, revision, None)

    def _add(self, at_ns: int, revision: int, timeline: Timeline | None) -> bool:
        if revision <= self.revision:
            return False
        self.revision = revision
        # a newer change replaces every pending change that would take effect at or after it
        self._entries = [e for e in self._entries if e[0] < at_ns and e[1] < revision]
        self._entries.append((at_ns, revision, timeline))
        self._entries.sort(key=lambda e: (e[0], e[1]))
        return True

    def at(self, t_ns: int) -> Timeline | None:
        """The timeline governing rig time ``t_ns`` (None: nothing scheduled, or stopped)."""
        current = None
        for at_ns, _, tl in self._entries:
            if at_ns <= t_ns:
                current = tl
            else:
                break
        return current

    def forget_before(self, t_ns: int) -> None:
        """Drop entries superseded before ``t_ns`` (keeps the one in force at ``t_ns``)."""
        keep_from = 0
        for i, (at_ns, _, _) in enumerate(self._entries):
            if at_ns <= t_ns:
                keep_from = i
        self._entries = self._entries[keep_from:]

    @property
    def pending(self) -> list[tuple[int, Timeline | None]]:
        """Every entry (anchor, timeline or None), in order."""
        return [(a, tl) for a, _, tl in self._entries]

    def ticks(self, bases: Mapping[int, int], lo_ns: int, hi_ns: int | None = None) -> Iterator[tuple[int, int]]:
        """``(frame_id, pts_ns)`` of the ticks at rig times in ``[lo_ns, hi_ns)`` (no end: None), in
        order, across the changes; tick k of a revision is frame ``bases[revision] + k`` (revisions
        without a base are skipped). A paused timeline has one tick, its held frame at its anchor; a
        timeline that does not loop ends after its last frame; a stop has none."""
        entries = self.pending
        for i, (start, tl) in enumerate(entries):
            end = entries[i + 1][0] if i + 1 < len(entries) else None
            if hi_ns is not None:
                end = hi_ns if end is None else min(end, hi_ns)
            if tl is None or tl.revision not in bases:
                continue
            base, a = bases[tl.revision], max(lo_ns, start)
            if end is not None and a >= end:
                continue
            if tl.paused:
                if a <= tl.anchor_ns and (end is None or tl.anchor_ns < end):
                    yield base, tl.anchor_ns
                continue
            k = tl.tick_at(a)
            if k is None:
                continue
            if tl.pts(k) < a:
                k += 1
            while (end is None or tl.pts(k) < end) and tl.frame_of_tick(k) is not None:
                yield base + k, tl.pts(k)
                k += 1
