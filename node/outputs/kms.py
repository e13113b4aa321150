"""A fullscreen output without X: SDL2 on the console's KMS/DRM, as a headless edge device drives
its HDMI port.

SDL2 (through PySDL2 and the system's libSDL2, ``apt-get install libsdl2-2.0-0``) opens the display
with its KMSDRM video driver: no X server, no desktop session, no XAUTHORITY; the node's user needs
the ``video`` and ``render`` groups. The same code runs with any SDL video driver
(``SDL_VIDEODRIVER=x11`` under Xvfb is how the tests exercise it). moderngl renders on SDL's
current context, whose functions it loads through ``SDL_GL_GetProcAddress``, so EGL (KMSDRM) and
GLX (X11) need nothing of their own.

The display is chosen by index (``kms:1``) or by connector name (``kms:HDMI-A-2``): SDL's display
names first, else the connected connectors the kernel lists under ``/sys/class/drm`` (in the order
of their connector ids, which is SDL's order). Escape and quit requests are ignored: the node is
stopped by its service manager, not from the projector's keyboard.
"""
from __future__ import annotations

import ctypes
import logging
import os
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from node.outputs.base import Output, OutputError, Snapshots, SwapInfo, check_slot
from node.render.context import ContextUnavailable, gl_choice
from node.render.gles_functions import GlesFunctions

if TYPE_CHECKING:  # pragma: no cover
    import moderngl

    from node.render.renderer import Renderer

log = logging.getLogger(__name__)

#: contexts asked of SDL, best first: (major, minor, profile) with profile "core" (desktop 3.3),
#: "" (desktop 3.1: a Raspberry Pi's V3D) or "es" (OpenGL ES 3.0+: Mali and Adreno drivers)
GL_VERSIONS = ((3, 3, "core"), (3, 1, ""), (3, 0, "es"))


def gl_versions(choice: str) -> tuple[tuple[int, int, str], ...]:
    """The entries of :data:`GL_VERSIONS` that the node's OpenGL choice (``auto``, ``gl``, ``gles``:
    ``--gl`` / ``$SHADOWLESS_GL``, see :func:`node.render.context.gl_choice`) allows."""
    if choice == "auto":
        return GL_VERSIONS
    return tuple(v for v in GL_VERSIONS if (v[2] == "es") == (choice == "gles"))


def drm_connectors(root: Path = Path("/sys/class/drm")) -> list[str]:
    """The kernel's connected connectors (e.g. ``HDMI-A-1``), ordered by connector id when the
    kernel says it (``connector_id``), else by name."""
    found = []
    for entry in root.glob("card*-*"):
        try:
            if (entry / "status").read_text().strip() != "connected":
                continue
        except OSError:
            continue
        try:
            key = int((entry / "connector_id").read_text())
        except (OSError, ValueError):
            key = 1 << 30
        found.append((key, entry.name.split("-", 1)[1]))
    return [name for _, name in sorted(found)]


class _SdlLoader:
    """moderngl's loader interface over ``SDL_GL_GetProcAddress`` (the current context's); on
    OpenGL ES with the substitutes moderngl needs there (:class:`GlesFunctions`)."""

    def __init__(self, sdl2: Any, *, gles: bool = False):
        get = sdl2.SDL_GL_GetProcAddress
        address = lambda name: get(name.encode()) or 0  # noqa: E731
        self.load_opengl_function = GlesFunctions(address).load_opengl_function if gles else address

    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        return None

    def release(self) -> None:
        return None


