"""Which OpenGL a headless node renders with: desktop OpenGL 3.1+ where EGL offers it, else
OpenGL ES 3.0+, chosen once when the context is made.

``auto`` (the default) asks glcontext's EGL backend for desktop OpenGL 3.1+ first, as every
node did before; where the display refuses it (EGL binds no desktop OpenGL API, has no
configuration or context for it, or offers one older than 3.1: Mali and Adreno vendor drivers,
some Mesa drivers) it makes an OpenGL ES 3 context instead (:mod:`node.render.egl_gles`). A
failure of EGL itself (no library, no display, eglInitialize) is reported as it is: OpenGL ES
would fail the same way. ``gl`` and ``gles`` force one API (``shadowless node --gl``, or the
``SHADOWLESS_GL`` environment variable, which the node's presenter process inherits).
"""
from __future__ import annotations

import logging
import os
from typing import Any

from node.render.shaders import MIN_GL_VERSION

__all__ = ["GL_CHOICES", "GL_ENV", "ContextUnavailable", "create_headless_context", "gl_choice"]

log = logging.getLogger(__name__)

GL_CHOICES = ("auto", "gl", "gles")
GL_ENV = "SHADOWLESS_GL"

# glcontext's EGL backend's messages when the display does not offer desktop OpenGL 3.1+ (as
# opposed to EGL failing as a whole), and moderngl's when the context it got is older.
_API_REFUSED = ("eglBindAPI failed", "eglChooseConfig failed", "eglCreateContext failed", "Requested OpenGL version")
# glcontext's message when the desktop GL library itself is missing (a system with libEGL and
# libGLESv2 but no libGL.so.1): OpenGL ES may still be had there.
_NO_LIBGL = " not loaded"


class ContextUnavailable(RuntimeError):
    """No headless context could be made; the message says what each API answered."""


def gl_choice(value: str | None = None) -> str:
    """``value``, else ``$SHADOWLESS_GL``, else ``auto``; checked against :data:`GL_CHOICES`."""
    choice = (value if value is not None else os.environ.get(GL_ENV, "")).strip().lower() or "auto"
    if choice not in GL_CHOICES:
        raise ContextUnavailable(f"the OpenGL choice (--gl, {GL_ENV}) must be one of {', '.join(GL_CHOICES)}, "
                                 f"got {choice!r}")
    return choice


def _desktop() -> Any:
    import moderngl  # lazy: only the process that renders loads GL

    return moderngl.create_standalone_context(backend="egl", require=MIN_GL_VERSION)


def _gles() -> Any:
    from node.render.egl_gles import create_gles_context

    return create_gles_context()


def create_headless_context(choice: str | None = None) -> Any:
    """A moderngl.Context without a window, current on this thread (see the module docstring).

    Parameters
    ----------
    choice : {"auto", "gl", "gles"}, optional
        Default: ``$SHADOWLESS_GL``, else ``auto``.

    Raises
    ------
    ContextUnavailable
        Neither API could be had; the message carries each API's error.
    """
    choice = gl_choice(choice)
    if choice == "gles":
        try:
            return _gles()
        except Exception as exc:  # EglError, or moderngl refusing the context
            raise ContextUnavailable(f"OpenGL ES 3.0+: {exc}") from exc
    try:
        return _desktop()
    except Exception as exc:  # moderngl/glcontext raise plain Exceptions here
        desktop_error = exc
        if choice == "gl" or not (str(exc).startswith(_API_REFUSED) or str(exc).endswith(_NO_LIBGL)):
            raise ContextUnavailable(f"desktop OpenGL 3.1+: {exc}") from exc
    try:
        ctx = _gles()
    except Exception as exc:
        raise ContextUnavailable(f"desktop OpenGL 3.1+: {desktop_error}; OpenGL ES 3.0+: {exc}") from exc
    log.info("desktop OpenGL 3.1+ is not offered here (%s): rendering with OpenGL ES", desktop_error)
    return ctx
