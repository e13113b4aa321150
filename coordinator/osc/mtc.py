"""MIDI timecode (MTC) read from bytes: the quarter-frame messages and the full-frame SysEx.

Pure Python and no MIDI library: the bytes come from a MIDI port (:mod:`coordinator.osc.mtc_input`,
mido) or a test. What is read is a :class:`Reading`: where the external clock is, in seconds from
00:00:00:00, at the instant its last byte arrived; the show-control service chases it exactly like
an OSC timecode (:mod:`coordinator.osc.timecode`).

**Rates** (the two bits ``rr`` beside the hours): 0 = 24 fps, 1 = 25 fps, 2 = 29.97 fps drop-frame
(30000/1001 frames a second; frames 0 and 1 are skipped at the start of every minute but every
tenth, so that the count stays on the wall clock), 3 = 30 fps.

**Quarter frames** (``F1 0nnndddd``): while the clock runs, the sender sends four a frame, pieces
``nnn`` = 0..7 in order, each carrying a nibble of the timecode of the frame during which piece 0
was sent (0: frames low nibble, 1: frames high bit, 2/3: seconds, 4/5: minutes, 6: hours low
nibble, 7: ``0rrh`` the rate and the hours' high bit). A timecode is therefore complete only with
piece 7, which arrives 7 quarter frames after the frame it names began: the reading at piece 7 is
that timecode **plus 7/4 of a frame** (the "2 frames behind" of the MTC spec is the next group's
start, a quarter frame later still). Pieces that come out of order (a dropped byte, a sender
running backwards while it shuttles) start the assembly again: a clock that runs backwards is not
chased, and the next 8 pieces in order give a reading again.

**Full frame** (``F0 7F dev 01 01 hh mm ss ff F7``, ``hh`` = ``0rrhhhhh``): the sender located to
this timecode (a jump, usually while stopped): a reading of exactly it, with no compensation.

Bytes may come in any pieces (:meth:`MtcDecoder.feed` keeps a partial message); System Real-Time
bytes (``F8``..``FF``) are ignored wherever they fall, any other message is skipped.
"""
from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction

#: the rate code (two bits) -> frames per second (exact) and whether frames are dropped
RATES: dict[int, tuple[Fraction, bool]] = {0: (Fraction(24), False), 1: (Fraction(25), False),
                                          2: (Fraction(30000, 1001), True), 3: (Fraction(30), False)}
#: each rate code as people say it
RATE_NAMES = {0: "24", 1: "25", 2: "29.97 drop", 3: "30"}
QUARTER_FRAME = 0xF1
SYSEX, SYSEX_END = 0xF0, 0xF7
#: the longest SysEx kept (a full-frame message is 10 bytes; longer ones are skipped, not stored)
SYSEX_MAX = 16


