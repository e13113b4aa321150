"""The node's renderer: content -> this projector's pixels, with moderngl.

One :class:`Renderer` draws into its own framebuffer (``width`` x ``height``, the
projector's pixels). Per frame it does one draw call: a full-screen triangle whose
fragment shader warps the content through the homography pose, or the textured mesh
of a projection pose with depth test. The same shader then applies the node's gain
and inverse-response LUT and quantises to 8 bits. See ``pipeline.glsl``.

The fragment shader is compiled once per variant (:class:`~node.render.shaders.Variant`: the
content's kind, a fade's start, blend maps, the LUT; #define lines after the #version line), at
the variant's first draw, and kept: llvmpipe runs both sides of a uniform's branches, so one
program for every path cost two to five times the rasterizer's CPU of the path taken.
:meth:`Renderer.warm_up` compiles the common ones ahead. The uniforms' values live in the
renderer and go to the program a draw uses, written only where they changed.

Blend maps (:class:`protos.blend.BlendMaps`, :meth:`Renderer.set_blend`) live in one RGBA32F
texture filtered by the texture unit (rgb = alpha, a = beta, the wire's float16 values; see
:mod:`node.render.blend_texture`); frames that apply the LUT are then
``LUT(clamp(gain * (alpha * value + beta)))``, dithered before the 8-bit output
(:func:`protos.spaces.blended_output` is the reference). Maps may be uploaded ahead of the frame
that first shows them (:meth:`Renderer.load_blend`).

Conventions (shared with the whole project)
--------------------------------------------
* Pixel (x, y) has its centre at integer (x, y) (OpenCV); images are numpy arrays with
  row 0 at the top. The framebuffer itself is in GL order (row 0 at the bottom) so that
  a window output can blit it to the screen unchanged; :meth:`Renderer.read` flips.
* A homography maps content pixels to projector pixels exactly as
  ``cv2.warpPerspective(content, H, (width, height))`` uses it; the warp reproduces
  ``INTER_LINEAR`` with ``BORDER_CONSTANT`` 0, in float arithmetic.
* A 3x4 projection matrix maps world mm to projector pixels (homogeneous, positive depth
  in front); mesh UV (0, 0) is the top-left corner of the content, content pixel
  ``x = u * W - 0.5``.

Threading: every method must be called from the one thread that owns the GL context.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from node.errors import NodeError
from node.render.blend_texture import blend_texture
from node.render.mesh import Mesh
from node.render.readback import ReadBack
from node.render.yuv_textures import YuvTextures, layout_key
from node.render.shaders import (BLACK, GREY, MIN_GL_VERSION, MIN_GLES_VERSION, RGB, YUV_PLANAR, YUV_SEMIPLANAR,
                                  Variant, glsl_header, has_norm16_textures, is_gles, is_software_rasterizer,
                                  load_shader, shading_language)
from protos.blend import BlendMaps
from protos.yuv import YuvFrame

__all__ = ["Mesh", "RenderError", "Renderer", "SPACES"]

log = logging.getLogger(__name__)

SPACES = ("content", "projector")

# numpy dtype -> moderngl texture dtype. 8/16-bit integers become normalised textures
# (GL divides by 255 / 65535 when sampling); floats are sampled as stored. OpenGL ES without
# GL_EXT_texture_norm16 has no 16-bit normalised textures: there 16-bit content is divided by
# 65535 on the CPU and stored as float32, which holds every 16-bit level exactly as GL's unorm
# conversion would (half floats would keep only 11 bits).
_TEXTURE_DTYPES = {
    np.dtype(np.uint8): "f1",
    np.dtype(np.uint16): "nu2",
    np.dtype(np.float16): "f2",
    np.dtype(np.float32): "f4",
}


#: what Renderer.warm_up compiles: stills with the LUT, with blend maps and without the LUT
#: (patterns), 8-bit video (planar with and without blend maps, NV12), and the fades a show makes
#: most (from black, between stills, between videos, from a still to a video); ~0.6 MB each
WARM_VARIANTS = (
    Variant.of(RGB), Variant.of(RGB, blend=True), Variant.of(RGB, apply_lut=False), Variant.of(GREY, apply_lut=False),
    Variant.of(YUV_PLANAR), Variant.of(YUV_PLANAR, blend=True), Variant.of(YUV_SEMIPLANAR),
    Variant.of(RGB, BLACK), Variant.of(RGB, RGB), Variant.of(YUV_PLANAR, YUV_PLANAR), Variant.of(YUV_PLANAR, RGB),
)


class RenderError(NodeError, RuntimeError):
    """OpenGL is unusable or refused a request; the message says what to check."""


@dataclass
class _Content:
    texture: Any  # moderngl.Texture
    shape: tuple[int, ...]
    dtype: np.dtype
    grey: bool
    yuv: YuvTextures | None = None    # a YUV picture: its planes (texture is then its Y plane)

    @property
    def size(self) -> tuple[int, int]:
        return self.yuv.content_size if self.yuv is not None else (self.shape[1], self.shape[0])

    @property
    def kind(self) -> int:
        """pipeline.glsl's kind of this content (RGB, GREY, YUV_PLANAR, YUV_SEMIPLANAR)."""
        if self.yuv is not None:
            return YUV_PLANAR if self.yuv.mode == 1 else YUV_SEMIPLANAR
        return GREY if self.grey else RGB


