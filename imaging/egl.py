"""A headless OpenGL context for the coordinator's 3D work (calibration, coverage, mesh compensation
and blending), with the same refusal everywhere when OpenGL cannot be had."""
from __future__ import annotations

from typing import Any

#: what to install when EGL gives no context (glcontext loads libGL.so.1 and libEGL.so.1)
INSTALL_HINT = "apt-get install libegl1 libgl1 libgl1-mesa-dri"


def standalone_context(error: type[Exception], needs: str) -> Any:
    """A moderngl.Context through EGL, without a window.

    Parameters
    ----------
    error : type of Exception
        What to raise when there is none (the caller's domain error), with one line saying why.
    needs : str
        Who needs it, for that line ("3D calibration", "coverage", ...).
    """
    try:
        import moderngl  # here, not at the top: OpenGL and its EGL driver are heavy, and only 3D work needs them
    except ImportError as exc:  # pragma: no cover - dependency missing
        raise error(f"{needs} needs moderngl (install shadowless with the 'node' extra)") from exc
    try:
        return moderngl.create_standalone_context(backend="egl")
    except Exception as exc:  # moderngl/glcontext raise plain Exceptions
        raise error(f"cannot create an OpenGL context through EGL ({exc}); install Mesa's EGL "
                    f"(e.g. {INSTALL_HINT}) or use a machine with a GPU") from exc