class KmsOutput(Output):
    """A fullscreen SDL2 window on one display, KMS/DRM by default (see the module docstring).

    Parameters
    ----------
    slot : str
        The node's slot (snapshot file names, window title).
    display : str
        ``""`` or ``"0"`` for the first display, an index, or a connector name.
    snapshot_dir, keep_last :
        As for :class:`node.outputs.offscreen.OffscreenOutput`.
    vsync : bool
        Swap interval 1 (True) or 0.
    video_driver : str, optional
        SDL video driver; default ``$SDL_VIDEODRIVER``, else ``KMSDRM``.

    Raises
    ------
    OutputError
        PySDL2 or libSDL2 missing, the display cannot be opened (no permission on /dev/dri, X
        running on it), no such display.
    """

    kind = "kms"

    def __init__(self, *, slot: str, display: str = "", snapshot_dir: Path | None = None, vsync: bool = True,
                 keep_last: bool = False, video_driver: str | None = None):
        self.slot = check_slot(slot)
        self._snap = Snapshots(slot, snapshot_dir, keep_last)
        self.vsync = vsync
        self.quit_requests = 0
        self._ctx: Any = None
        self._gl: Any = None
        self.window: Any = None
        self.gl_version = ""
        self.gles = False             # the context is OpenGL ES (read-backs in RGBA)
        try:
            # PySDL2 finds the system's libSDL2 (or the pysdl2-dll wheel's); only this output needs it
            import sdl2
        except ImportError as exc:
            raise OutputError("the kms output needs PySDL2 and libSDL2: pip install 'shadowless[kms]' and "
                              "apt-get install libsdl2-2.0-0") from exc
        except Exception as exc:  # PySDL2 raises a plain RuntimeError when libSDL2 is missing
            raise OutputError(f"the kms output cannot load libSDL2 ({exc}); apt-get install libsdl2-2.0-0") from exc
        self._sdl = sdl2
        driver = video_driver or os.environ.get("SDL_VIDEODRIVER") or "KMSDRM"
        sdl2.SDL_SetHint(sdl2.SDL_HINT_VIDEODRIVER, driver.encode())
        sdl2.SDL_SetHint(b"SDL_VIDEO_MINIMIZE_ON_FOCUS_LOSS", b"0")   # a projector must not go dark
        if sdl2.SDL_InitSubSystem(sdl2.SDL_INIT_VIDEO) != 0:
            raise OutputError(f"cannot open the display with SDL's {driver} driver ({self._error()}); for KMSDRM "
                              "the node's user needs the video and render groups and no X server may hold the "
                              "display; for X11 set DISPLAY")
        self.driver = (sdl2.SDL_GetCurrentVideoDriver() or b"?").decode()
        try:
            self.display_index = self._pick_display(display)
            mode = sdl2.SDL_DisplayMode()
            if sdl2.SDL_GetDesktopDisplayMode(self.display_index, ctypes.byref(mode)) != 0:
                raise OutputError(f"cannot read display {self.display_index}'s mode ({self._error()})")
            self._size = (int(mode.w), int(mode.h))
            self.refresh_hz = int(mode.refresh_rate)
        except BaseException:
            sdl2.SDL_QuitSubSystem(sdl2.SDL_INIT_VIDEO)
            raise
        log.info("kms output: SDL %s driver, display %d %s %dx%d@%d Hz", self.driver, self.display_index,
                 self.display_name, *self._size, self.refresh_hz)

    # -- helpers
    def _error(self) -> str:
        return (self._sdl.SDL_GetError() or b"").decode("utf-8", "replace") or "no detail from SDL"

    def _display_names(self) -> list[str]:
        sdl2 = self._sdl
        return [(sdl2.SDL_GetDisplayName(i) or b"").decode("utf-8", "replace")
                for i in range(max(0, sdl2.SDL_GetNumVideoDisplays()))]

    def _pick_display(self, display: str) -> int:
        names = self._display_names()
        if not names:
            raise OutputError(f"SDL's {self.driver} driver found no display ({self._error()}); is a projector "
                              "connected and switched on?")
        connectors = drm_connectors() if self.driver.upper() == "KMSDRM" else []
        text = display.strip()
        if text == "":
            index = 0
        elif re.fullmatch(r"\d+", text):
            index = int(text)
        elif text in names:
            index = names.index(text)
        elif text in connectors and connectors.index(text) < len(names):
            index = connectors.index(text)
        else:
            index = -1
        if not 0 <= index < len(names):
            listing = ", ".join(f"{i}: {n}" + (f" ({connectors[i]})" if i < len(connectors) else "")
                                for i, n in enumerate(names))
            raise OutputError(f"no display {display!r} for the kms output; displays: {listing}")
        self.display_name = names[index] + (f" ({connectors[index]})" if index < len(connectors) else "")
        return index

    # -- the Output contract
    def native_size(self) -> tuple[int, int]:
        """(width, height) of the display's current mode (the framebuffer's once opened)."""
        return self._size

    def make_context(self) -> "moderngl.Context":
        if self._ctx is not None:
            return self._ctx
        sdl2 = self._sdl
        where = sdl2.SDL_WINDOWPOS_UNDEFINED_DISPLAY(self.display_index)
        flags = sdl2.SDL_WINDOW_OPENGL | sdl2.SDL_WINDOW_FULLSCREEN
        errors = []
        try:
            choice = gl_choice()
        except ContextUnavailable as exc:
            raise OutputError(str(exc)) from None
        for major, minor, profile in gl_versions(choice):
            sdl2.SDL_GL_ResetAttributes()
            sdl2.SDL_GL_SetAttribute(sdl2.SDL_GL_CONTEXT_MAJOR_VERSION, major)
            sdl2.SDL_GL_SetAttribute(sdl2.SDL_GL_CONTEXT_MINOR_VERSION, minor)
            if profile:
                mask = sdl2.SDL_GL_CONTEXT_PROFILE_CORE if profile == "core" else sdl2.SDL_GL_CONTEXT_PROFILE_ES
                sdl2.SDL_GL_SetAttribute(sdl2.SDL_GL_CONTEXT_PROFILE_MASK, mask)
            sdl2.SDL_GL_SetAttribute(sdl2.SDL_GL_DOUBLEBUFFER, 1)
            for attr in (sdl2.SDL_GL_RED_SIZE, sdl2.SDL_GL_GREEN_SIZE, sdl2.SDL_GL_BLUE_SIZE):
                sdl2.SDL_GL_SetAttribute(attr, 8)   # SDL's default minimum is 3 bits: a projector needs 8
            # No depth buffer on the screen: it only receives the renderer's blit, and a blit whose
            # depth formats differ (the visual's 32-bit vs the renderer's 24-bit) fails as a whole.
            sdl2.SDL_GL_SetAttribute(sdl2.SDL_GL_DEPTH_SIZE, 0)
            name = f"{'OpenGL ES ' if profile == 'es' else ''}{major}.{minor}"
            window = sdl2.SDL_CreateWindow(f"shadowless {self.slot}".encode(), where, where, *self._size, flags)
            if not window:
                errors.append(f"{name}: {self._error()}")
                continue
            gl = sdl2.SDL_GL_CreateContext(window)
            if not gl:
                errors.append(f"{name}: {self._error()}")
                sdl2.SDL_DestroyWindow(window)
                continue
            self.window, self._gl, self.gl_version, self.gles = window, gl, name, profile == "es"
            break
        else:
            wanted = {"auto": "OpenGL 3.1+ or OpenGL ES 3.0+", "gl": "OpenGL 3.1+", "gles": "OpenGL ES 3.0+"}[choice]
            raise OutputError(f"cannot open a fullscreen {wanted} surface on display {self.display_index} "
                              f"({'; '.join(errors)}); the GPU driver must offer {wanted}")
        try:
            sdl2.SDL_GL_MakeCurrent(self.window, self._gl)
            if sdl2.SDL_GL_SetSwapInterval(1 if self.vsync else 0) != 0 and self.vsync:
                log.warning("the kms output could not turn vsync on (%s): swaps may tear", self._error())
            sdl2.SDL_ShowCursor(sdl2.SDL_DISABLE)
            # Lazy: moderngl is loaded only by the process that renders (see base.headless_context).
            import moderngl

            moderngl.init_context(_SdlLoader(sdl2, gles=self.gles))
            self._ctx = moderngl.get_context()
            w, h = ctypes.c_int(), ctypes.c_int()
            sdl2.SDL_GL_GetDrawableSize(self.window, ctypes.byref(w), ctypes.byref(h))
            if (w.value, h.value) != self._size and w.value > 0:
                log.info("kms drawable is %dx%d (display mode %dx%d)", w.value, h.value, *self._size)
                self._size = (w.value, h.value)
        except BaseException:
            self._destroy_window()
            raise
        self.poll()
        return self._ctx

    def prepare(self, renderer: "Renderer") -> None:
        """Blit the renderer's framebuffer to the back buffer (sizes must match)."""
        if self._ctx is None:
            raise OutputError("make_context() must be called before prepare()")
        if (renderer.width, renderer.height) != self._size:
            raise OutputError(f"the renderer is {renderer.width}x{renderer.height} but the display is "
                              f"{self._size[0]}x{self._size[1]}; resize the renderer to native_size()")
        self._ctx.copy_framebuffer(self._ctx.screen, renderer.framebuffer)

    def swap(self) -> None:
        self._sdl.SDL_GL_SwapWindow(self.window)

    def after_swap(self, renderer: "Renderer", info: SwapInfo) -> None:
        self.poll()
        self._snap.handle(renderer, info)

    def poll(self) -> None:
        """Drain SDL's events (keeps the display responsive); quit requests are counted, not obeyed."""
        sdl2 = self._sdl
        event = sdl2.SDL_Event()
        while sdl2.SDL_PollEvent(ctypes.byref(event)):
            if event.type == sdl2.SDL_QUIT:
                self.quit_requests += 1
                log.warning("ignoring a quit request on the projector of %s; stop the node instead", self.slot)

    def read_back_buffer(self) -> np.ndarray:
        """(H, W, 3) uint8, row 0 at the top: the back buffer (what the next swap shows)."""
        w, h = self._size
        n = 4 if self.gles else 3      # GLES reads RGBA only
        data = self._ctx.screen.read(viewport=(0, 0, w, h), components=n, alignment=1)
        return np.frombuffer(data, np.uint8).reshape(h, w, n)[::-1, :, :3].copy()

    @property
    def last_image(self) -> np.ndarray | None:
        return self._snap.last_image

    @property
    def last_info(self) -> SwapInfo | None:
        return self._snap.last_info

    def _destroy_window(self) -> None:
        sdl2 = self._sdl
        if self._ctx is not None:
            self._ctx.release()
            self._ctx = None
        if self._gl is not None:
            sdl2.SDL_GL_DeleteContext(self._gl)
            self._gl = None
        if self.window is not None:
            sdl2.SDL_DestroyWindow(self.window)
            self.window = None

    def close(self) -> None:
        if self._sdl is None:
            return
        self._destroy_window()
        self._sdl.SDL_QuitSubSystem(self._sdl.SDL_INIT_VIDEO)
        self._sdl = None
