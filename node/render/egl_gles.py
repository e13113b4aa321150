"""A headless OpenGL ES 3 context through EGL, made with ctypes, for moderngl to attach to.

moderngl and glcontext create desktop OpenGL contexts only, but many edge GPUs' drivers offer
OpenGL ES alone (Mali and Adreno vendor drivers), or a desktop GL older than the renderer needs
next to a GLES 3. moderngl attaches to any context that is current on the calling thread, given an
object that loads GL functions by name (``load_opengl_function``) and is released with the moderngl
context (``release``). :class:`GlesContext` is that object: it opens the same EGL display
glcontext's ``egl`` backend opens (the first EGL device, or ``GLCONTEXT_DEVICE_INDEX``), creates an
OpenGL ES 3.x context on it without a window (surfaceless where ``EGL_KHR_surfaceless_context``
is offered, otherwise on a 1x1 pbuffer), makes it current, and destroys it on :meth:`release`.

Only libEGL is needed (``libEGL.so.1``, Mesa's or a vendor's); function pointers come from
``eglGetProcAddress`` (EGL 1.5, or ``EGL_KHR_get_all_proc_addresses``, resolves core GL ES
functions too), else from ``libGLESv2.so.2`` where an older EGL does not.

moderngl loads desktop GL names and calls a few that GLES lacks; the loader gives those a GLES
equivalent, a no-op, or "absent" (:class:`node.render.gles_functions.GlesFunctions`).
"""
from __future__ import annotations

import ctypes
import os
from typing import Any

from node.render.gles_functions import GlesFunctions

__all__ = ["EglError", "GlesContext", "create_gles_context"]

# EGL enums (EGL 1.5 and the EXT/KHR extensions used here)
_EGL_SUCCESS = 0x3000
_EGL_NONE = 0x3038
_EGL_EXTENSIONS = 0x3055
_EGL_CLIENT_APIS = 0x308D
_EGL_SURFACE_TYPE = 0x3033
_EGL_PBUFFER_BIT = 0x0001
_EGL_RENDERABLE_TYPE = 0x3040
_EGL_OPENGL_ES3_BIT = 0x0040
_EGL_RED_SIZE, _EGL_GREEN_SIZE, _EGL_BLUE_SIZE = 0x3024, 0x3023, 0x3022
_EGL_DONT_CARE = -1
_EGL_WIDTH, _EGL_HEIGHT = 0x3057, 0x3056
_EGL_OPENGL_ES_API = 0x30A0
_EGL_CONTEXT_MAJOR_VERSION = 0x3098
_EGL_CONTEXT_MINOR_VERSION = 0x30FB
_EGL_PLATFORM_DEVICE_EXT = 0x313F
_EGL_DEFAULT_DISPLAY = None

_EGL_ERRORS = {
    0x3001: "EGL_NOT_INITIALIZED", 0x3002: "EGL_BAD_ACCESS", 0x3003: "EGL_BAD_ALLOC", 0x3004: "EGL_BAD_ATTRIBUTE",
    0x3005: "EGL_BAD_CONFIG", 0x3006: "EGL_BAD_CONTEXT", 0x3007: "EGL_BAD_CURRENT_SURFACE",
    0x3008: "EGL_BAD_DISPLAY", 0x3009: "EGL_BAD_MATCH", 0x300A: "EGL_BAD_NATIVE_PIXMAP",
    0x300B: "EGL_BAD_NATIVE_WINDOW", 0x300C: "EGL_BAD_PARAMETER", 0x300D: "EGL_BAD_SURFACE",
    0x300E: "EGL_CONTEXT_LOST",
}

_vp = ctypes.c_void_p
_i32 = ctypes.c_int32


class EglError(RuntimeError):
    """EGL refused a step; the message names the step and EGL's error code."""


def _attribs(*pairs: int) -> Any:
    """An EGL attribute list (EGLint pairs, then EGL_NONE)."""
    return (_i32 * (len(pairs) + 1))(*pairs, _EGL_NONE)