def _check_size(width: int, height: int, limit: int) -> tuple[int, int]:
    if isinstance(width, bool) or isinstance(height, bool):
        raise ValueError(f"output size must be two integers, got {width!r} x {height!r}")
    try:
        w, h = int(width), int(height)
    except (TypeError, ValueError):
        raise ValueError(f"output size must be two integers, got {width!r} x {height!r}") from None
    if w != width or h != height or not (1 <= w <= limit and 1 <= h <= limit):
        raise ValueError(f"output size must be whole pixels in 1..{limit}, got {width!r} x {height!r}")
    return w, h


def _mat_bytes(m: np.ndarray) -> bytes:
    """GLSL matN uniform bytes (column-major float32) for a row-major numpy (N, N)."""
    return np.ascontiguousarray(m.T, dtype=np.float32).tobytes()


class Renderer:
    """Renders content into one projector's pixels (see module docstring).

    Parameters
    ----------
    ctx : moderngl.Context
        The GL context (OpenGL >= 3.1 or OpenGL ES >= 3.0) the calling thread owns.
    width, height : int
        Output size in projector pixels.
    """

    #: textures forgotten and kept for reuse (one per size and type, the most recent ones)
    SPARE_TEXTURES = 2

    def __init__(self, ctx: Any, width: int, height: int):
        import moderngl  # the node extra; imported here so `import node.render` stays light

        self._mgl = moderngl
        self._gles = is_gles(ctx)
        if ctx.version_code < (MIN_GLES_VERSION if self._gles else MIN_GL_VERSION):
            raise RenderError(
                f"OpenGL 3.1 or newer (or OpenGL ES 3.0) is needed, this context offers "
                f"{'OpenGL ES ' if self._gles else ''}{ctx.version_code // 100}.{ctx.version_code // 10 % 10} "
                f"({ctx.info.get('GL_RENDERER', '?')}); update the GPU driver or Mesa"
            )
        self.ctx = ctx
        self._norm16 = has_norm16_textures(ctx)
        #: a planar YUV picture's U and V go up interleaved into one texture and draw as semi-planar
        #: (yuv_textures.py): four chroma fetches per pixel instead of eight, for an interleave on the
        #: CPU per frame; worth it where the CPU also draws. Read at each upload.
        self.interleave_chroma = is_software_rasterizer(ctx)
        self._norm16_note_logged = False
        self._owns_ctx = False
        self._released = False
        self._max_texture = int(ctx.info["GL_MAX_TEXTURE_SIZE"])
        self._width, self._height = _check_size(width, height, self._max_texture)
        # One program per shader and variant (pipeline.glsl's #defines), compiled at first use and kept;
        # the uniforms' values live here and go to the program a draw uses (_use). Texture units:
        # content_from is a crossfade's picture before (render(fade=...)); then a YUV picture's chroma
        # planes and those of the picture a fade starts from (yuv_textures.py).
        self._header = glsl_header(ctx.version_code, self._gles)
        self._uniforms: dict[str, Any] = {"content": 0, "lut": 1, "blend": 2, "content_from": 3, "chroma_u": 4,
                                          "chroma_v": 5, "from_chroma_u": 6, "from_chroma_v": 7}
        # (shader, Variant) -> [program, its uniforms by name, the values last written, its VAO or None]
        self._programs: dict[tuple[str, Variant], list] = {}
        # moderngl resolves `#include "pipeline.glsl"` from ctx.includes
        ctx.includes["pipeline.glsl"] = load_shader("pipeline.glsl")
        self._program("warp", Variant.of(RGB))     # refuses now, with the driver's words, if it cannot compile
        # the blend maps in use (None: none) and those uploaded ahead of use, by blend id
        self._blend: tuple[str, Any] | None = None
        self._blend_ahead: tuple[str, Any] | None = None
        # bound to the blend's unit while no maps are set (never sampled then: no BLEND variant draws)
        self._blend_none = ctx.texture((1, 1), 4, np.array([1, 1, 1, 0], np.float16).tobytes(), dtype="f2")
        self._contents: dict[str, _Content] = {}
        # forgotten textures kept for reuse, by ((H, W, C), dtype); at most SPARE_TEXTURES
        self._spare: dict[tuple[tuple[int, ...], np.dtype], Any] = {}
        # the last YUV picture forgotten: its textures, refilled by the next of the same layout
        self._spare_yuv: YuvTextures | None = None
        self._lut_tex: Any = None
        self._lut_shape: tuple[int, int] | None = None
        self.set_lut(None)
        self.set_gain(1.0)
        # pose: None, ("homography", H, content_size) or ("projection", P, near, far)
        self._pose: tuple | None = None
        self._pose_content_size: tuple[int, int] | None = None
        self._warp_pose_bytes = b""
        self._warp_identity_bytes = b""
        self._mesh_vbo: Any = None
        self._mesh_ibo: Any = None
        self._fbo: Any = None
        self._color: Any = None
        self._depth: Any = None
        self._allocate_targets()

    # ------------------------------------------------------------------ construction
    @classmethod
    def standalone(cls, width: int, height: int, *, gl: str | None = None) -> "Renderer":
        """A renderer on its own headless EGL context (released by :meth:`release`): desktop
        OpenGL 3.1+, else OpenGL ES 3.0+ (``gl``: "auto", "gl" or "gles"; default
        ``$SHADOWLESS_GL`` or "auto"; see :mod:`node.render.context`)."""
        from node.render.context import ContextUnavailable, create_headless_context

        try:
            ctx = create_headless_context(gl)
        except ContextUnavailable as exc:
            raise RenderError(
                "cannot create a headless OpenGL 3.1+ or OpenGL ES 3.0+ context through EGL "
                f"({exc}); install Mesa's EGL and DRI drivers (e.g. apt-get install libegl1 libgl1 libgl1-mesa-dri)"
            ) from exc
        try:
            renderer = cls(ctx, width, height)
        except BaseException:
            ctx.release()
            raise
        renderer._owns_ctx = True
        return renderer

    def _allocate_targets(self) -> None:
        """(Re)create the framebuffer and read-back buffers for the current size."""
        for obj in (self._fbo, self._color, self._depth):
            if obj is not None:
                obj.release()
        size = (self._width, self._height)
        self._color = self.ctx.texture(size, 4, dtype="f1")
        self._color.filter = (self._mgl.NEAREST, self._mgl.NEAREST)
        self._depth = None
        self._fbo = None
        self._attach_depth(self._mesh_vbo is not None)
        self._readback = ReadBack(self._width, self._height, rgba=self._gles)
        # projector space: GL window coords -> OpenCV projector pixels (the content *is* in projector pixels)
        self._warp_identity_bytes = _mat_bytes(self._window_to_pixels())
        self._update_pose_uniforms()
        self._update_blend_uniforms()

    def _attach_depth(self, depth: bool) -> None:
        """(Re)build the framebuffer, with a depth buffer only once a mesh needs one (a homography
        never tests depth; at 1080p it is 8 MB of an edge computer's shared memory)."""
        if self._fbo is not None and (self._depth is not None) == depth:
            return
        for obj in (self._fbo, self._depth):
            if obj is not None:
                obj.release()
        size = (self._width, self._height)
        self._depth = self.ctx.depth_renderbuffer(size) if depth else None
        self._fbo = self.ctx.framebuffer(color_attachments=[self._color], depth_attachment=self._depth)
        self._fbo.clear(0.0, 0.0, 0.0, 1.0, depth=1.0)

    def _window_to_pixels(self) -> np.ndarray:
        """(3, 3) float64: GL window coords (centres at +0.5, rows bottom-up) -> OpenCV pixels."""
        return np.array([[1.0, 0.0, -0.5], [0.0, -1.0, self._height - 0.5], [0.0, 0.0, 1.0]])

    # ------------------------------------------------------------------ programs
    def _program(self, shader: str, variant: Variant) -> list:
        """The program of ``shader`` ("warp" or "mesh") for ``variant``, compiled at its first use:
        [program, its uniforms by name, the values last written to it, its vertex array or None]."""
        entry = self._programs.get((shader, variant))
        if entry is not None:
            return entry
        header = self._header + variant.defines()
        vertex = "fullscreen.vert.glsl" if shader == "warp" else "mesh.vert.glsl"
        try:
            prog = self.ctx.program(vertex_shader=load_shader(vertex, header),
                                    fragment_shader=load_shader(f"{shader}.frag.glsl", header))
        except self._mgl.Error as exc:
            raise RenderError(f"the renderer's shaders do not compile on this driver: {exc}") from exc
        members = {name: prog[name] for name in prog if isinstance(prog[name], self._mgl.Uniform)}
        entry = [prog, members, {}, self.ctx.vertex_array(prog, []) if shader == "warp" else None]
        self._programs[(shader, variant)] = entry
        return entry

    def _use(self, shader: str, variant: Variant) -> list:
        """The program for the next draw, with every uniform it has set to the renderer's value
        (written only where it changed since that program's last draw)."""
        entry = self._program(shader, variant)
        prog, members, written = entry[0], entry[1], entry[2]
        values = self._uniforms
        for name, member in members.items():
            value = values.get(name)
            if value is None or written.get(name) == value:
                continue
            if isinstance(value, bytes):
                member.write(value)
            else:
                member.value = value
            written[name] = value
        if shader == "mesh" and entry[3] is None:
            entry[3] = self.ctx.vertex_array(prog, [(self._mesh_vbo, "3f 2f", "in_position", "in_uv")],
                                             index_buffer=self._mesh_ibo, index_element_size=4)
        return entry

    def _release_mesh_arrays(self) -> None:
        for (shader, _), entry in self._programs.items():
            if shader == "mesh" and entry[3] is not None:
                entry[3].release()
                entry[3] = None

    # ------------------------------------------------------------------ properties
    @property
    def width(self) -> int:
        return self._width

    @property
    def height(self) -> int:
        return self._height

    @property
    def gl_profile(self) -> str:
        """What the renderer runs on, e.g. ``OpenGL 3.1, GLSL 1.40 (V3D 4.2)`` or
        ``OpenGL ES 3.2, GLSL ES 3.00 (llvmpipe (LLVM 15.0.6, 256 bits))``."""
        v = self.ctx.version_code
        api = "OpenGL ES" if self._gles else "OpenGL"
        return (f"{api} {v // 100}.{v // 10 % 10}, {shading_language(v, self._gles)} "
                f"({self.ctx.info.get('GL_RENDERER', '?')})")

    @property
    def gles(self) -> bool:
        """Whether the context is OpenGL ES (shaders compiled as GLSL ES 3.00)."""
        return self._gles

    @property
    def framebuffer(self) -> Any:
        """The moderngl.Framebuffer rendered into (RGBA8, GL row order; outputs blit from it)."""
        return self._fbo

    def resize(self, width: int, height: int) -> None:
        """Change the output size (reallocates the framebuffer; the pose is kept)."""
        w, h = _check_size(width, height, self._max_texture)
        if (w, h) != (self._width, self._height):
            self._width, self._height = w, h
            self._allocate_targets()

    # ------------------------------------------------------------------ pose
    def set_homography(self, h: np.ndarray, content_size: tuple[int, int]) -> None:
        """Planar pose: ``h`` (3, 3) maps content pixels to projector pixels.

        Parameters
        ----------
        h : (3, 3) float64
            Homography, as ``cv2.warpPerspective(content, h, (width, height))`` uses it.
        content_size : (int, int)
            (width, height) of the content this pose was calibrated for; rendering
            content of another size raises ValueError.
        """
        hm = np.asarray(h, dtype=np.float64)
        if hm.shape != (3, 3):
            raise ValueError(f"homography must be (3, 3), got shape {hm.shape}")
        if not np.isfinite(hm).all():
            raise ValueError("homography must be finite")
        try:
            cw, ch = (int(v) for v in content_size)
        except (TypeError, ValueError):
            raise ValueError(f"content_size must be (width, height), got {content_size!r}") from None
        if cw < 1 or ch < 1 or tuple(content_size) != (cw, ch):
            raise ValueError(f"content_size must be two positive integers, got {content_size!r}")
        scale = np.abs(hm).max()
        if scale == 0 or np.linalg.cond(hm / scale) > 1e12:
            raise ValueError("homography is singular (it does not map the content onto a plane)")
        centre = hm @ np.array([(cw - 1) / 2.0, (ch - 1) / 2.0, 1.0])
        if abs(centre[2]) <= 1e-12 * np.abs(centre).max():
            raise ValueError("homography maps the content centre to infinity")
        self._pose = ("homography", hm.copy(), (cw, ch))
        self._pose_content_size = (cw, ch)
        self._update_pose_uniforms()

    def set_projection(self, p: np.ndarray, mesh: Mesh, *, near: float, far: float) -> None:
        """3D pose: ``p`` (3, 4) maps world mm to projector pixels; ``mesh`` is the surface.

        Parameters
        ----------
        p : (3, 4) float64
            Projection matrix (OpenCV convention, homogeneous). Its scale is irrelevant;
            its sign is taken so that the mesh lies at positive depth.
        mesh : Mesh
            Surface, textured with the content through its UVs.
        near, far : float
            Depth range in mm along the projector's axis (0 < near < far); geometry
            outside it is clipped.
        """
        pm = np.asarray(p, dtype=np.float64)
        if pm.shape != (3, 4):
            raise ValueError(f"projection matrix must be (3, 4), got shape {pm.shape}")
        if not np.isfinite(pm).all():
            raise ValueError("projection matrix must be finite")
        if not isinstance(mesh, Mesh):
            raise ValueError(f"mesh must be a Mesh, got {type(mesh).__name__}")
        near, far = float(near), float(far)
        if not (math.isfinite(near) and math.isfinite(far) and 0.0 < near < far):
            raise ValueError(f"need 0 < near < far (finite, mm), got near={near}, far={far}")
        axis = np.linalg.norm(pm[2, :3])
        if axis == 0:
            raise ValueError("projection matrix has no depth axis (its third row starts with zeros)")
        pm = pm / axis  # third row . (X, 1) = depth in mm
        depth = mesh.vertices.astype(np.float64) @ pm[2, :3] + pm[2, 3]
        if np.median(depth) < 0:
            pm = -pm
        data = np.concatenate([mesh.vertices, mesh.uvs], axis=1).astype(np.float32)
        self._release_mesh_arrays()     # each mesh program's vertex array is made at its next draw
        for obj in (self._mesh_vbo, self._mesh_ibo):
            if obj is not None:
                obj.release()
        self._mesh_vbo = self.ctx.buffer(data.tobytes())
        self._mesh_ibo = self.ctx.buffer(mesh.faces.tobytes())
        self._attach_depth(True)
        self._pose = ("projection", pm, near, far)
        self._pose_content_size = None
        self._update_pose_uniforms()

    def clear_pose(self) -> None:
        """Forget the pose: content frames render black until a new pose is set."""
        self._pose = None
        self._pose_content_size = None
        self._release_mesh_arrays()
        for obj in (self._mesh_vbo, self._mesh_ibo):
            if obj is not None:
                obj.release()
        self._mesh_vbo = self._mesh_ibo = None

    def _update_pose_uniforms(self) -> None:
        """Recompute the pose's uniforms (they depend on the output size too)."""
        if self._pose is None:
            return
        if self._pose[0] == "homography":
            hm, (cw, ch) = self._pose[1], self._pose[2]
            inv = np.linalg.inv(hm)
            # w > 0 on the horizon side where the content is: where H sends the content centre
            if (hm @ np.array([(cw - 1) / 2.0, (ch - 1) / 2.0, 1.0]))[2] < 0:
                inv = -inv
            m = inv @ self._window_to_pixels()
            self._warp_pose_bytes = _mat_bytes(m / np.abs(m).max())
        else:
            pm, near, far = self._pose[1], self._pose[2], self._pose[3]
            w, h = self._width, self._height
            x, y, d = pm  # rows; d . (X, 1) = depth (mm)
            clip = np.empty((4, 4))
            # NDC x = 2 (px + 0.5) / W - 1; NDC y = 1 - 2 (py + 0.5) / H (OpenCV rows top-down)
            clip[0] = (2.0 * x + d) / w - d
            clip[1] = d - (2.0 * y + d) / h
            clip[2] = (far + near) / (far - near) * d
            clip[2, 3] -= 2.0 * far * near / (far - near)
            clip[3] = d
            self._uniforms["world_to_clip"] = _mat_bytes(clip)

    # ------------------------------------------------------------------ luminance
    def set_lut(self, lut: np.ndarray | None) -> None:
        """Inverse-response LUT: (C, E) float32, C in {1, 3}, E >= 2; None = identity.

        Row c holds E samples of channel c's input value (0..1) for linear luminance
        ``k / (E - 1)``, k = 0..E-1; values between samples are interpolated linearly.
        A single row (C = 1) applies to all three channels.
        """
        if lut is None:
            table = np.array([[0.0, 1.0]] * 3, np.float32)
        else:
            table = np.asarray(lut, dtype=np.float32)
            if table.ndim != 2 or table.shape[0] not in (1, 3) or table.shape[1] < 2:
                raise ValueError(f"LUT must be (C, E) with C in {{1, 3}} and E >= 2, got shape {table.shape}")
            if table.shape[1] - 1 > self._max_texture:
                raise ValueError(f"LUT has {table.shape[1]} samples; this GPU allows at most {self._max_texture + 1}")
            if not np.isfinite(table).all():
                raise ValueError("LUT values must be finite")
            if table.shape[0] == 1:
                table = np.repeat(table, 3, axis=0)
        e = table.shape[1]
        # texel k of row c holds samples k and k + 1 (pipeline.glsl's lut_channel: one fetch per channel)
        pairs = np.ascontiguousarray(np.stack([table[:, :-1], table[:, 1:]], axis=2))
        if self._lut_shape != (3, e):
            if self._lut_tex is not None:
                self._lut_tex.release()
            self._lut_tex = self.ctx.texture((e - 1, 3), 2, dtype="f4")
            self._lut_tex.filter = (self._mgl.NEAREST, self._mgl.NEAREST)
            self._lut_shape = (3, e)
        self._lut_tex.write(pairs.tobytes())
        self._uniforms["lut_size"] = e

    def set_gain(self, gain: float) -> None:
        """Linear gain applied to the content before the LUT (>= 0)."""
        g = float(gain)
        if not math.isfinite(g) or g < 0:
            raise ValueError(f"gain must be finite and >= 0, got {gain!r}")
        self._uniforms["gain"] = g
        self._gain = g

    @property
    def gain(self) -> float:
        return self._gain

    # ------------------------------------------------------------------ blend maps
    @staticmethod
    def _check_maps(maps: object) -> None:
        if not isinstance(maps, BlendMaps):
            raise ValueError(f"blend maps must be a BlendMaps, got {type(maps).__name__}")

    def _blend_texture(self, maps: BlendMaps) -> tuple[str, Any]:
        return maps.blend_id, blend_texture(self.ctx, self._mgl, maps, self._max_texture)

    def load_blend(self, maps: BlendMaps) -> None:
        """Upload blend maps ahead of the frame that first shows them (:meth:`set_blend` then switches
        without a transfer). One set is kept ahead: loading another releases it. ValueError if the maps
        are not a :class:`~protos.blend.BlendMaps` or exceed the GPU's texture size."""
        self._check_maps(maps)
        if self._blend_ahead is not None and self._blend_ahead[0] == maps.blend_id:
            return
        if self._blend is not None and self._blend[0] == maps.blend_id:
            return
        entry = self._blend_texture(maps)
        if self._blend_ahead is not None:
            self._blend_ahead[1].release()
        self._blend_ahead = entry

    def set_blend(self, maps: BlendMaps | None) -> None:
        """Render with ``maps`` from the next frame on (None: no blend, the output as without one,
        bit for bit). Maps loaded ahead under the same blend id are used without a transfer; the
        maps replaced are released.

        Parameters
        ----------
        maps : BlendMaps or None
            ``alpha`` (h, w, 3) and ``beta`` (h, w) on a grid over this renderer's output
            (:mod:`protos.blend`), held as float16.
        """
        if maps is not None:
            self._check_maps(maps)
        if maps is None:
            new = None
        elif self._blend is not None and self._blend[0] == maps.blend_id:
            return
        elif self._blend_ahead is not None and self._blend_ahead[0] == maps.blend_id:
            new, self._blend_ahead = self._blend_ahead, None
        else:
            new = self._blend_texture(maps)
        if self._blend is not None:
            self._blend[1].release()
        self._blend = new
        self._update_blend_uniforms()

    @property
    def blend_id(self) -> str:
        """The id of the blend maps in use ("" none)."""
        return self._blend[0] if self._blend is not None else ""

    def _update_blend_uniforms(self) -> None:
        """The blend's uniforms (they depend on the output size only)."""
        self._uniforms["blend_xform"] = (1.0 / self._width, 1.0 / self._height)
        self._uniforms["out_rows"] = self._height

    def _bind_blend(self) -> None:
        (self._blend[1] if self._blend is not None else self._blend_none).use(2)

    # ------------------------------------------------------------------ content
    def upload(self, content_id: str, image: np.ndarray) -> None:
        """Upload content once under ``content_id`` (content ids are immutable).

        Parameters
        ----------
        content_id : str
            Non-empty. Uploading an id that is already present does nothing (no GPU
            transfer), provided shape and dtype match; otherwise ValueError (forget it first).
        image : (H, W) or (H, W, C) uint8, uint16, float16 or float32, C in 1..4
            Integers are normalised to [0, 1] (/255, /65535); floats are linear values.
            C = 1 (grey) is replicated to RGB; C = 2 is grey + alpha, C = 4 RGBA: alpha is ignored.
        """
        if not isinstance(content_id, str) or not content_id:
            raise ValueError(f"content_id must be a non-empty string, got {content_id!r}")
        if isinstance(image, YuvFrame):
            self._upload_yuv(content_id, image)
            return
        arr = np.asarray(image)
        if arr.ndim == 2:
            arr = arr[:, :, None]
        if arr.ndim != 3 or not 1 <= arr.shape[2] <= 4:
            raise ValueError(f"content must be (H, W) or (H, W, C) with C in 1..4, got shape {np.shape(image)}")
        if arr.dtype not in _TEXTURE_DTYPES:
            raise ValueError(f"content dtype must be uint8, uint16, float16 or float32, got {arr.dtype}")
        h, w, c = arr.shape
        if not (1 <= w <= self._max_texture and 1 <= h <= self._max_texture):
            raise ValueError(f"content size {w}x{h} is outside 1..{self._max_texture} pixels per side")
        existing = self._contents.get(content_id)
        if existing is not None:
            if existing.shape == arr.shape and existing.dtype == arr.dtype:
                return
            raise ValueError(
                f"content {content_id!r} is already uploaded as {existing.shape} {existing.dtype}, "
                f"not {arr.shape} {arr.dtype}; content ids are immutable (forget() it first)"
            )
        data, gl_dtype = np.ascontiguousarray(arr), _TEXTURE_DTYPES[arr.dtype]
        if gl_dtype == "nu2" and not self._norm16:
            data, gl_dtype = self._norm16_as_float(data), "f4"
        spare = self._spare.pop((arr.shape, arr.dtype), None)
        if spare is not None:      # a forgotten texture of this size and type: write into it
            tex = spare
            tex.write(data, alignment=1)
        else:
            tex = self.ctx.texture((w, h), c, data, dtype=gl_dtype, alignment=1)
            tex.filter = (self._mgl.NEAREST, self._mgl.NEAREST)
            tex.repeat_x = tex.repeat_y = False
        self._contents[content_id] = _Content(tex, arr.shape, arr.dtype, c <= 2)

    def _upload_yuv(self, content_id: str, frame: YuvFrame) -> None:
        """A video frame's planes as textures, converted to RGB in the shader (:mod:`protos.yuv`);
        drawn at ``frame.content_size``: the warp scales the planes to it."""
        lw, lh = frame.luma_size
        if not (1 <= lw <= self._max_texture and 1 <= lh <= self._max_texture):
            raise ValueError(f"content size {lw}x{lh} is outside 1..{self._max_texture} pixels per side")
        shape, dtype = frame.planes[0].shape, frame.planes[0].dtype
        existing = self._contents.get(content_id)
        if existing is not None:
            if existing.yuv is not None and existing.yuv.key == layout_key(frame):
                return
            raise ValueError(f"content {content_id!r} is already uploaded as another picture; content ids are "
                             "immutable (forget() it first)")
        spare = self._spare_yuv
        if spare is not None and spare.key == layout_key(frame) and spare.interleaved == (
                self.interleave_chroma and frame.layout == "planar"):
            planes, self._spare_yuv = self._spare_yuv, None
            planes.refill(frame)
        else:
            if frame.bits > 8 and not self._norm16 and not self._norm16_note_logged:
                self._norm16_as_float(np.zeros((1, 1), np.uint16))   # logs the note once
            planes = YuvTextures(frame, self._plane_texture, self._norm16, self.interleave_chroma)
        self._contents[content_id] = _Content(planes.textures[0], shape, dtype, False, planes)

    def _plane_texture(self, data: np.ndarray) -> Any:
        """One plane's texture: (h, w) or (h, w, 2) uint8, uint16 or float32 (unfiltered, unrepeated)."""
        h, w = data.shape[:2]
        comps = 1 if data.ndim == 2 else data.shape[2]
        tex = self.ctx.texture((w, h), comps, np.ascontiguousarray(data), dtype=_TEXTURE_DTYPES[data.dtype],
                               alignment=1)
        tex.filter = (self._mgl.NEAREST, self._mgl.NEAREST)
        tex.repeat_x = tex.repeat_y = False
        return tex

    def _norm16_as_float(self, data: np.ndarray) -> np.ndarray:
        """(H, W, C) uint16 -> float32 / 65535, for a context without 16-bit normalised textures."""
        if not self._norm16_note_logged:
            self._norm16_note_logged = True
            log.info("this OpenGL ES has no 16-bit normalised textures (GL_EXT_texture_norm16): 16-bit content is "
                     "uploaded as float32, same precision, twice the GPU memory")
        out = data.astype(np.float32)
        out /= np.float32(65535.0)   # correctly rounded, as GL's c / (2^16 - 1)
        return out

    def forget(self, content_id: str, *, reuse: bool = True) -> None:
        """Release the content uploaded under ``content_id`` (no error if unknown).

        The last texture forgotten of each size and type is kept for the next upload of that
        size and type (a video's frames, one after the other, reuse one texture instead of
        allocating one per frame); the others are released. ``reuse=False`` releases it (content
        drawn once, such as a warm-up picture: a 1080p RGB texture kept for nothing is 8 MB).
        """
        entry = self._contents.pop(content_id, None)
        if entry is not None and not reuse:
            entry.yuv.release() if entry.yuv is not None else entry.texture.release()
        elif entry is not None and entry.yuv is not None:
            if self._spare_yuv is not None:
                self._spare_yuv.release()
            self._spare_yuv = entry.yuv
        elif entry is not None:
            old = self._spare.pop((entry.shape, entry.dtype), None)
            if old is not None:
                old.release()
            if len(self._spare) >= self.SPARE_TEXTURES:
                self._spare.pop(next(iter(self._spare))).release()
            self._spare[(entry.shape, entry.dtype)] = entry.texture

    def has(self, content_id: str) -> bool:
        return content_id in self._contents

    @property
    def content_ids(self) -> tuple[str, ...]:
        """Ids currently uploaded, oldest first."""
        return tuple(self._contents)

    # ------------------------------------------------------------------ drawing
    def render(self, content_id: str | None, *, space: str = "content", apply_lut: bool = True,
               fade: tuple[str, float] | None = None) -> None:
        """Draw one frame into :attr:`framebuffer` (one draw call).

        Parameters
        ----------
        content_id : str or None
            Uploaded content to show; None or "" renders black.
        space : {"content", "projector"}
            ``content``: warp through the pose (black without a pose). ``projector``:
            the content already is in projector pixels and must be exactly
            ``width`` x ``height`` (ValueError otherwise).
        apply_lut : bool
            True: value = LUT(clamp(gain * value)), or with blend maps LUT(clamp(gain * (alpha *
            value + beta))) dithered; False: value = clamp(value) (no gain, no LUT, no blend; e.g.
            calibration patterns).
        fade : (str, float), optional
            A crossfade's step: ``(before_id, m)`` mixes the uploaded content ``before_id`` ("":
            black) into this frame's, ``before * (1 - m) + content * m`` on the linear values
            before the gain, blend and LUT (:func:`protos.fade.mix_reference`). Content space
            only; ``before_id`` must have the pose's content size (ValueError otherwise).
        """
        if space not in SPACES:
            raise ValueError(f"space must be one of {SPACES}, got {space!r}")
        fbo = self._fbo
        fbo.use()
        if not content_id:
            fbo.clear(0.0, 0.0, 0.0, 1.0, depth=1.0)
            return
        entry = self._contents.get(content_id)
        if entry is None:
            raise KeyError(f"content {content_id!r} is not uploaded (upload() it first; it may have been forgotten)")
        if space == "projector":
            if entry.size != (self._width, self._height):
                raise ValueError(
                    f"projector-space content is {entry.size[0]}x{entry.size[1]} but the output is "
                    f"{self._width}x{self._height}; they must match"
                )
            self._set_fade(None)
            self._draw_warp(entry, self._warp_identity_bytes, apply_lut, None)
            return
        if self._pose is None:
            fbo.clear(0.0, 0.0, 0.0, 1.0, depth=1.0)
            return
        fade_from = self._set_fade(fade)
        if self._pose[0] == "homography":
            if entry.size != self._pose_content_size:
                cw, ch = self._pose_content_size
                raise ValueError(
                    f"content {content_id!r} is {entry.size[0]}x{entry.size[1]} but the homography pose "
                    f"was set for {cw}x{ch} content"
                )
            self._draw_warp(entry, self._warp_pose_bytes, apply_lut, fade_from)
            return
        self._bind_content(entry, mesh=True)
        vao = self._use("mesh", self._variant(entry, apply_lut, fade_from))[3]
        fbo.clear(0.0, 0.0, 0.0, 1.0, depth=1.0)
        self.ctx.enable_only(self._mgl.DEPTH_TEST)
        self.ctx.depth_func = "<"
        try:
            vao.render(self._mgl.TRIANGLES)
        finally:
            self.ctx.enable_only(self._mgl.NOTHING)

    def _variant(self, entry: _Content, apply_lut: bool, fade_from: int | None) -> Variant:
        return Variant.of(entry.kind, fade_from, self._blend is not None, apply_lut)

    def _set_fade(self, fade: tuple[str, float] | None) -> int | None:
        """The fade's uniforms and texture for the next draw; the kind of the picture it starts from
        (BLACK for none), or None without a fade."""
        if fade is None:
            return None
        before_id, m = fade
        if not 0.0 <= float(m) <= 1.0:
            raise ValueError(f"a fade's mix must be in 0..1, got {m!r}")
        before = None
        if before_id:
            before = self._contents.get(before_id)
            if before is None:
                raise KeyError(f"content {before_id!r} to fade from is not uploaded")
            if self._pose_content_size is not None and before.size != self._pose_content_size:
                raise ValueError(f"content {before_id!r} to fade from is {before.size[0]}x{before.size[1]}, "
                                 f"the pose's content is {self._pose_content_size[0]}x{self._pose_content_size[1]}")
        self._uniforms["fade_mix"] = float(m)
        if before is None:
            return BLACK
        before.texture.use(3)
        if before.yuv is not None:
            before.yuv.bind(self._uniforms, "from_", (3, 6, 7),
                            mesh=self._pose is not None and self._pose[0] == "projection")
        return before.kind

    def _bind_content(self, entry: _Content, *, mesh: bool = False) -> None:
        """The content's texture(s), the LUT and the blend maps bound for the next draw, and a YUV
        picture's uniforms set."""
        entry.texture.use(0)
        if entry.yuv is not None:
            entry.yuv.bind(self._uniforms, "", (0, 4, 5), mesh=mesh)
        self._lut_tex.use(1)
        self._bind_blend()

    def _draw_warp(self, entry: _Content, matrix: bytes, apply_lut: bool, fade_from: int | None) -> None:
        self._uniforms["frag_to_content"] = matrix
        self._bind_content(entry)
        vao = self._use("warp", self._variant(entry, apply_lut, fade_from))[3]
        self.ctx.enable_only(self._mgl.NOTHING)
        vao.render(self._mgl.TRIANGLES, vertices=3)

    def warm_up(self) -> None:
        """Compile the shader variants a node draws most and draw each once, into a 2x2 corner of
        the framebuffer (then cleared), so that the driver compiles them now (llvmpipe JITs a
        program at its first draw, per texture format: ~0.1 s and several MB each), not while a
        frame waits for its deadline: :data:`WARM_VARIANTS`, on 8-bit content (planar YUV as the kind it
        draws as: semi-planar where its chroma is interleaved, :attr:`interleave_chroma`). Others compile at
        their first draw. The pose, blend maps, LUT and uploaded content are left as they were."""
        def picture(kind: int) -> _Content:
            if kind in (RGB, GREY):
                shape = (2, 2, 3) if kind == RGB else (2, 2, 1)
                tex = self.ctx.texture((2, 2), shape[2], np.zeros(shape, np.uint8), dtype="f1", alignment=1)
                return _Content(tex, shape, np.dtype(np.uint8), kind == GREY)
            y, c = np.zeros((2, 2), np.uint8), np.full((1, 1), 128, np.uint8)
            planes = (y, c, c) if kind == YUV_PLANAR else (y, np.full((1, 1, 2), 128, np.uint8))
            frame = YuvFrame(planes=planes, layout="planar" if kind == YUV_PLANAR else "semiplanar")
            yuv = YuvTextures(frame, self._plane_texture, self._norm16, self.interleave_chroma)
            return _Content(yuv.textures[0], (2, 2), np.dtype(np.uint8), False, yuv)

        pictures = {kind: picture(kind) for kind in (RGB, GREY, YUV_PLANAR, YUV_SEMIPLANAR)}
        # a planar picture draws as the kind its textures are (semi-planar where its chroma is interleaved):
        # the programs compiled are those its frames will use, each once
        drawn: dict[Variant, Variant] = {}
        for v in WARM_VARIANTS:
            fade = v.fade_from if v.fade_from in (None, BLACK) else pictures[v.fade_from].kind
            drawn.setdefault(Variant.of(pictures[v.content].kind, fade, v.blend, v.apply_lut), v)
        saved = dict(self._uniforms)
        fbo = self._fbo
        try:
            fbo.viewport = (0, 0, 2, 2)
            fbo.use()
            self._uniforms.update(frag_to_content=_mat_bytes(np.eye(3)), fade_mix=0.5)
            self.ctx.enable_only(self._mgl.NOTHING)
            for d, v in drawn.items():
                if v.fade_from is not None and v.fade_from != BLACK:
                    before = pictures[v.fade_from]
                    before.texture.use(3)
                    if before.yuv is not None:
                        before.yuv.bind(self._uniforms, "from_", (3, 6, 7))
                self._bind_content(pictures[v.content])
                self._use("warp", d)[3].render(self._mgl.TRIANGLES, vertices=3)
        finally:
            self._uniforms.clear()
            self._uniforms.update(saved)
            fbo.viewport = (0, 0, self._width, self._height)
            fbo.use()
            fbo.clear(0.0, 0.0, 0.0, 1.0, depth=1.0)
            for entry in pictures.values():
                if entry.yuv is not None:
                    entry.yuv.release()
                else:
                    entry.texture.release()

    def read(self) -> np.ndarray:
        """What the projector receives: (height, width, 3) uint8 RGB, row 0 at the top.

        The returned array is the renderer's own buffer, overwritten by the next
        :meth:`read` (and reallocated by :meth:`resize`): copy it to keep it. Read a strip of rows
        at a time (:mod:`node.render.readback`): no second full-size copy.
        """
        return self._readback.read(self._fbo)

    def read_rows(self, top: int, rows: int) -> np.ndarray:
        """Rows ``top`` to ``top + rows - 1`` of what :meth:`read` returns, read back alone (a
        preview reads a band at a time, never holding the full-size picture): (rows, width, 3) uint8
        RGB, a view of a buffer overwritten by the next call. ValueError outside the output."""
        return self._readback.rows(self._fbo, top, rows)

    # ------------------------------------------------------------------ teardown
    def release(self) -> None:
        """Release every GL object (and the context, for :meth:`standalone`). Idempotent."""
        if self._released:
            return
        self._released = True
        for entry in self._contents.values():
            if entry.yuv is not None:
                entry.yuv.release()
            else:
                entry.texture.release()
        self._contents.clear()
        if self._spare_yuv is not None:
            self._spare_yuv.release()
            self._spare_yuv = None
        for tex in self._spare.values():
            tex.release()
        self._spare.clear()
        for entry in (self._blend, self._blend_ahead):
            if entry is not None:
                entry[1].release()
        self._blend = self._blend_ahead = None
        self._blend_none.release()
        for prog, _, _, vao in self._programs.values():
            if vao is not None:
                vao.release()
            prog.release()
        self._programs.clear()
        for obj in (self._mesh_vbo, self._mesh_ibo, self._lut_tex, self._fbo, self._color, self._depth):
            if obj is not None:
                obj.release()
        if self._owns_ctx:
            self.ctx.release()

    def __enter__(self) -> "Renderer":
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