@dataclass(frozen=True)
class Timecode:
    """hh:mm:ss:ff at rate code ``rate`` (:data:`RATES`)."""

    hours: int
    minutes: int
    seconds: int
    frames: int
    rate: int

    def __post_init__(self) -> None:
        if self.rate not in RATES:
            raise ValueError(f"MTC rate code must be 0..3, got {self.rate}")
        nominal = self.nominal_fps
        if not (0 <= self.hours < 24 and 0 <= self.minutes < 60 and 0 <= self.seconds < 60
                and 0 <= self.frames < nominal):
            raise ValueError(f"timecode {self} is out of range at {RATE_NAMES[self.rate]} fps")
        if self.drop and self.seconds == 0 and self.frames < 2 and self.minutes % 10:
            raise ValueError(f"timecode {self} does not exist at 29.97 drop-frame (frames 0 and 1 are dropped)")

    @property
    def fps(self) -> Fraction:
        """Frames per second, exact (30000/1001 at 29.97)."""
        return RATES[self.rate][0]

    @property
    def drop(self) -> bool:
        return RATES[self.rate][1]

    @property
    def nominal_fps(self) -> int:
        """The frames counted per timecode second (30 at 29.97)."""
        return round(self.fps)

    @property
    def frame_number(self) -> int:
        """Frames since 00:00:00:00 (drop-frame: the dropped numbers are not counted)."""
        n = self.nominal_fps
        count = ((self.hours * 60 + self.minutes) * 60 + self.seconds) * n + self.frames
        if self.drop:
            total_minutes = self.hours * 60 + self.minutes
            count -= 2 * (total_minutes - total_minutes // 10)
        return count

    @property
    def seconds_since_midnight(self) -> float:
        """Real seconds since 00:00:00:00: ``frame_number / fps``."""
        return float(self.frame_number / self.fps)

    def __str__(self) -> str:
        sep = ";" if self.drop else ":"
        return f"{self.hours:02d}:{self.minutes:02d}:{self.seconds:02d}{sep}{self.frames:02d}"


def from_frame_number(count: int, rate: int) -> Timecode:
    """The timecode of frame ``count`` since 00:00:00:00 at rate code ``rate`` (wraps at 24 h)."""
    fps, drop = RATES[rate]
    n = round(fps)
    if drop:        # 17982 frames per 10 minutes; 1798 in each minute but the tenth (which has 1800)
        tens, rest = divmod(count, 17982)
        count += 18 * tens + (2 * ((rest - 2) // 1798) if rest >= 2 else 0)
    count %= 24 * 3600 * n
    frames = count % n
    secs = count // n
    return Timecode(secs // 3600, secs // 60 % 60, secs % 60, frames, rate)


def quarter_frames(tc: Timecode) -> bytes:
    """The eight quarter-frame messages (16 bytes) that carry ``tc``, pieces 0..7."""
    nibbles = (tc.frames & 0xF, tc.frames >> 4, tc.seconds & 0xF, tc.seconds >> 4, tc.minutes & 0xF,
               tc.minutes >> 4, tc.hours & 0xF, (tc.rate << 1) | (tc.hours >> 4))
    return b"".join(bytes((QUARTER_FRAME, (k << 4) | v)) for k, v in enumerate(nibbles))


def full_frame(tc: Timecode, device: int = 0x7F) -> bytes:
    """The full-frame SysEx (10 bytes) that locates to ``tc``."""
    return bytes((SYSEX, 0x7F, device & 0x7F, 0x01, 0x01, (tc.rate << 5) | tc.hours, tc.minutes, tc.seconds,
                  tc.frames, SYSEX_END))


@dataclass(frozen=True)
class Reading:
    """The external clock: ``seconds`` since 00:00:00:00 at rig time ``at_ns`` (when the message that
    completed it arrived); ``kind`` "quarter" (running) or "full" (located); ``timecode`` as sent."""

    seconds: float
    at_ns: int
    kind: str
    timecode: Timecode


class MtcDecoder:
    """Feed it MIDI bytes as they arrive; it returns the readings they complete (module docstring)."""

    def __init__(self) -> None:
        self._pieces: list[int] = []        # the nibbles of the group being assembled, pieces 0..len-1
        self._status = 0                    # the status byte whose data bytes are awaited (0: none)
        self._sysex: bytearray | None = None
        self.skipped = 0                    # malformed or out-of-order messages seen (for the log)

    def feed(self, data: bytes | bytearray | list[int], at_ns: int) -> list[Reading]:
        """The readings completed by ``data``, which arrived at rig time ``at_ns``."""
        out: list[Reading] = []
        for b in data:
            b &= 0xFF
            if b >= 0xF8:                   # System Real-Time: may sit anywhere, even inside a SysEx
                continue
            if self._sysex is not None:
                if b == SYSEX_END:
                    reading = self._full(bytes(self._sysex), at_ns)
                    self._sysex = None
                    if reading is not None:
                        out.append(reading)
                    continue
                if b & 0x80:                # any other status ends a SysEx that never closed
                    self._sysex = None
                    self.skipped += 1
                else:
                    if len(self._sysex) < SYSEX_MAX:
                        self._sysex.append(b)
                    continue
            if b == SYSEX:
                self._sysex, self._status = bytearray(), 0
            elif b & 0x80:
                self._status = b
            elif self._status == QUARTER_FRAME:
                self._status = 0
                reading = self._quarter(b, at_ns)
                if reading is not None:
                    out.append(reading)
            # data bytes of any other message (notes, clocks' song position, ...) are not ours
        return out

    def _quarter(self, b: int, at_ns: int) -> Reading | None:
        piece, nibble = b >> 4, b & 0xF
        if piece != len(self._pieces):
            self.skipped += piece != 0 or bool(self._pieces)
            self._pieces = []
            if piece != 0:
                return None
        self._pieces.append(nibble)
        if piece < 7:
            return None
        p = self._pieces
        self._pieces = []
        try:
            tc = Timecode(hours=p[6] | (p[7] & 1) << 4, minutes=p[4] | p[5] << 4, seconds=p[2] | p[3] << 4,
                          frames=p[0] | p[1] << 4, rate=(p[7] >> 1) & 3)
        except ValueError:
            self.skipped += 1
            return None
        # piece 7 arrives 7 quarter frames after the frame tc names began
        return Reading(tc.seconds_since_midnight + float(Fraction(7, 4) / tc.fps), at_ns, "quarter", tc)

    def _full(self, body: bytes, at_ns: int) -> Reading | None:
        """``body``: the SysEx's bytes between F0 and F7."""
        if len(body) != 8 or body[0] != 0x7F or body[2:4] != b"\x01\x01":
            return None                     # another SysEx (or a user-bits message): not a location
        hr, mn, sc, fr = body[4:8]
        self._pieces = []
        try:
            tc = Timecode(hours=hr & 0x1F, minutes=mn, seconds=sc, frames=fr, rate=(hr >> 5) & 3)
        except ValueError:
            self.skipped += 1
            return None
        return Reading(tc.seconds_since_midnight, at_ns, "full", tc)
