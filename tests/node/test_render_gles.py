"""The renderer on OpenGL ES 3 (Mali and Adreno drivers offer nothing else): every check of
test_render.py (the warps against cv2.warpPerspective and protos.spaces, LUT, gain, 16-bit and
float precision, meshes) run again on a real GLES context, and the capability a node reports
checked against what EGL says the context is.

Mesa's llvmpipe offers OpenGL ES 3.2 through EGL. Each case runs in a child process: Mesa reads
its overrides when a process makes its first context, and a GLES context made current here would
take the thread's current context from the desktop ones of other tests.

* ``MESA_GL_VERSION_OVERRIDE=3.0`` makes EGL refuse desktop OpenGL 3.1 contexts, as on a board
  whose desktop GL is too old: the default choice (``auto``) must fall back to GLES by itself.
* ``MESA_GLES_VERSION_OVERRIDE=3.0`` plus ``MESA_EXTENSION_OVERRIDE`` removing 16-bit normalised
  textures and float filtering/rendering emulates a bare OpenGL ES 3.0 driver: 16-bit content
  must keep its precision through the float32 fallback (Mesa then refuses R16 textures for real).
"""
from __future__ import annotations

import json
import os
import selectors
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from node.render.context import GL_ENV
from node.render.shaders import glsl_header
from protos import auth

HERE = Path(__file__).resolve().parent
DESKTOP_TOO_OLD = {"MESA_GL_VERSION_OVERRIDE": "3.0"}
BARE_GLES30 = {"MESA_GLES_VERSION_OVERRIDE": "3.0",
               "MESA_EXTENSION_OVERRIDE": "-GL_EXT_texture_norm16 -GL_EXT_color_buffer_float "
                                          "-GL_EXT_color_buffer_half_float -GL_OES_texture_float_linear"}


def child_env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != GL_ENV and not k.startswith("MESA_")}
    return {**env, **extra}


@pytest.mark.parametrize("name, extra, version", [
    pytest.param("GLES 3.2", DESKTOP_TOO_OLD, "320", id="gles3.2"),
    pytest.param("a bare GLES 3.0", {**DESKTOP_TOO_OLD, **BARE_GLES30}, "300", id="bare-gles3.0"),
])
def test_every_render_check_passes_on_opengl_es(name, extra, version):
    env = child_env(**extra, SHADOWLESS_TEST_GL_VERSION=version)
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(HERE / "test_render.py")],
                       capture_output=True, text=True, env=env, cwd=HERE.parents[1], timeout=600)
    assert r.returncode == 0, name + "\n" + r.stdout[-4000:] + r.stderr[-2000:]
    assert " passed" in r.stdout and "skipped" not in r.stdout and "failed" not in r.stdout


# Run in the child: the context an offscreen output makes, what the node reports for it, and what
# EGL itself says the current context is (eglQueryContext: the client API and, for GLES, its major
# version), plus whether the shaders compile without the GLSL ES precision header.
PROBE = r"""
import ctypes, json, re
import moderngl
from node.outputs.offscreen import OffscreenOutput
from node.render import Renderer
from node.render.shaders import gl_description, load_shader

out = OffscreenOutput(slot="r0c0")
ctx = out.make_context()
egl = ctypes.CDLL("libEGL.so.1")
egl.eglGetCurrentDisplay.restype = egl.eglGetCurrentContext.restype = ctypes.c_void_p
egl.eglQueryContext.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int32, ctypes.POINTER(ctypes.c_int32)]

def query(attribute):
    value = ctypes.c_int32(0)
    ok = egl.eglQueryContext(egl.eglGetCurrentDisplay(), egl.eglGetCurrentContext(), attribute, ctypes.byref(value))
    return value.value if ok else None

renderer = Renderer(ctx, 8, 8)
result = {"client_api": {0x30A0: "gles", 0x30A2: "gl"}.get(query(0x3097)), "client_version": query(0x3098),
          "gl_version": ctx.info["GL_VERSION"], "gl_renderer": ctx.info["GL_RENDERER"],
          "description": gl_description(ctx), "profile": renderer.gl_profile}
if result["client_api"] == "gles":
    vertex = load_shader("fullscreen.vert.glsl", "#version 300 es\n")
    for header in ("#version 300 es\n", "#version 140\n"):   # no default precision; desktop GLSL
        try:
            ctx.program(vertex_shader=vertex, fragment_shader=load_shader("warp.frag.glsl", header))
            result[header.strip()] = "compiled"
        except moderngl.Error:
            result[header.strip()] = "refused"
renderer.release()
out.close()
print(json.dumps(result))
"""


