"""The camera exposure a measurement on an object runs at: the rig's white inside the camera's range.

A camera's exposure is set once, on the table. An object can be lit far brighter: the bust's crown
is closer to the projectors and faces them, and 25 projectors throw 1.9 times the camera's full scale
there. A dot of one texel is nearly as bright as the white where a texel spans several camera pixels,
so the dots clip too, ``L`` comes out short where the surface is brightest, and every score made
against a clipped capture measures the sensor. So before measuring, the rig shows white, and the
captures that follow run at the relative exposure that puts the brightest pixel at :data:`HEADROOM`
of full scale (never above the camera's own). ``L`` is then in the units of that exposure, and every
capture compared with it is taken at the same one.
"""
from __future__ import annotations

from collections.abc import Awaitable, Callable

import numpy as np

__all__ = ["CLIPPED", "HEADROOM", "exposure_for_white"]

#: a capture value at or above this share of the camera's full scale is taken as clipped
CLIPPED = 1.0 - 1.0 / 512
#: where the brightest pixel of the rig's white should land, as a share of full scale
HEADROOM = 0.9
PROBE = 0.25      # the white is captured at this relative exposure: up to 4x full scale is read in one capture
_HALVINGS = 6     # and halved while it still clips: up to 256x


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
