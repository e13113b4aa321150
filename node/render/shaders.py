"""The renderer's GLSL sources, with the ``#version`` line the context speaks, and what a
context offers the renderer (its API, the shading language, the texture formats it lacks).

The shaders beside this module are written in the common subset of GLSL 1.40 and GLSL ES 3.00
(no layout qualifiers, no texture rectangles; ``in``/``out``, ``texelFetch``, ``textureSize``,
``gl_VertexID``, integer bit operations), which OpenGL 3.1 (a Raspberry Pi's V3D) accepts as
``#version 140``, 3.3+ as ``#version 330 core`` and OpenGL ES 3.x (Mali, Adreno) as
``#version 300 es`` once default precisions are declared; the files carry no ``#version`` line
of their own.
"""
from __future__ import annotations

from importlib import resources
from typing import Any, NamedTuple

#: the oldest desktop OpenGL the renderer runs on: 3.1 (GLSL 1.40)
MIN_GL_VERSION = 310
#: the oldest OpenGL ES it runs on: 3.0 (GLSL ES 3.00)
MIN_GLES_VERSION = 300

# GLSL ES has no default float precision in fragment shaders and samples lowp from a sampler
# without one: every value the renderer computes (content coordinates of a 4K projector,
# 16-bit and float content, the LUT) needs highp, which OpenGL ES 3.0 guarantees in both stages.
_GLES_HEADER = "#version 300 es\nprecision highp float;\nprecision highp int;\nprecision highp sampler2D;\n"


#: a content's kind, as pipeline.glsl's CONTENT_KIND and FADE_FROM number them (0: black, only as a fade's start)
BLACK, RGB, GREY, YUV_PLANAR, YUV_SEMIPLANAR = 0, 1, 2, 3, 4


class Variant(NamedTuple):
    """One compiled form of the warp and mesh fragment shaders (pipeline.glsl's #define lines).

    ``content``: the frame's kind (RGB .. YUV_SEMIPLANAR); ``fade_from``: None without a fade, else
    the kind of the picture it starts from (BLACK for none); ``blend``: blend maps are applied
    (only with ``apply_lut``; :meth:`of` drops it otherwise); ``apply_lut``: gain, blend and LUT.
    """

    content: int
    fade_from: int | None
    blend: bool
    apply_lut: bool

    @classmethod
    def of(cls, content: int, fade_from: int | None = None, blend: bool = False, apply_lut: bool = True) -> "Variant":
        """The variant, normalised: blend maps count only where the LUT is applied."""
        return cls(int(content), None if fade_from is None else int(fade_from), bool(blend and apply_lut),
                   bool(apply_lut))

    def defines(self) -> str:
        """The #define lines that select this variant, to follow the #version line."""
        fade = -1 if self.fade_from is None else self.fade_from
        return (f"#define CONTENT_KIND {self.content}\n#define FADE_FROM {fade}\n#define BLEND {int(self.blend)}\n"
                f"#define APPLY_LUT {int(self.apply_lut)}\n")


def is_gles(ctx: Any) -> bool:
    """Whether ``ctx`` is an OpenGL ES context (its GL_VERSION starts "OpenGL ES", per the spec)."""
    return str(ctx.info.get("GL_VERSION", "")).startswith("OpenGL ES")


def glsl_header(version_code: int, gles: bool = False) -> str:
    """The ``#version`` line (and, for GLSL ES, the default precisions) for a context of
    ``version_code`` (e.g. 310, 330, 460; 300..320 for OpenGL ES)."""
    if gles:
        return _GLES_HEADER
    return "#version 330 core\n" if version_code >= 330 else "#version 140\n"


def shading_language(version_code: int, gles: bool = False) -> str:
    """The GLSL the shaders are compiled as: "GLSL 1.40", "GLSL 3.30" or "GLSL ES 3.00"."""
    if gles:
        return "GLSL ES 3.00"
    return "GLSL 3.30" if version_code >= 330 else "GLSL 1.40"


def is_software_rasterizer(ctx: Any) -> bool:
    """Whether ``ctx`` draws on the CPU (Mesa's llvmpipe or softpipe, SwiftShader), by its GL_RENDERER:
    there a texel fetch costs the same CPU as the node's own work."""
    renderer = str(ctx.info.get("GL_RENDERER", "")).lower()
    return any(name in renderer for name in ("llvmpipe", "softpipe", "swiftshader"))


def has_norm16_textures(ctx: Any) -> bool:
    """Whether 16-bit normalised textures (R16, RGBA16) exist: always on desktop OpenGL, on
    OpenGL ES only with GL_EXT_texture_norm16 (core GLES 3.x has none)."""
    return not is_gles(ctx) or "GL_EXT_texture_norm16" in ctx.extensions


def has_float_linear(ctx: Any) -> bool:
    """Whether float32 textures can be filtered (LINEAR): always on desktop OpenGL, on OpenGL ES
    only with GL_OES_texture_float_linear (core GLES 3.x filters float16 only)."""
    return not is_gles(ctx) or "GL_OES_texture_float_linear" in ctx.extensions


def fallbacks(ctx: Any) -> tuple[str, ...]:
    """What the renderer does differently on ``ctx`` for want of a format, in a few words each."""
    return tuple(note for ok, note in ((has_norm16_textures(ctx), "16-bit content as float32"),
                                       (has_float_linear(ctx), "blend maps as float16")) if not ok)


def load_shader(name: str, header: str = "") -> str:
    """Read a shader file that lives beside this module, after ``header`` (its #version line)."""
    return header + resources.files(__package__).joinpath(name).read_text(encoding="utf-8")


def gl_description(ctx: Any) -> str:
    """What a context offers, for the operator's status: e.g. "OpenGL 3.1, GLSL 1.40, V3D 4.2" or
    "OpenGL ES 3.2, GLSL ES 3.00, llvmpipe (LLVM 15.0.6, 256 bits)" (the API and version the node
    got, the shading language its shaders use, the driver), then any format it falls back from."""
    v, gles = ctx.version_code, is_gles(ctx)
    api = "OpenGL ES" if gles else "OpenGL"
    renderer = str(ctx.info.get("GL_RENDERER", "")).strip()
    text = f"{api} {v // 100}.{v % 100 // 10}, {shading_language(v, gles)}"
    text = f"{text}, {renderer}" if renderer else text
    notes = fallbacks(ctx)
    return f"{text}; {', '.join(notes)}" if notes else text
