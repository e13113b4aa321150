"""The GL function table moderngl gets on an OpenGL ES context, whoever made the context.

moderngl 5.13 loads desktop GL names and calls a few of them unconditionally where GLES has none
(found by tracing every call the renderer's tests make to a name ``libGLESv2`` does not export):
``glClearDepth`` (framebuffer clears; GLES has ``glClearDepthf``), ``glClampColor`` (every
read-back; GLES never clamps unorm reads) and, at start-up, ``glPrimitiveRestartIndex``
(moderngl enables GLES's fixed restart index where it finds none). A driver may hand out a stub
that raises a GL error for such a name (Mesa does) or no pointer at all (moderngl would then call
address 0). :class:`GlesFunctions` gives those names a GLES equivalent, a no-op, or 0 for
"absent", and every other name the context's own address. The headless EGL context
(:mod:`node.render.egl_gles`) and the fullscreen SDL output (:mod:`node.outputs.kms`) share it.
"""
from __future__ import annotations

import ctypes
from typing import Callable

__all__ = ["GlesFunctions"]

_vp = ctypes.c_void_p
_CLEAR_DEPTH = ctypes.CFUNCTYPE(None, ctypes.c_double)
_NO_OP = ctypes.CFUNCTYPE(None)


class GlesFunctions:
    """moderngl's loader protocol (``load_opengl_function``) over a GLES context's ``address``.

    Parameters
    ----------
    address : callable
        ``name -> int``: the current context's function address (0 where it has none).
    """

    def __init__(self, address: Callable[[str], int]):
        self._address = address
        clear_depthf = ctypes.CFUNCTYPE(None, ctypes.c_float)(address("glClearDepthf"))
        # the ctypes callbacks live as long as this object: moderngl keeps their raw addresses
        self._substitutes: dict[str, object | None] = {
            # void glClearDepth(GLdouble) -> glClearDepthf(GLfloat): a double arrives, a float leaves
            "glClearDepth": _CLEAR_DEPTH(lambda depth: clear_depthf(depth)),
            # void glClampColor(GLenum, GLenum): GLES reads unorm colour unclamped by definition
            "glClampColor": _NO_OP(lambda: None),
            "glPrimitiveRestartIndex": None,
        }

    def load_opengl_function(self, name: str) -> int:
        """The address of GL function ``name`` (0 where the context lacks it)."""
        if name in self._substitutes:
            fn = self._substitutes[name]
            return 0 if fn is None else int(ctypes.cast(fn, _vp).value)
        return int(self._address(name) or 0)

    load = load_opengl_function  # glcontext's name for it
