"""node/outputs/: the offscreen output (snapshots), the fullscreen window (under Xvfb) and the factory."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import types
from pathlib import Path

import cv2
import numpy as np
import pytest

import node.outputs as outputs
from node.outputs import OffscreenOutput, OutputError, SwapInfo, WindowOutput, open_output
from node.image_files import decode_png_text, read_png
from node.render import Renderer

REPO = Path(__file__).resolve().parents[2]


def info(frame_id: int, tag: str, slot: str = "r1c2") -> SwapInfo:
    return SwapInfo(slot=slot, frame_id=frame_id, tag=tag, pts_ns=1_000 * frame_id, swap_rig_ns=1_000 * frame_id + 7,
                    host_monotonic_ns=5_000 * frame_id)


class CountingReads:
    """Wraps a renderer and counts read-backs (after_swap only needs ``read``)."""

    def __init__(self, renderer: Renderer):
        self.renderer = renderer
        self.reads = 0

    def read(self) -> np.ndarray:
        self.reads += 1
        return self.renderer.read()


# ----------------------------------------------------------------------------- offscreen


def test_offscreen_is_the_default_and_owns_one_context():
    for spec in ("offscreen", "", "  offscreen "):
        out = open_output(spec, slot="r0c0")
        try:
            assert isinstance(out, OffscreenOutput) and out.kind == "offscreen"
            assert out.native_size() is None
            ctx = out.make_context()
            assert out.make_context() is ctx and ctx.version_code >= 330
        finally:
            out.close()
            out.close()  # idempotent


def test_offscreen_snapshots_show_frames_atomically(tmp_path):
    snap = tmp_path / "snaps"  # created on first use
    out = open_output("offscreen", slot="r1c2", snapshot_dir=snap)
    r = Renderer(out.make_context(), 64, 48)
    try:
        image = np.random.default_rng(3).integers(0, 256, (48, 64, 3), dtype=np.uint8)
        r.upload("img", image)
        r.render("img", space="projector")
        counting = CountingReads(r)
        out.prepare(r)
        out.swap()
        out.after_swap(counting, info(7, "show:test"))
        assert counting.reads == 1 and out.snapshots_written == 1
        png = snap / "r1c2.png"
        np.testing.assert_array_equal(read_png(png), image)
        np.testing.assert_array_equal(cv2.imread(str(png), cv2.IMREAD_UNCHANGED)[:, :, ::-1], image)  # libpng agrees
        meta = json.loads((snap / "r1c2.json").read_text())
        assert meta == {"slot": "r1c2", "frame_id": 7, "tag": "show:test", "pts_ns": 7000, "swap_rig_ns": 7007,
                        "host_monotonic_ns": 35000, "width": 64, "height": 48, "png": "r1c2.png"}
        assert decode_png_text(png.read_bytes())["frame_id"] == "7"
        np.testing.assert_array_equal(out.last_image, image)
        assert out.last_info.frame_id == 7
        first = png.read_bytes()

        # a frame that is not a "show" frame: no read-back, no file
        r.render(None)
        out.after_swap(counting, info(8, "calib:gray3"))
        assert counting.reads == 1 and png.read_bytes() == first
        np.testing.assert_array_equal(out.last_image, image)

        # the next show frame replaces both files; no temporary files are left behind
        out.after_swap(counting, info(9, "show"))
        assert read_png(png).max() == 0 and json.loads((snap / "r1c2.json").read_text())["frame_id"] == 9
        assert sorted(p.name for p in snap.iterdir()) == ["r1c2.json", "r1c2.png"]
    finally:
        r.release()
        out.close()


def test_offscreen_keep_last_reads_back_every_frame_into_a_copy():
    out = OffscreenOutput(slot="r0c0", keep_last=True)
    r = Renderer(out.make_context(), 8, 4)
    try:
        assert out.last_image is None
        r.upload("white", np.full((4, 8), 255, np.uint8))
        r.render("white", space="projector")
        out.after_swap(r, info(1, "calib", slot="r0c0"))
        kept = out.last_image
        assert kept.shape == (4, 8, 3) and (kept == 255).all()
        r.render(None)
        r.read()
        assert (kept == 255).all()  # a copy, not the renderer's reused buffer
        out.after_swap(r, info(2, "calib", slot="r0c0"))
        assert out.last_image.max() == 0 and out.last_info.frame_id == 2
    finally:
        r.release()
        out.close()


def test_snapshot_failure_does_not_stop_the_node(tmp_path, caplog):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    out = OffscreenOutput(slot="r0c0", snapshot_dir=blocker / "snaps")
    r = Renderer(out.make_context(), 8, 8)
    try:
        r.render(None)
        out.after_swap(r, info(1, "show", slot="r0c0"))
        assert out.snapshots_written == 0 and out._snap.snapshot_failures == 1
        assert "cannot write the snapshot" in caplog.text
    finally:
        r.release()
        out.close()


# ----------------------------------------------------------------------------- factory


@pytest.mark.parametrize("spec", ["projector", "window:first", "window:-1", "room://", "room://host", "room://h:99999",
                                  "room:/h:1", "offscreen:0"])
def test_bad_specs_name_the_accepted_forms(spec):
    with pytest.raises(OutputError) as err:
        open_output(spec, slot="r0c0")
    message = str(err.value)
    assert "window:1" in message or "room://HOST:PORT" in message
    assert spec.strip() in message


@pytest.mark.parametrize("slot", ["", "../r0c0", "a/b", ".hidden", "x" * 80])
def test_unusable_slot_names_are_refused(slot, tmp_path):
    with pytest.raises(OutputError, match="slot name"):
        open_output("offscreen", slot=slot, snapshot_dir=tmp_path)


def test_room_output_is_imported_lazily(monkeypatch):
    code = "import sys, node.outputs as o; o.open_output('offscreen', slot='r0c0').close(); print('node.outputs.room_link' in sys.modules, 'grpc' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "False False"

    calls = []
    fake = types.ModuleType("node.outputs.room_link")

    class RoomOutput(outputs.Output):
        def __init__(self, *args, **kwargs):
            calls.append((args, kwargs))

        def make_context(self):  # pragma: no cover - never called here
            raise AssertionError

    fake.RoomOutput = RoomOutput
    monkeypatch.setitem(sys.modules, "node.outputs.room_link", fake)
    out = open_output("room://127.0.0.1:50071", slot="r3c4", snapshot_dir=Path("/tmp/x"))
    assert isinstance(out, RoomOutput)
    assert calls == [(("room://127.0.0.1:50071",), {"slot": "r3c4", "snapshot_dir": Path("/tmp/x")})]


# ----------------------------------------------------------------------------- window


def test_window_without_display_says_so(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(OutputError, match="DISPLAY"):
        open_output("window", slot="r0c0")


def test_window_on_an_unreachable_display_says_so(monkeypatch):
    monkeypatch.setenv("DISPLAY", ":4093")  # nothing listens there
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(OutputError, match="cannot open the display"):
        WindowOutput(slot="r0c0")


def _xserver():
    """tests/node/xserver.py (test modules cannot import their siblings by name)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("xserver", Path(__file__).with_name("xserver.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def xvfb():
    """A private Xvfb (640x480, 24-bit) on a free display number; yields its DISPLAY string."""
    try:
        server = _xserver().xvfb()
        display = server.__enter__()
    except RuntimeError as exc:
        pytest.fail(f"{exc} (needed to test the window output)")
    try:
        yield display
    finally:
        server.__exit__(None, None, None)


WINDOW_SCRIPT = textwrap.dedent(
    r'''
    import ctypes, ctypes.util, json, sys, time
    from pathlib import Path

    import glfw
    import numpy as np

    from node.outputs import OutputError, SwapInfo, WindowOutput, open_output
    from node.render import Renderer

    out_dir = Path(sys.argv[1])
    result = {}

    # --- X11 through ctypes: grab what the X server shows, send a key press
    x11 = ctypes.CDLL(ctypes.util.find_library("X11") or "libX11.so.6")
    class XImage(ctypes.Structure):
        _fields_ = [("width", ctypes.c_int), ("height", ctypes.c_int), ("xoffset", ctypes.c_int),
                    ("format", ctypes.c_int), ("data", ctypes.POINTER(ctypes.c_ubyte)), ("byte_order", ctypes.c_int),
                    ("bitmap_unit", ctypes.c_int), ("bitmap_bit_order", ctypes.c_int), ("bitmap_pad", ctypes.c_int),
                    ("depth", ctypes.c_int), ("bytes_per_line", ctypes.c_int), ("bits_per_pixel", ctypes.c_int),
                    ("red_mask", ctypes.c_ulong), ("green_mask", ctypes.c_ulong), ("blue_mask", ctypes.c_ulong)]
    class XKeyEvent(ctypes.Structure):
        _fields_ = [("type", ctypes.c_int), ("serial", ctypes.c_ulong), ("send_event", ctypes.c_int),
                    ("display", ctypes.c_void_p), ("window", ctypes.c_ulong), ("root", ctypes.c_ulong),
                    ("subwindow", ctypes.c_ulong), ("time", ctypes.c_ulong), ("x", ctypes.c_int), ("y", ctypes.c_int),
                    ("x_root", ctypes.c_int), ("y_root", ctypes.c_int), ("state", ctypes.c_uint),
                    ("keycode", ctypes.c_uint), ("same_screen", ctypes.c_int)]
    class XEvent(ctypes.Union):
        _fields_ = [("xkey", XKeyEvent), ("pad", ctypes.c_long * 24)]
    x11.XOpenDisplay.restype = ctypes.c_void_p
    x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
    x11.XDefaultRootWindow.restype = ctypes.c_ulong
    x11.XDefaultRootWindow.argtypes = [ctypes.c_void_p]
    x11.XGetImage.restype = ctypes.POINTER(XImage)
    x11.XGetImage.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_int, ctypes.c_int, ctypes.c_uint,
                              ctypes.c_uint, ctypes.c_ulong, ctypes.c_int]
    x11.XKeysymToKeycode.restype = ctypes.c_ubyte
    x11.XKeysymToKeycode.argtypes = [ctypes.c_void_p, ctypes.c_ulong]
    x11.XSendEvent.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_int, ctypes.c_long, ctypes.POINTER(XEvent)]
    x11.XFlush.argtypes = [ctypes.c_void_p]
    x11.XSync.argtypes = [ctypes.c_void_p, ctypes.c_int]
    x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
    xdpy = x11.XOpenDisplay(None)

    def screen(w, h):
        """What the X server displays: (h, w, 3) uint8 RGB, row 0 at the top."""
        x11.XSync(xdpy, 0)
        img = x11.XGetImage(xdpy, x11.XDefaultRootWindow(xdpy), 0, 0, w, h, 0xFFFFFFFF, 2).contents  # ZPixmap
        assert (img.bits_per_pixel, img.red_mask, img.green_mask, img.blue_mask, img.byte_order) == \
            (32, 0xFF0000, 0xFF00, 0xFF, 0), "unexpected X visual"
        raw = np.ctypeslib.as_array(img.data, shape=(img.height * img.bytes_per_line,))
        return raw.reshape(img.height, img.bytes_per_line)[:, : w * 4].reshape(h, w, 4)[:, :, [2, 1, 0]].copy()

    def send_key(window, keysym, press):
        ev = XEvent()
        ev.xkey.type = 2 if press else 3  # KeyPress / KeyRelease
        ev.xkey.display = xdpy
        ev.xkey.window = window
        ev.xkey.root = x11.XDefaultRootWindow(xdpy)
        ev.xkey.keycode = x11.XKeysymToKeycode(xdpy, keysym)
        ev.xkey.same_screen = 1
        x11.XSendEvent(xdpy, window, 1, 1 if press else 2, ctypes.byref(ev))
        x11.XFlush(xdpy)

    try:
        open_output("window:3", slot="r0c0")
    except OutputError as exc:
        result["bad_monitor"] = str(exc)

    out = open_output("window", slot="r0c0", snapshot_dir=out_dir / "snaps")
    result["native_size"] = list(out.native_size())
    ctx = out.make_context()
    w, h = out.native_size()
    r = Renderer(ctx, w, h)
    result["cursor_hidden"] = glfw.get_input_mode(out.window, glfw.CURSOR) == glfw.CURSOR_HIDDEN
    result["gl"] = ctx.version_code

    known = np.random.default_rng(11).integers(0, 256, (h, w, 3), dtype=np.uint8)
    r.upload("known", known)
    r.render("known", space="projector")
    out.prepare(r)
    back = out.read_back_buffer()
    out.swap()
    out.after_swap(r, SwapInfo("r0c0", 1, "show:known", 10, 11, 12))
    shown_known = screen(w, h)

    # a warped frame: what the window shows must be exactly what the renderer reads back
    yy, xx = np.mgrid[0:120, 0:160]
    content = np.stack([xx * 255 // 159, yy * 255 // 119, (xx + yy) % 256], axis=-1).astype(np.uint8)
    H = np.array([[2.9, 0.4, 40.0], [-0.3, 2.6, 30.0], [0.0004, 0.0003, 1.0]])
    r.set_homography(H, (160, 120))
    r.set_lut(np.stack([np.linspace(0, 1, 64) ** (1 / g) for g in (2.0, 2.2, 2.4)]).astype(np.float32))
    r.set_gain(0.9)
    r.upload("content", content)
    r.render("content")
    out.prepare(r)
    out.swap()
    out.after_swap(r, SwapInfo("r0c0", 2, "calib", 20, 21, 22))
    shown_warp = screen(w, h)
    offscreen_warp = r.read().copy()

    # Escape and a close request change nothing
    keys = []
    glfw.set_key_callback(out.window, lambda win, key, scancode, action, mods: keys.append((key, action)))
    xwin = glfw.get_x11_window(out.window)
    for press in (True, False):
        send_key(xwin, 0xFF1B, press)  # XK_Escape
    glfw.set_window_should_close(out.window, True)
    deadline = time.monotonic() + 60
    while len(keys) < 2 and time.monotonic() < deadline:
        glfw.wait_events_timeout(1.0)   # returns as soon as the X server delivers an event
    out.poll()
    result["escape_seen"] = [k for k, a in keys if k == glfw.KEY_ESCAPE]
    result["should_close"] = bool(glfw.window_should_close(out.window))
    result["close_requests"] = out.close_requests
    r.render(None)  # still renders after Escape: black now
    out.prepare(r)
    out.swap()
    out.after_swap(r, SwapInfo("r0c0", 3, "calib", 30, 31, 32))
    shown_after_escape = screen(w, h)
    result["after_escape_black"] = int(shown_after_escape.max()) == 0

    # a renderer of the wrong size cannot be blitted
    r.resize(w // 2, h)
    try:
        out.prepare(r)
    except OutputError as exc:
        result["wrong_size"] = str(exc)

    r.release()
    out.close()
    x11.XCloseDisplay(xdpy)
    np.savez(out_dir / "images.npz", known=known, back=back, shown_known=shown_known, shown_warp=shown_warp,
             offscreen_warp=offscreen_warp)
    (out_dir / "result.json").write_text(json.dumps(result))
    '''
)


#: a Raspberry Pi's V3D offers OpenGL 3.1 (GLSL 1.40) and no 3.3 core: Mesa restricted to that
GL31 = {"MESA_GL_VERSION_OVERRIDE": "3.1", "MESA_GLSL_VERSION_OVERRIDE": "140"}


@pytest.mark.parametrize("gl", ["default", "gl31"])
def test_fullscreen_window_under_xvfb(xvfb, tmp_path, gl):
    env = {k: v for k, v in os.environ.items() if k != "WAYLAND_DISPLAY"}
    env["DISPLAY"] = xvfb
    if gl == "gl31":
        env.update(GL31)
    done = subprocess.run([sys.executable, "-c", WINDOW_SCRIPT, str(tmp_path)], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, f"window script failed:\n{done.stdout}\n{done.stderr}"
    result = json.loads((tmp_path / "result.json").read_text())
    images = np.load(tmp_path / "images.npz")

    assert result["native_size"] == [640, 480]
    assert result["cursor_hidden"]
    assert (result["gl"] == 310) if gl == "gl31" else (result["gl"] >= 330), result["gl"]
    # the back buffer after prepare(), and what the X server shows after swap(), are the frame exactly
    np.testing.assert_array_equal(images["back"], images["known"])
    np.testing.assert_array_equal(images["shown_known"], images["known"])
    np.testing.assert_array_equal(images["shown_warp"], images["offscreen_warp"])
    assert images["shown_warp"].std() > 20  # a real picture, not a blank screen
    np.testing.assert_array_equal(read_png(tmp_path / "snaps" / "r0c0.png"), images["known"])

    assert "no monitor with index 3" in result["bad_monitor"] and "0: " in result["bad_monitor"]
    assert result["escape_seen"], "the synthetic Escape key never reached the window (the test proves nothing)"
    assert not result["should_close"] and result["close_requests"] == 1
    assert result["after_escape_black"]
    assert "320x480" in result["wrong_size"] and "640x480" in result["wrong_size"]


def test_offscreen_without_egl_says_what_to_install(monkeypatch):
    import moderngl

    def no_egl(**kwargs):
        raise Exception("eglGetDisplay failed")

    monkeypatch.setattr(moderngl, "create_standalone_context", no_egl)
    with pytest.raises(OutputError, match="eglGetDisplay failed.*libegl1"):
        OffscreenOutput(slot="r0c0").make_context()


def test_window_without_glfw_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "glfw", None)  # makes `import glfw` fail
    with pytest.raises(OutputError, match=r"shadowless\[window\]"):
        open_output("window:0", slot="r0c0")
