"""What a presenter draws once when its output opens, before any frame: every shader path it will use.

llvmpipe JITs a shader at its first draw (~0.1 s): drawn now, not while the first real frame waits for
its deadline, nor the first frame shown with blend maps at the instant every node switches.
"""
from __future__ import annotations

import numpy as np

from node.render.renderer import Renderer
from protos.blend import BlendMaps


def warm_start(r: Renderer, ctx) -> None:
    """Draw once with every shader path so the driver compiles them now, on ``r`` (whose GL context is
    ``ctx``); the renderer is left with no content, no LUT, no blend maps and no pose."""
    img = np.zeros((r.height, r.width, 3), np.uint8)          # (H, W, 3) uint8: black at the output's size
    r.upload("__warm__", img)
    r.set_homography(np.eye(3), (r.width, r.height))
    for lut in (None, np.tile(np.linspace(0, 1, 16, dtype=np.float32), (3, 1))):
        r.set_lut(lut)
        r.render("__warm__", space="content", apply_lut=True)
        r.render("__warm__", space="content", apply_lut=False)
    r.render("__warm__", space="projector", apply_lut=False)
    # the blended pipeline too: the first frame shown with blend maps must not wait for it
    r.set_blend(BlendMaps(np.ones((1, 1, 3), np.float32), np.zeros((1, 1), np.float32)))
    r.render("__warm__", space="content", apply_lut=True)
    r.set_blend(None)
    ctx.finish()
    r.forget("__warm__", reuse=False)     # drawn once: its 8 MB texture not kept for reuse
    # the shader variants of video, blends and fades too (node/render/renderer.py); drawn after the
    # forget, so that llvmpipe lets the warm picture's texture go now (it keeps a released texture
    # until a draw binds another), not at the first content: 8 MB less for an idle presenter at 1080p
    r.warm_up()
    r.set_lut(None)
    r.clear_pose()
