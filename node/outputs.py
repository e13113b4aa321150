"""Where a node's rendered frames go: offscreen, a fullscreen window, or the virtual room.

An :class:`Output` owns the GL context the node renders with (one thread owns
both). The presenter calls, for every frame, in this order and from that thread:

1. ``renderer.render(...)`` into the renderer's framebuffer (early, as soon as the frame arrives),
2. :meth:`Output.prepare` (still before the presentation time: e.g. blit to the window's back buffer),
3. :meth:`Output.swap` exactly at the presentation time (must be fast: this instant is the swap),
4. :meth:`Output.after_swap` (read-back, PNG snapshots, sending to the room: off the critical instant).

Specs understood by :func:`open_output`: ``offscreen`` (default), ``window[:MONITOR]``
and ``room://HOST:PORT``.
"""
from __future__ import annotations

import abc
import json
import logging
import os
import re
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from node.errors import NodeError

if TYPE_CHECKING:  # pragma: no cover
    import moderngl

    from node.render.renderer import Renderer

log = logging.getLogger(__name__)

#: the forms :func:`open_output` accepts, for error messages and ``--help``
SPEC_FORMS = ("offscreen", "window", "window:MONITOR (0-based monitor index)", "room://HOST:PORT")
_SLOT_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


class OutputError(NodeError, RuntimeError):
    """An output cannot be opened or used; the message says what to do."""


@dataclass(frozen=True)
class SwapInfo:
    """What was just swapped in."""

    slot: str
    frame_id: int
    tag: str
    pts_ns: int
    swap_rig_ns: int
    host_monotonic_ns: int


class Output(abc.ABC):
    kind: str = "abstract"

    @abc.abstractmethod
    def make_context(self) -> "moderngl.Context":
        """Create (once) and return the GL context the renderer must use."""

    def native_size(self) -> tuple[int, int] | None:
        """(width, height) the display wants, or None if any size will do."""
        return None

    def prepare(self, renderer: "Renderer") -> None:
        """Called after rendering, before the presentation time."""

    def swap(self) -> None:
        """Called at the presentation time. Must return quickly."""

    def after_swap(self, renderer: "Renderer", info: SwapInfo) -> None:
        """Called right after :meth:`swap`; may read back and ship the frame."""

    def poll(self) -> None:
        """Called when the presenter is idle (no frame for a while): keep a window responsive."""

    def close(self) -> None:
        """Release the context and any connection."""


# ------------------------------------------------------------------------- snapshots


def wants_snapshot(info: SwapInfo) -> bool:
    """Whether a swapped frame is one to keep for inspection (its tag starts with ``show``)."""
    return info.tag.startswith("show")


def write_snapshot(snapshot_dir: Path, image: np.ndarray, info: SwapInfo) -> Path:
    """Write what a node shows to ``snapshot_dir/<slot>.png`` and ``<slot>.json``, each atomically.

    Parameters
    ----------
    snapshot_dir : Path
        Created if missing.
    image : (H, W, 3) uint8
        What the projector receives (e.g. ``renderer.read()``), row 0 at the top, RGB.
    info : SwapInfo
        Written to the JSON file (frame_id, tag, pts and swap instants) and into the PNG's
        ``tEXt`` chunks, so a reader can check that the two files belong to the same frame.

    Returns
    -------
    Path
        The PNG written.
    """
    from node.png import atomic_write_bytes, encode_png

    folder = Path(snapshot_dir)
    folder.mkdir(parents=True, exist_ok=True)
    png = folder / f"{info.slot}.png"
    meta = {**asdict(info), "width": int(image.shape[1]), "height": int(image.shape[0]), "png": png.name}
    text = {"Software": "shadowless node", **{k: str(v) for k, v in asdict(info).items()}}
    atomic_write_bytes(png, encode_png(image, compress_level=1, filter="up", text=text))
    atomic_write_bytes(folder / f"{info.slot}.json", (json.dumps(meta, indent=1) + "\n").encode())
    return png


class _Snapshots:
    """Shared by the offscreen and window outputs: read back only when someone wants the image."""

    def __init__(self, slot: str, snapshot_dir: Path | None, keep_last: bool):
        self.slot = slot
        self.snapshot_dir = Path(snapshot_dir) if snapshot_dir is not None else None
        self.keep_last = keep_last
        #: (H, W, 3) uint8 copy of the last frame read back (None until one was), and its SwapInfo
        self.last_image: np.ndarray | None = None
        self.last_info: SwapInfo | None = None
        self.snapshots_written = 0
        self.snapshot_failures = 0

    def handle(self, renderer: "Renderer", info: SwapInfo) -> None:
        snapshot = self.snapshot_dir is not None and wants_snapshot(info)
        if not (snapshot or self.keep_last):
            return
        image = renderer.read()
        self.last_image = image.copy()
        self.last_info = info
        if snapshot:
            try:
                write_snapshot(self.snapshot_dir, image, info)
            except OSError as exc:  # inspection aid: never take the projector down over it
                self.snapshot_failures += 1
                log.warning("cannot write the snapshot of frame %d to %s: %s", info.frame_id, self.snapshot_dir, exc)
            else:
                self.snapshots_written += 1


def _check_slot(slot: str) -> str:
    if not isinstance(slot, str) or not _SLOT_NAME.fullmatch(slot):
        raise OutputError(
            f"slot name {slot!r} is not usable (letters, digits, '_', '.', '-'; e.g. r0c0): it names snapshot files"
        )
    return slot


# ------------------------------------------------------------------------- offscreen