def probe(**extra: str) -> dict:
    r = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, env=child_env(**extra),
                       cwd=HERE.parents[1], timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    return json.loads(r.stdout.strip().splitlines()[-1])


def test_the_reported_capability_is_the_context_egl_made():
    desktop = probe()
    assert desktop["client_api"] == "gl", desktop
    v = desktop["gl_version"].split()[0]  # desktop GL_VERSION starts "<major>.<minor>"
    assert desktop["description"].startswith(f"OpenGL {v[:3]}, GLSL ") and " ES" not in desktop["description"]

    fallback = probe(**DESKTOP_TOO_OLD)
    assert (fallback["client_api"], fallback["client_version"]) == ("gles", 3), fallback
    assert fallback["gl_version"].startswith("OpenGL ES 3.2")
    assert fallback["description"] == f"OpenGL ES 3.2, GLSL ES 3.00, {fallback['gl_renderer']}"
    assert fallback["profile"] == f"OpenGL ES 3.2, GLSL ES 3.00 ({fallback['gl_renderer']})"
    # the context enforces GLSL ES: the renderer's shaders need their precision header there
    assert (fallback["#version 300 es"], fallback["#version 140"]) == ("refused", "refused")

    # a system without the desktop GL library (libEGL and libGLESv2 only) renders with OpenGL ES too
    no_libgl = probe(GLCONTEXT_LINUX_LIBGL="libGL-absent.so.1")
    assert (no_libgl["client_api"], no_libgl["client_version"]) == ("gles", 3), no_libgl

    bare = probe(**BARE_GLES30, **{GL_ENV: "gles"})
    assert (bare["client_api"], bare["client_version"]) == ("gles", 3) and bare["gl_version"].startswith("OpenGL ES 3.0")
    # the bare profile takes away 16-bit normalised textures and filtered float32 ones: both fallbacks show
    assert bare["description"] == (f"OpenGL ES 3.0, GLSL ES 3.00, {bare['gl_renderer']}; "
                                   "16-bit content as float32, blend maps as float16")


def test_the_glsl_es_header_asks_for_high_precision_everywhere():
    """llvmpipe computes in 32-bit floats whatever the qualifiers say; a Mali computes mediump in
    16 bits, which would cost 4K content coordinates and 16-bit levels their precision."""
    header = glsl_header(300, gles=True)
    assert header.startswith("#version 300 es\n")
    for kind in ("float", "int", "sampler2D"):
        assert f"precision highp {kind};" in header


def test_shadowless_node_gl_gles_renders_with_opengl_es_and_says_so(tmp_path):
    """``shadowless node --gl gles``: the presenter process (it inherits the choice) makes a GLES
    context on a machine that offers desktop GL, and logs what it renders with, the string
    `shadowless status` shows for the node."""
    token = tmp_path / "token"
    token.write_text(auth.new_token() + "\n")
    token.chmod(0o600)
    # no coordinator answers: the presenter opens its output before the node finds one
    proc = subprocess.Popen([sys.executable, "-m", "shadowless", "node", "--slot", "r0c0", "--gl", "gles",
                             "--coordinator", "127.0.0.1:1", "--token-file", str(token), "--cache-dir",
                             str(tmp_path / "cache")],
                            env=child_env(), cwd=HERE.parents[1], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)
    lines: list[str] = []
    try:
        with selectors.DefaultSelector() as sel:
            sel.register(proc.stderr, selectors.EVENT_READ)
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and not any("rendering with" in line for line in lines):
                if sel.select(timeout=max(0.0, deadline - time.monotonic())):
                    line = proc.stderr.readline()
                    if not line:
                        break
                    lines.append(line)
        said = [line for line in lines if "rendering with" in line]
        assert said and "rendering with OpenGL ES 3." in said[0] and ", GLSL ES 3.00, " in said[0], "".join(lines)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stderr.close()


def test_mistakes_in_choosing_the_gl_are_named():
    from node.render import RenderError, Renderer
    from node.render.egl_gles import EglError, GlesContext

    with pytest.raises(RenderError, match=r"OpenGL choice \(--gl, SHADOWLESS_GL\) must be one of auto, gl, gles, "
                                          r"got 'vulkan'"):
        Renderer.standalone(8, 8, gl="vulkan")
    # refused before any context is made (nothing becomes current in this process)
    with pytest.raises(EglError, match=r"EGL device 99 was asked for \(GLCONTEXT_DEVICE_INDEX\), but there are \d"):
        GlesContext(device_index=99)