class _Egl:
    """The few libEGL entry points used, with their C signatures."""

    def __init__(self, libegl: str):
        try:
            lib = ctypes.CDLL(libegl)
        except OSError as exc:
            raise EglError(f"cannot load {libegl} ({exc})") from None
        self.lib = lib
        sig = {
            "eglGetError": (_i32, []),
            "eglGetProcAddress": (_vp, [ctypes.c_char_p]),
            "eglQueryString": (ctypes.c_char_p, [_vp, _i32]),
            "eglGetDisplay": (_vp, [_vp]),
            "eglInitialize": (ctypes.c_uint, [_vp, ctypes.POINTER(_i32), ctypes.POINTER(_i32)]),
            "eglChooseConfig": (ctypes.c_uint, [_vp, ctypes.POINTER(_i32), ctypes.POINTER(_vp), _i32,
                                                ctypes.POINTER(_i32)]),
            "eglBindAPI": (ctypes.c_uint, [ctypes.c_uint]),
            "eglCreateContext": (_vp, [_vp, _vp, _vp, ctypes.POINTER(_i32)]),
            "eglCreatePbufferSurface": (_vp, [_vp, _vp, ctypes.POINTER(_i32)]),
            "eglMakeCurrent": (ctypes.c_uint, [_vp, _vp, _vp, _vp]),
            "eglGetCurrentContext": (_vp, []),
            "eglGetCurrentDisplay": (_vp, []),
            "eglGetCurrentSurface": (_vp, [_i32]),
            "eglDestroyContext": (ctypes.c_uint, [_vp, _vp]),
            "eglDestroySurface": (ctypes.c_uint, [_vp, _vp]),
        }
        for name, (restype, argtypes) in sig.items():
            try:
                fn = getattr(lib, name)
            except AttributeError:
                raise EglError(f"{libegl} has no {name}") from None
            fn.restype, fn.argtypes = restype, argtypes
            setattr(self, name, fn)

    def error(self, step: str) -> EglError:
        code = int(self.eglGetError())
        return EglError(f"{step} failed ({_EGL_ERRORS.get(code, hex(code))})")

    def proc(self, name: str, restype: Any, *argtypes: Any) -> Any:
        """An EGL extension function, or None where the library lacks it."""
        address = self.eglGetProcAddress(name.encode())
        return ctypes.CFUNCTYPE(restype, *argtypes)(address) if address else None

    def extensions(self, display: Any) -> set[str]:
        text = self.eglQueryString(display, _EGL_EXTENSIONS)
        return set((text or b"").decode("ascii", "replace").split())


def _open_display(egl: _Egl, device_index: int) -> Any:
    """The EGL display of device ``device_index`` (as glcontext's egl backend picks it), or the
    default display where the library cannot enumerate devices; initialised."""
    display = None
    client = egl.extensions(None)  # client extensions (EGL_EXT_client_extensions); empty if unsupported
    if "EGL_EXT_platform_device" in client and client & {"EGL_EXT_device_enumeration", "EGL_EXT_device_base"}:
        query = egl.proc("eglQueryDevicesEXT", ctypes.c_uint, _i32, ctypes.POINTER(_vp), ctypes.POINTER(_i32))
        platform = egl.proc("eglGetPlatformDisplayEXT", _vp, ctypes.c_uint, _vp, ctypes.POINTER(_i32))
        if query is not None and platform is not None:
            devices = (_vp * 16)()
            count = _i32(0)
            if not query(16, devices, ctypes.byref(count)):
                raise egl.error("eglQueryDevicesEXT")
            if not 0 <= device_index < count.value:
                raise EglError(f"EGL device {device_index} was asked for (GLCONTEXT_DEVICE_INDEX), "
                               f"but there are {count.value}")
            display = platform(_EGL_PLATFORM_DEVICE_EXT, devices[device_index], None)
            if not display:
                raise egl.error("eglGetPlatformDisplayEXT")
    if not display:
        display = egl.eglGetDisplay(_EGL_DEFAULT_DISPLAY)
        if not display:
            raise egl.error("eglGetDisplay")
    major, minor = _i32(0), _i32(0)
    if not egl.eglInitialize(display, ctypes.byref(major), ctypes.byref(minor)):
        raise egl.error("eglInitialize")
    return display


