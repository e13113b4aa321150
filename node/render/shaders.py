"""The renderer's GLSL sources, with the ``#version`` line the context speaks.

The shaders beside this module are written in GLSL 1.40 (no layout qualifiers, ``in``/``out``,
``texelFetch``), which OpenGL 3.1 (a Raspberry Pi's V3D) accepts as ``#version 140`` and 3.3+
as ``#version 330 core``; the files carry no ``#version`` line of their own.
"""
from __future__ import annotations

from importlib import resources

#: the oldest OpenGL the renderer runs on: 3.1 (GLSL 1.40)
MIN_GL_VERSION = 310


def glsl_header(version_code: int) -> str:
    """The ``#version`` line for a context of ``version_code`` (e.g. 310, 330, 460)."""
    return "#version 330 core\n" if version_code >= 330 else "#version 140\n"


def load_shader(name: str, header: str = "") -> str:
    """Read a shader file that lives beside this module, after ``header`` (its #version line)."""
    return header + resources.files(__package__).joinpath(name).read_text(encoding="utf-8")


def gl_description(ctx) -> str:
    """What a context offers, for the operator's status: e.g. "OpenGL 3.1, GLSL 1.40, V3D 4.2"
    (the version the node asked for and got, the shading language its shaders use, the driver)."""
    v = ctx.version_code
    glsl = glsl_header(v).split()[1]
    renderer = str(ctx.info.get("GL_RENDERER", "")).strip()
    text = f"OpenGL {v // 100}.{v % 100 // 10}, GLSL {glsl[0]}.{glsl[1:]}"
    return f"{text}, {renderer}" if renderer else text
