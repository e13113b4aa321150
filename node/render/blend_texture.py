"""Blend maps as the texture the node's shader samples: one texel fetch per pixel, filtered by the
texture unit (pipeline.glsl's ``blend_at``).

A :class:`protos.blend.BlendMaps` of ``w`` x ``h`` texels becomes one RGBA texture of ``w`` x ``h``
(rgb = alpha, a = beta), its rows in GL order (row 0 is the output's bottom row, as
``gl_FragCoord`` counts them), with LINEAR filtering and CLAMP_TO_EDGE. Sampled at texture
coordinate ``gl_FragCoord.xy / (W, H)`` for an output of W x H pixels, the filter reads map texel
``((x + 0.5) w / W - 0.5, (y + 0.5) h / H - 0.5)`` (OpenCV pixel (x, y), rows from the top once the
flip is undone), bilinear between the four texels around it, clamped to the edge texels: exactly
:func:`protos.spaces.blend_sample`.

Format: RGBA32F holding the wire's float16 values exactly, where float32 textures can be filtered
(desktop OpenGL always; OpenGL ES with ``GL_OES_texture_float_linear``); else RGBA16F, the same
values, which every OpenGL ES 3 filters. llvmpipe filters float32 texels directly and converts
float16 texels one by one first: at 1080p the filtered RGBA32F fetch costs about a third of the four
explicit float16 fetches it replaces (``shadowless bench node --size 1920x1080``). A real GPU does
either in one instruction, its bilinear weights possibly rounded to 8 bits (1/256 of a texel): the
weights of maps at a quarter of the output's resolution, 1/8, 3/8, 5/8 and 7/8, are exact in 8 bits;
at other ratios an alpha differs from the float weights' by at most 1/512 of the step between two
neighbouring texels.

Memory: 16 bytes per texel, 2.1 MB for 1080p's 480 x 270 maps (8 bytes, 1 MB, as RGBA16F).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from node.render.shaders import has_float_linear, is_gles
from protos.blend import BlendMaps

__all__ = ["blend_texture"]

#: GL_RGBA32F, the internal format desktop OpenGL converts the float16 upload to
_GL_RGBA32F = 0x8814


def blend_texture(ctx: Any, mgl: Any, maps: BlendMaps, max_side: int) -> Any:
    """The moderngl texture of ``maps`` for ``ctx`` (see the module docstring); ValueError when a
    side exceeds ``max_side`` (the GPU's largest texture)."""
    w, h = maps.size
    if w > max_side or h > max_side:
        raise ValueError(f"blend maps of {w}x{h} texels exceed this GPU's {max_side} per side")
    # the wire's float16 bytes (a decoded or packed instance holds them; numpy converts float32 to
    # float16 slowly: 13 ms for 1080p maps against under 1 ms to copy the halves), rows flipped to GL order
    alpha, beta = maps.encode()
    data = np.empty((h, w, 4), "<f2")
    data[:, :, :3] = np.frombuffer(alpha, "<f2").reshape(h, w, 3)[::-1]
    data[:, :, 3] = np.frombuffer(beta, "<f2").reshape(h, w)[::-1]
    if not has_float_linear(ctx):
        tex = ctx.texture((w, h), 4, data, dtype="f2", alignment=1)
    elif is_gles(ctx):      # OpenGL ES takes RGBA32F from float32 data only
        tex = ctx.texture((w, h), 4, data.astype(np.float32), dtype="f4", alignment=1)
    else:                   # desktop OpenGL converts the halves itself, faster than numpy
        tex = ctx.texture((w, h), 4, data, dtype="f2", alignment=1, internal_format=_GL_RGBA32F)
    tex.filter = (mgl.LINEAR, mgl.LINEAR)
    tex.repeat_x = tex.repeat_y = False       # CLAMP_TO_EDGE
    return tex
