"""node/outputs/kms.py: the fullscreen output without X (SDL2's KMS/DRM), run here through the
same code with SDL's X11 driver under Xvfb: what the X server shows is the offscreen rendering."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from node.outputs import OutputError, open_output
from node.outputs.kms import drm_connectors

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]

def _xserver():
    import importlib.util

    spec = importlib.util.spec_from_file_location("xserver", HERE / "xserver.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def display():
    with _xserver().xvfb() as d:
        yield d


KMS_SCRIPT = textwrap.dedent(
    r'''
    import ctypes, importlib.util, json, sys, time
    from pathlib import Path

    import numpy as np
    import sdl2

    from node.outputs import OutputError, SwapInfo, open_output
    from node.render import Renderer

    out_dir, helper = Path(sys.argv[1]), sys.argv[2]
    spec = importlib.util.spec_from_file_location("xserver", helper)
    xserver = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(xserver)
    screen = xserver.XScreen()
    result = {}

    try:
        open_output("kms:7", slot="r0c0")
    except OutputError as exc:
        result["bad_display"] = str(exc)

    out = open_output("kms", slot="r0c0", snapshot_dir=out_dir / "snaps")
    result["driver"], result["native_size"] = out.driver, list(out.native_size())
    ctx = out.make_context()
    result["gl_version"], result["context"] = out.gl_version, ctx.version_code
    w, h = out.native_size()
    r = Renderer(ctx, w, h)

    # a warped frame through a LUT and gain, as on a rig
    yy, xx = np.mgrid[0:120, 0:160]
    content = np.stack([xx * 255 // 159, yy * 255 // 119, (xx + yy) % 256], axis=-1).astype(np.uint8)
    H = np.array([[2.9, 0.4, 40.0], [-0.3, 2.6, 30.0], [0.0004, 0.0003, 1.0]])
    lut = np.stack([np.linspace(0, 1, 64) ** (1 / g) for g in (2.0, 2.2, 2.4)]).astype(np.float32)
    r.set_homography(H, (160, 120))
    r.set_lut(lut)
    r.set_gain(0.9)
    r.upload("content", content)
    r.render("content")
    out.prepare(r)
    back = out.read_back_buffer()
    swap_ms = []
    for i in range(20):             # the swap as the presenter times it
        t = time.perf_counter()
        out.swap()
        swap_ms.append((time.perf_counter() - t) * 1e3)
        out.prepare(r)
    out.after_swap(r, SwapInfo("r0c0", 1, "show:warp", 10, 11, 12))
    shown = screen.grab(w, h)
    result["swap_ms_median"] = float(np.median(swap_ms))

    # the same frame on a headless desktop-GL context of its own: the offscreen rendering (with
    # GLES on the display: the same picture through the other API)
    ref = Renderer.standalone(w, h, gl="gl")
    ref.set_homography(H, (160, 120))
    ref.set_lut(lut)
    ref.set_gain(0.9)
    ref.upload("content", content)
    ref.render("content")
    offscreen = ref.read().copy()
    ref.release()

    # a quit request is ignored: the node's service manager stops it, not the projector's keyboard
    ev = sdl2.SDL_Event()
    ev.type = sdl2.SDL_QUIT
    sdl2.SDL_PushEvent(ctypes.byref(ev))
    out.poll()
    result["quit_requests"] = out.quit_requests
    r.render(None)
    out.prepare(r)
    out.swap()
    result["black_after_quit"] = int(screen.grab(w, h).max()) == 0

    r.release()
    out.close()
    screen.close()
    np.savez(out_dir / "images.npz", back=back, shown=shown, offscreen=offscreen)
    (out_dir / "result.json").write_text(json.dumps(result))
    '''
)


@pytest.mark.parametrize("gl", ["auto", "gles"])
def test_kms_output_under_xvfb_shows_the_offscreen_rendering(display, tmp_path, gl):
    """The default (desktop GL where offered) and OpenGL ES forced (as on a Mali or Adreno board)."""
    env = {k: v for k, v in os.environ.items() if k != "WAYLAND_DISPLAY"}
    env.update(DISPLAY=display, SDL_VIDEODRIVER="x11", SHADOWLESS_GL=gl)
    done = subprocess.run([sys.executable, "-c", KMS_SCRIPT, str(tmp_path), str(HERE / "xserver.py")], cwd=REPO,
                          env=env, capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, f"kms script failed:\n{done.stdout}\n{done.stderr}"
    result = json.loads((tmp_path / "result.json").read_text())
    images = np.load(tmp_path / "images.npz")

    assert result["driver"] == "x11" and result["native_size"] == [640, 480]
    assert result["context"] >= (300 if gl == "gles" else 310)
    assert result["gl_version"].startswith("OpenGL ES 3.") == (gl == "gles"), result["gl_version"]
    np.testing.assert_array_equal(images["back"], images["offscreen"])
    np.testing.assert_array_equal(images["shown"], images["offscreen"])   # the X server's screenshot
    assert images["shown"].std() > 20, "a real picture, not a blank screen"
    assert result["swap_ms_median"] > 0
    assert "no display '7'" in result["bad_display"] and "0: " in result["bad_display"]
    assert result["quit_requests"] == 1 and result["black_after_quit"]


def test_kms_without_a_usable_display_says_what_to_check(monkeypatch):
    """Here there is no DRM device this user may open as a display: the error says what to check."""
    monkeypatch.setenv("SDL_VIDEODRIVER", "KMSDRM")
    code = ("from node.outputs import OutputError, open_output\n"
            "try:\n    open_output('kms', slot='r0c0')\n    print('opened')\n"
            "except OutputError as exc:\n    print(exc)\n")
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60,
                          env={**os.environ, "SDL_VIDEODRIVER": "KMSDRM"})
    assert done.returncode == 0, done.stderr
    assert "opened" not in done.stdout, "this machine has a display: the test needs one without"
    assert "KMSDRM" in done.stdout and "video and render groups" in done.stdout


def test_kms_spec_forms():
    with pytest.raises(OutputError, match="kms"):
        open_output("kms:", slot="r0c0")


def test_drm_connectors_reads_connected_ones_in_connector_id_order(tmp_path):
    for name, status, cid in [("card1-HDMI-A-2", "connected", 45), ("card1-HDMI-A-1", "connected", 33),
                              ("card1-DSI-1", "disconnected", 30), ("card1-Writeback-1", "unknown", 50)]:
        (tmp_path / name).mkdir()
        (tmp_path / name / "status").write_text(status + "\n")
        (tmp_path / name / "connector_id").write_text(f"{cid}\n")
    assert drm_connectors(tmp_path) == ["HDMI-A-1", "HDMI-A-2"]
