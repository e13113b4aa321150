"""The camera exposure a measurement on an object runs at: the rig's white inside the camera's range.

A camera's exposure is set once, on the table. An object can be lit far brighter: the bust's crown
is closer to the projectors and faces them, and 25 projectors throw 1.9 times the camera's full scale
there. A dot of one texel is nearly as bright as the white where a texel spans several camera pixels,
so the dots clip too, ``L`` comes out short where the surface is brightest, and every score made
against a clipped capture measures the sensor. So before measuring, the rig shows white, and the
captures that follow run at the relative exposure that puts the brightest pixel at :data:`HEADROOM`
of full scale (never above the camera's own). ``L`` is then in the units of that exposure, and every
capture compared with it is taken at the same one.

A dot pattern lights a few texels apart, so its brightest pixel holds a part of the white's: the dots
are captured longer (:func:`dot_gain`), as far as the first pattern's peak allows, and brought back to
the white's units. The noise in ``L`` falls by the same factor, for two more captures (that pattern
at the white's exposure, and the black at the longer one) and no extra pattern.
"""
from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field

import numpy as np

__all__ = ["CLIPPED", "DOT_GAIN_MAX", "DOT_HEADROOM", "HEADROOM", "Capture", "DotExposure", "dot_exposure", "dot_gain",
           "exposure_for_white"]

#: a capture value at or above this share of the camera's full scale is taken as clipped
CLIPPED = 1.0 - 1.0 / 512
#: where the brightest pixel of the rig's white should land, as a share of full scale
HEADROOM = 0.9
PROBE = 0.25      # the white is captured at this relative exposure: up to 4x full scale is read in one capture
_HALVINGS = 6     # and halved while it still clips: up to 256x
#: where the first dot pattern's brightest pixel should land: the other patterns light other texels and may
#: be brighter, so there is more headroom than for the white; a pattern that clips is captured again
DOT_HEADROOM = 0.6
#: the most the dots' exposure is raised over the white's
DOT_GAIN_MAX = 16.0


async def exposure_for_white(capture: Callable[[float | None], Awaitable[np.ndarray]], *, adjustable: bool,
                             log: Callable[[str], None]) -> tuple[float, float]:
    """``(exposure, peak)``: the relative exposure (at most 1) at which the white the caller shows peaks at
    :data:`HEADROOM` of full scale, and that peak at the camera's own exposure (a share of full scale).

    ``capture(exposure)``: one capture of the white, ``(H, W, C)`` float in ``[0, 1]`` (``None``: the
    camera's own exposure). One capture at :data:`PROBE` (so the count does not depend on the rig), more
    only while the white still clips there. A camera that cannot change its exposure (``adjustable``
    False) keeps its own, with a warning when the white clips.
    """
    scale = PROBE if adjustable else 1.0
    p = float(np.max(await capture(scale if adjustable else None)))
    for _ in range(_HALVINGS if adjustable else 0):
        if p < CLIPPED:
            break
        scale /= 2
        p = float(np.max(await capture(scale)))
    if p >= CLIPPED:
        log("warning: the rig's white reaches the camera's full scale on the surface"
            + ("" if adjustable else " and this camera cannot change its exposure per capture")
            + ": L is short where the captures clip; lower the camera's exposure and measure again")
        return (scale if adjustable else 1.0), p / scale
    peak = p / scale
    chosen = min(1.0, HEADROOM / peak) if adjustable and peak > 0 else 1.0
    if chosen < 1.0:
        log(f"the rig's white reaches {peak:.2f} of the camera's full scale on the surface: measuring at "
            f"{chosen:.3f} times its exposure")
    return chosen, peak


def dot_gain(peak: float, *, adjustable: bool) -> float:
    """How many times the white's exposure the dot patterns are captured at, from ``peak``: the brightest
    value of the first dot pattern captured at the white's exposure (a share of full scale, the black
    level included). 1 for a camera that cannot change its exposure, at most :data:`DOT_GAIN_MAX`, and
    never below 1: a dot is never brighter than the white it is part of.
    """
    if not adjustable or not np.isfinite(peak) or peak <= 0:
        return 1.0
    return float(min(DOT_GAIN_MAX, max(1.0, DOT_HEADROOM / peak)))


#: ``capture(exposure, frames)``: one capture of what the rig shows, ``(H, W, C)`` float in ``[0, 1]``
#: (``exposure`` None: the camera's own)
Capture = Callable[[float | None, int], Awaitable[np.ndarray]]


@dataclass
class DotExposure:
    """The dot patterns captured at ``gain`` times the white's exposure and returned in the white's units.

    ``exposure`` is the white's (``None``: the camera's own), the one ``L`` and ``black`` are in;
    ``black_long`` is the black at the dots' exposure. A pattern that clips at the longer exposure is
    captured again at the white's (``again``); one that clips even there is noted in ``clipped``.
    """

    exposure: float | None
    black: np.ndarray
    gain: float = 1.0
    black_long: np.ndarray | None = None
    again: list[int] = field(default_factory=list)
    clipped: list[int] = field(default_factory=list)

    @property
    def long(self) -> float:
        """The dots' relative exposure."""
        return (1.0 if self.exposure is None else self.exposure) * self.gain

    async def take(self, k: int, capture: Capture, frames: int) -> np.ndarray:
        """Pattern ``k``'s capture in the white's units: ``black + (long - black_long) / gain``, or the
        capture at the white's exposure when the longer one clips."""
        if self.gain > 1.0 and self.black_long is not None:
            img = await capture(self.long, frames)
            if float(img.max()) < CLIPPED:
                return self.black + (img - self.black_long) / np.float32(self.gain)
            self.again.append(k)
        img = await capture(self.exposure, frames)
        if float(img.max()) >= CLIPPED:
            self.clipped.append(k)
        return img

    def report(self, patterns: int, log: Callable[[str], None]) -> None:
        """Log the patterns captured again and warn about the ones that clipped."""
        if self.again:
            log(f"{len(self.again)} of {patterns} dot patterns clipped at {self.gain:.2f} times the white's exposure "
                "and were captured again at the white's")
        if self.clipped:
            log(f"warning: {len(self.clipped)} of {patterns} dot patterns reached the camera's full scale: L is short "
                "where they clipped; lower the camera's exposure and measure again")


async def dot_exposure(capture: Capture, *, show_first: Callable[[], Awaitable[object]],
                       show_black: Callable[[], Awaitable[object]], black: np.ndarray, exposure: float | None,
                       adjustable: bool, frames: int, log: Callable[[str], None]) -> DotExposure:
    """How the dot patterns are captured: the first pattern (``show_first``) captured once at the white's
    ``exposure`` sets the :func:`dot_gain`; when it is above 1, the black (``show_black``) is captured at
    the longer exposure with ``frames``. Two captures, none for a camera that cannot change its exposure."""
    out = DotExposure(exposure, black)
    if not adjustable:
        return out
    await show_first()
    gain = dot_gain(float((await capture(exposure, 1)).max()), adjustable=True)
    if gain > 1.0:
        out.gain = gain
        log(f"the dot patterns are captured at {gain:.2f} times the white's exposure (L's noise falls as much)")
        await show_black()
        out.black_long = await capture(out.long, frames)
    return out
