"""Stage 1, exposure: every projector black, then every projector white, per camera."""
from __future__ import annotations

import numpy as np

from imaging.calibration import graycode
from coordinator.calibration.stages.state import SATURATED, Abort, State, full

UNDER_EXPOSED = 0.02        # every projector white must reach at least this (fraction of full scale)


async def exposure(st: State) -> None:
    """Capture ``st.dark`` and ``st.white``; stop the run when a camera is under-exposed."""
    ctx, slots = st.ctx, st.slots
    ctx.progress("exposure", "", 0, 2, "every projector black")
    st.dark = await st.shoot({s: full(st.sizes[s], 0) for s in slots}, require=slots)
    ctx.progress("exposure", "", 1, 2, "every projector white")
    st.white = await st.shoot({s: full(st.sizes[s], 255) for s in slots}, require=slots)
    for i, (d, w) in zip(st.cameras, zip(st.dark, st.white)):
        level = float(np.percentile(graycode.luminance(w) - graycode.luminance(d), 99.0))
        if level < UNDER_EXPOSED:
            raise Abort(f"camera {i} under-exposed (every projector at full white reaches only {100 * level:.1f} % "
                        "of full scale): raise the exposure or gain (or check that the projectors are on)")
        sat = float(np.mean(w.max(axis=2) >= SATURATED))
        if sat > st.opts.max_saturated:
            ctx.log(f"note: camera {i} saturates {100 * sat:.0f} % of its pixels when every projector is white; "
                    "calibration shows one projector's light at a time, but light-transport measurements may need less exposure")
    ctx.progress("exposure", "", 2, 2, "ok")
