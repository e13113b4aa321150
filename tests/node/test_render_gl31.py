"""The renderer on an edge GPU's OpenGL 3.1 (GLSL 1.40), as a Raspberry Pi's V3D driver offers:
every check of test_render.py (the warps against cv2.warpPerspective and protos.spaces, LUT,
gain, 16-bit and float precision, meshes) run again on a context Mesa restricts to 3.1."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import moderngl

from node.render.shaders import glsl_header

GL31 = {"MESA_GL_VERSION_OVERRIDE": "3.1", "MESA_GLSL_VERSION_OVERRIDE": "140", "GLCONTEXT_GLVERSION": "310"}
HERE = Path(__file__).resolve().parent


def test_glsl_header_follows_the_context_version():
    assert glsl_header(310) == "#version 140\n"
    assert glsl_header(330) == "#version 330 core\n"
    assert glsl_header(460) == "#version 330 core\n"


def test_every_render_check_passes_on_opengl_3_1():
    env = {**os.environ, **GL31, "SHADOWLESS_TEST_GL_VERSION": "310"}
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(HERE / "test_render.py")],
                       capture_output=True, text=True, env=env, cwd=HERE.parents[1], timeout=600)
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-2000:]
    assert " passed" in r.stdout and "skipped" not in r.stdout


def test_the_3_3_shaders_would_not_compile_there():
    """The restriction is real: GLSL 3.30 is refused on the emulated context (checked in a child,
    since Mesa reads the override when a process creates its first context)."""
    code = ("import moderngl\n"
            "ctx = moderngl.create_standalone_context(backend='egl', require=310)\n"
            "src = '#version 330 core\\nout vec4 c; void main() { c = vec4(1.0); }'\n"
            "vs = '#version 330 core\\nvoid main() { gl_Position = vec4(0.0); }'\n"
            "try:\n    ctx.program(vertex_shader=vs, fragment_shader=src)\n    print('compiled')\n"
            "except moderngl.Error:\n    print('refused')\n"
            "print(ctx.version_code)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env={**os.environ, **GL31},
                       timeout=120)
    assert r.stdout.split() == ["refused", "310"], r.stdout + r.stderr
    assert moderngl  # the default context here is 3.3+ (test_render.py runs on it)