class GlesContext:
    """An OpenGL ES 3.x context, current on the thread that made it; moderngl's loader for it.

    Parameters
    ----------
    device_index : int, optional
        Which EGL device (default: ``GLCONTEXT_DEVICE_INDEX`` or 0, as glcontext's egl backend).
    libegl : str
        The EGL library to load.

    Raises
    ------
    EglError
        The display offers no OpenGL ES 3 (the message names the refused step).
    """

    def __init__(self, *, device_index: int | None = None, libegl: str = "libEGL.so.1"):
        if device_index is None:
            device_index = int(os.environ.get("GLCONTEXT_DEVICE_INDEX") or 0)
        egl = _Egl(libegl)
        self._egl = egl
        self._display = _open_display(egl, device_index)
        apis = (egl.eglQueryString(self._display, _EGL_CLIENT_APIS) or b"").decode("ascii", "replace").split()
        if "OpenGL_ES" not in apis:
            raise EglError(f"this EGL display offers no OpenGL ES (its client APIs: {' '.join(apis) or 'none'})")
        surfaceless = "EGL_KHR_surfaceless_context" in egl.extensions(self._display)
        config, count = _vp(), _i32(0)
        wanted = _attribs(_EGL_RENDERABLE_TYPE, _EGL_OPENGL_ES3_BIT,
                          _EGL_SURFACE_TYPE, _EGL_DONT_CARE if surfaceless else _EGL_PBUFFER_BIT,
                          _EGL_RED_SIZE, 8, _EGL_GREEN_SIZE, 8, _EGL_BLUE_SIZE, 8)
        if not egl.eglChooseConfig(self._display, wanted, ctypes.byref(config), 1, ctypes.byref(count)):
            raise egl.error("eglChooseConfig")
        if count.value < 1:
            raise EglError("this EGL display has no OpenGL ES 3 configuration (EGL_OPENGL_ES3_BIT)")
        if not egl.eglBindAPI(_EGL_OPENGL_ES_API):
            raise egl.error("eglBindAPI(EGL_OPENGL_ES_API)")
        # 3.0 is the floor; drivers hand out the newest version compatible with it (3.1, 3.2)
        self._context = egl.eglCreateContext(self._display, config, None,
                                             _attribs(_EGL_CONTEXT_MAJOR_VERSION, 3, _EGL_CONTEXT_MINOR_VERSION, 0))
        if not self._context:
            raise egl.error("eglCreateContext(OpenGL ES 3.0)")
        self._surface = None
        if not surfaceless:
            self._surface = egl.eglCreatePbufferSurface(self._display, config, _attribs(_EGL_WIDTH, 1, _EGL_HEIGHT, 1))
            if not self._surface:
                err = egl.error("eglCreatePbufferSurface")
                egl.eglDestroyContext(self._display, self._context)
                raise err
        self._previous: list[tuple[Any, Any, Any, Any]] = []
        self._released = False
        try:
            self._make_current()
        except EglError:
            self.release()
            raise
        self._gles_lib: Any = None
        self._functions = GlesFunctions(self._address)

    def _make_current(self) -> None:
        egl = self._egl
        if not egl.eglMakeCurrent(self._display, self._surface, self._surface, self._context):
            raise egl.error("eglMakeCurrent")

    def _address(self, name: str) -> int:
        address = self._egl.eglGetProcAddress(name.encode())
        if not address:  # EGL < 1.5 without EGL_KHR_get_all_proc_addresses: core functions by symbol
            if self._gles_lib is None:
                try:
                    self._gles_lib = ctypes.CDLL("libGLESv2.so.2")
                except OSError:
                    self._gles_lib = False
            if self._gles_lib:
                address = ctypes.cast(getattr(self._gles_lib, name, None) or 0, _vp).value
        return int(address or 0)

    # ------------------------------------------------------------------ moderngl's loader protocol

    def load_opengl_function(self, name: str) -> int:
        """The address of GL function ``name`` (0 where the context lacks it)."""
        return self._functions.load_opengl_function(name)

    load = load_opengl_function  # glcontext's name for it

    def __enter__(self) -> "GlesContext":
        egl = self._egl
        self._previous.append((egl.eglGetCurrentDisplay(), egl.eglGetCurrentSurface(0x3059),
                               egl.eglGetCurrentSurface(0x305A), egl.eglGetCurrentContext()))
        self._make_current()
        return self

    def __exit__(self, *exc: object) -> None:
        display, draw, read, context = self._previous.pop()
        if display:
            self._egl.eglMakeCurrent(display, draw, read, context)
        else:
            self._egl.eglMakeCurrent(self._display, None, None, None)

    def release(self) -> None:
        """Destroy the context (and its pbuffer); idempotent. The display stays initialised: it is
        shared with every other EGL context of the process (glcontext's too), as glcontext leaves it."""
        if self._released:
            return
        self._released = True
        egl = self._egl
        if egl.eglGetCurrentContext() == self._context:
            egl.eglMakeCurrent(self._display, None, None, None)
        egl.eglDestroyContext(self._display, self._context)
        if self._surface:
            egl.eglDestroySurface(self._display, self._surface)


def create_gles_context(*, device_index: int | None = None) -> Any:
    """A moderngl.Context on a new headless OpenGL ES 3.x context (current on this thread).

    ``ctx.release()`` destroys the EGL context too (moderngl calls :meth:`GlesContext.release`).
    Raises :class:`EglError` where EGL offers no OpenGL ES 3.
    """
    import moderngl  # lazy, as everywhere in the renderer: only a process that renders loads GL

    gles = GlesContext(device_index=device_index)
    try:
        moderngl.init_context(gles)
        return moderngl.get_context()
    except BaseException:
        gles.release()
        raise
