"""A fullscreen window on an attached display (a projector on HDMI), through glfw."""
from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from node.outputs.base import Output, OutputError, Snapshots, SwapInfo, check_slot
from node.render.shaders import MIN_GL_VERSION

if TYPE_CHECKING:  # pragma: no cover
    import moderngl

    from node.render.renderer import Renderer

log = logging.getLogger(__name__)


class WindowOutput(Output):
    """A fullscreen window on an attached display (a projector on HDMI), through glfw.

    Opens at the monitor's native video mode, hides the cursor, never iconifies
    when it loses focus, and ignores Escape and close requests (the node is stopped
    by its service manager, not from the projector's keyboard). Swaps with vsync
    (swap interval 1) unless ``vsync=False``.

    glfw is an optional extra (``pip install 'shadowless[window]'``). One
    WindowOutput per process. glfw wants to be driven from one thread: create,
    use and close the output on the presenter thread.

    Parameters
    ----------
    slot : str
        The node's slot (window title, snapshot file names).
    monitor : int
        0-based index into the monitors glfw reports (0 = primary).
    snapshot_dir : Path, optional
        As for :class:`OffscreenOutput`.
    vsync : bool
        Swap interval 1 (True) or 0.
    keep_last : bool
        As for :class:`OffscreenOutput`.

    Raises
    ------
    OutputError
        glfw missing, no display (``DISPLAY`` unset or unreachable), no such monitor.
    """

    kind = "window"

    def __init__(
        self,
        *,
        slot: str,
        monitor: int = 0,
        snapshot_dir: Path | None = None,
        vsync: bool = True,
        keep_last: bool = False,
    ):
        self.slot = check_slot(slot)
        self._snap = Snapshots(slot, snapshot_dir, keep_last)
        self.vsync = vsync
        self.close_requests = 0
        self._errors: list[str] = []
        self._ctx: Any = None
        self.window: Any = None
        try:
            # Lazy and optional: glfw is the `window` extra, absent on headless installs (and a
            # test makes it unimportable); every other output works without it.
            import glfw
        except ImportError as exc:
            raise OutputError(
                "the window output needs the glfw package: pip install 'shadowless[window]'"
            ) from exc
        self._glfw = glfw
        if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
            raise OutputError(
                "no display for the window output: DISPLAY is not set; set it to the X display that drives "
                "the projector (e.g. DISPLAY=:0) or use the offscreen output"
            )
        self._initialised = False
        self._previous_error_callback = glfw.set_error_callback(self._on_glfw_error)
        if not glfw.init():
            glfw.set_error_callback(self._previous_error_callback)
            raise OutputError(
                f"cannot open the display DISPLAY={os.environ.get('DISPLAY', '')!r} ({self._last_error()}); "
                "check that the X server runs and this user may connect to it (xhost/XAUTHORITY)"
            )
        self._initialised = True
        try:
            monitors = glfw.get_monitors() or []
            if isinstance(monitor, bool) or not isinstance(monitor, int) or not 0 <= monitor < len(monitors):
                listing = ", ".join(
                    f"{i}: {self._monitor_name(m)} {glfw.get_video_mode(m).size.width}x"
                    f"{glfw.get_video_mode(m).size.height}"
                    for i, m in enumerate(monitors)
                ) or "none"
                raise OutputError(f"no monitor with index {monitor!r} on DISPLAY={os.environ.get('DISPLAY', '')!r}; "
                                  f"monitors: {listing}")
            self._monitor = monitors[monitor]
            self.monitor_index = monitor
            mode = glfw.get_video_mode(self._monitor)
            self._mode = mode
            self._size = (int(mode.size.width), int(mode.size.height))
        except BaseException:
            self._terminate()
            raise

    # -- helpers
    def _on_glfw_error(self, code: int, description: bytes) -> None:
        text = description.decode("utf-8", "replace") if isinstance(description, bytes) else str(description)
        self._errors.append(f"glfw error {code:#x}: {text}")
        del self._errors[:-8]

    def _last_error(self) -> str:
        return self._errors[-1] if self._errors else "no detail from glfw"

    def _monitor_name(self, monitor: Any) -> str:
        name = self._glfw.get_monitor_name(monitor)
        return name.decode("utf-8", "replace") if isinstance(name, bytes) else str(name)

    def _terminate(self) -> None:
        if self._initialised:
            self._initialised = False
            self._glfw.terminate()
        self._glfw.set_error_callback(self._previous_error_callback)

    # -- the Output contract
    def native_size(self) -> tuple[int, int]:
        """(width, height) of the window's framebuffer: the monitor's native mode."""
        return self._size

    def make_context(self) -> "moderngl.Context":
        if self._ctx is not None:
            return self._ctx
        if not self._initialised:
            raise OutputError("the window output is closed")
        glfw = self._glfw
        mode = self._mode
        window = None
        # OpenGL 3.3 core where the driver offers it, else 3.1 (a Raspberry Pi's V3D): the renderer
        # runs on both (node.render.shaders); 3.1 has no core profile to ask for
        for minor, core in ((3, True), (1, False)):
            glfw.default_window_hints()
            glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
            glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, minor)
            if core:
                glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
                glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
            glfw.window_hint(glfw.DOUBLEBUFFER, True)
            glfw.window_hint(glfw.AUTO_ICONIFY, False)  # a projector must not go dark when focus moves
            glfw.window_hint(glfw.RED_BITS, mode.bits.red)
            glfw.window_hint(glfw.GREEN_BITS, mode.bits.green)
            glfw.window_hint(glfw.BLUE_BITS, mode.bits.blue)
            glfw.window_hint(glfw.REFRESH_RATE, mode.refresh_rate)
            window = glfw.create_window(self._size[0], self._size[1], f"shadowless {self.slot}", self._monitor, None)
            if window:
                break
        if not window:
            raise OutputError(
                f"cannot open a fullscreen OpenGL window on monitor {self.monitor_index} ({self._last_error()}); "
                "the display's GL driver must offer OpenGL 3.1 or newer"
            )
        self.window = window
        try:
            glfw.make_context_current(window)
            glfw.swap_interval(1 if self.vsync else 0)
            glfw.set_input_mode(window, glfw.CURSOR, glfw.CURSOR_HIDDEN)
            # Lazy: moderngl is loaded only by the process that renders (see base.headless_context).
            import moderngl

            self._ctx = moderngl.create_context(require=MIN_GL_VERSION)
            fb = tuple(int(v) for v in glfw.get_framebuffer_size(window))
            if fb != self._size:  # e.g. a scaled desktop: projector pixels are framebuffer pixels
                log.info("window framebuffer is %dx%d (monitor mode %dx%d)", *fb, *self._size)
                self._size = fb
        except BaseException:
            self._destroy_window()
            raise
        glfw.poll_events()
        return self._ctx

    def prepare(self, renderer: "Renderer") -> None:
        """Blit the renderer's framebuffer to the window's back buffer (sizes must match)."""
        if self._ctx is None:
            raise OutputError("make_context() must be called before prepare()")
        if (renderer.width, renderer.height) != self._size:
            raise OutputError(
                f"the renderer is {renderer.width}x{renderer.height} but the window is {self._size[0]}x"
                f"{self._size[1]}; resize the renderer to native_size()"
            )
        self._ctx.copy_framebuffer(self._ctx.screen, renderer.framebuffer)

    def swap(self) -> None:
        self._glfw.swap_buffers(self.window)

    def after_swap(self, renderer: "Renderer", info: SwapInfo) -> None:
        self.poll()
        self._snap.handle(renderer, info)

    def poll(self) -> None:
        """Process window events (keeps the window responsive); close requests are ignored."""
        glfw = self._glfw
        glfw.poll_events()
        if self.window is not None and glfw.window_should_close(self.window):
            self.close_requests += 1
            glfw.set_window_should_close(self.window, False)
            log.warning("ignoring a request to close the projector window of %s; stop the node instead", self.slot)

    def read_back_buffer(self) -> np.ndarray:
        """(H, W, 3) uint8, row 0 at the top: the window's back buffer (what the next swap shows)."""
        w, h = self._size
        data = self._ctx.screen.read(viewport=(0, 0, w, h), components=3, alignment=1)
        return np.frombuffer(data, np.uint8).reshape(h, w, 3)[::-1].copy()

    @property
    def last_image(self) -> np.ndarray | None:
        return self._snap.last_image

    @property
    def last_info(self) -> SwapInfo | None:
        return self._snap.last_info

    def _destroy_window(self) -> None:
        if self._ctx is not None:
            self._ctx.release()
            self._ctx = None
        if self.window is not None:
            self._glfw.destroy_window(self.window)
            self.window = None

    def close(self) -> None:
        self._destroy_window()
        self._terminate()