def headless_context() -> "moderngl.Context":
    """A standalone OpenGL 3.3 context through EGL (Mesa's llvmpipe where there is no GPU)."""
    import moderngl

    try:
        return moderngl.create_standalone_context(backend="egl", require=330)
    except Exception as exc:  # moderngl/glcontext raise plain Exceptions here
        raise OutputError(
            f"cannot create a headless OpenGL 3.3 context through EGL ({exc}); install Mesa's EGL and "
            "DRI drivers (e.g. apt-get install libegl1 libgl1-mesa-dri) or the GPU vendor's EGL"
        ) from exc


class OffscreenOutput(Output):
    """Headless output: renders into an EGL context; nothing is displayed.

    Parameters
    ----------
    slot : str
        The node's slot (names the snapshot files).
    snapshot_dir : Path, optional
        If given, every frame whose tag starts with ``show`` is written to
        ``snapshot_dir/<slot>.png`` (+ ``.json``) atomically, after the swap.
    keep_last : bool
        Also read back every other swapped frame into :attr:`last_image` (tests).
        Otherwise frames are read back only for snapshots.
    """

    kind = "offscreen"

    def __init__(self, *, slot: str, snapshot_dir: Path | None = None, keep_last: bool = False):
        self.slot = _check_slot(slot)
        self._snap = _Snapshots(slot, snapshot_dir, keep_last)
        self._ctx: Any = None

    @property
    def last_image(self) -> np.ndarray | None:
        """(H, W, 3) uint8: the last frame read back after a swap (a copy), or None."""
        return self._snap.last_image

    @property
    def last_info(self) -> SwapInfo | None:
        return self._snap.last_info

    @property
    def snapshots_written(self) -> int:
        return self._snap.snapshots_written

    def make_context(self) -> "moderngl.Context":
        if self._ctx is None:
            self._ctx = headless_context()
        return self._ctx

    def after_swap(self, renderer: "Renderer", info: SwapInfo) -> None:
        self._snap.handle(renderer, info)

    def close(self) -> None:
        if self._ctx is not None:
            self._ctx.release()
            self._ctx = None


# ------------------------------------------------------------------------- window

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
        self.slot = _check_slot(slot)
        self._snap = _Snapshots(slot, snapshot_dir, keep_last)
        self.vsync = vsync
        self.close_requests = 0
        self._errors: list[str] = []
        self._ctx: Any = None
        self.window: Any = None
        try:
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
        glfw.default_window_hints()
        glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
        glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
        glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
        glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
        glfw.window_hint(glfw.DOUBLEBUFFER, True)
        glfw.window_hint(glfw.AUTO_ICONIFY, False)  # a projector must not go dark when focus moves
        glfw.window_hint(glfw.RED_BITS, mode.bits.red)
        glfw.window_hint(glfw.GREEN_BITS, mode.bits.green)
        glfw.window_hint(glfw.BLUE_BITS, mode.bits.blue)
        glfw.window_hint(glfw.REFRESH_RATE, mode.refresh_rate)
        window = glfw.create_window(self._size[0], self._size[1], f"shadowless {self.slot}", self._monitor, None)
        if not window:
            raise OutputError(
                f"cannot open a fullscreen OpenGL 3.3 window on monitor {self.monitor_index} ({self._last_error()}); "
                "the display's GL driver must offer OpenGL 3.3 core"
            )
        self.window = window
        try:
            glfw.make_context_current(window)
            glfw.swap_interval(1 if self.vsync else 0)
            glfw.set_input_mode(window, glfw.CURSOR, glfw.CURSOR_HIDDEN)
            import moderngl

            self._ctx = moderngl.create_context(require=330)
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


# ------------------------------------------------------------------------- factory


def open_output(spec: str, *, slot: str, snapshot_dir: Path | None = None) -> Output:
    """Open the output named by ``spec`` for node ``slot``.

    ``spec`` is one of :data:`SPEC_FORMS`: ``offscreen`` (headless; the default when
    empty), ``window`` or ``window:MONITOR`` (fullscreen on monitor MONITOR, 0-based),
    or ``room://HOST:PORT`` (frames go to the virtual room).

    ``snapshot_dir``: if given, every frame whose tag starts with ``show`` is
    also written to ``snapshot_dir/<slot>.png`` (atomically) for inspection.

    Raises
    ------
    OutputError
        Unknown or malformed spec (the message lists the accepted forms), or the
        output cannot be opened.
    """
    if not isinstance(spec, str):
        raise OutputError(f"output spec must be a string, got {type(spec).__name__}")
    text = spec.strip()
    forms = ", ".join(SPEC_FORMS)
    if text in ("", "offscreen"):
        return OffscreenOutput(slot=slot, snapshot_dir=snapshot_dir)
    if text == "window" or text.startswith("window:"):
        index_text = text.partition(":")[2] if ":" in text else "0"
        if not index_text.isdigit():
            raise OutputError(f"output {spec!r}: the monitor must be a 0-based index like window:1 (accepted: {forms})")
        return WindowOutput(slot=slot, monitor=int(index_text), snapshot_dir=snapshot_dir)
    if text.startswith("room://"):
        _check_slot(slot)
        host, sep, port = text[len("room://") :].rpartition(":")
        if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise OutputError(f"output {spec!r}: expected room://HOST:PORT, e.g. room://127.0.0.1:50070")
        from node.room_output import RoomOutput

        return RoomOutput(text, slot=slot, snapshot_dir=snapshot_dir)
    raise OutputError(f"unknown output {spec!r}; accepted: {forms}")
