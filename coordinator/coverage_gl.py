"""OpenGL rasterisation of a mesh for the coverage map (moderngl on a standalone EGL context).

Three passes, each a few lines of GLSL kept here beside the numpy that reads them back:

* **texels** (:meth:`CoverageRaster.texels`): the mesh drawn in its own UV space, one
  fragment per texel of the content texture whose centre a triangle covers: the world point,
  the interpolated vertex normal and the triangle (``gl_PrimitiveID``) at every texel centre.
  This is how the surface is sampled: one sample per texel the content can paint.
* **depth** (:meth:`CoverageRaster.depth_map`): the mesh seen from a projector's pinhole, each
  pixel holding the nearest depth along the projector's axis (mm): a shadow map.
* **view** (:meth:`CoverageRaster.view`): the mesh seen from any pinhole (the figure's virtual
  camera), each pixel holding the content uv and the normal of the nearest surface.

Window pixel ``(x + 0.5, y + 0.5)`` is image pixel ``(x, y)`` and read-back row 0 is image row 0
(:func:`imaging.calibration.threed.gl_projection`); in UV space read-back row ``i``, column
``j`` is the texel whose centre is uv ``((j + 0.5) / w, (i + 0.5) / h)``, uv (0, 0) being the
content image's top-left corner (the mesh convention).

Use from one thread; :meth:`CoverageRaster.close` when done (or use it as a context manager).
"""
from __future__ import annotations

import numpy as np

from imaging.calibration.errors import CalibrationError
from imaging.calibration.threed import Pinhole, gl_projection
from imaging.egl import standalone_context

_TEXEL_VS = """
#version 330
in vec3 in_position;
in vec3 in_normal;
in vec2 in_uv;
out vec3 v_position;
out vec3 v_normal;
void main() {
    v_position = in_position;
    v_normal = in_normal;
    gl_Position = vec4(in_uv * 2.0 - 1.0, 0.0, 1.0);
}
"""

_TEXEL_FS = """
#version 330
in vec3 v_position;
in vec3 v_normal;
layout(location = 0) out vec4 out_position;   // xyz world mm, w = 1 where a triangle covers the texel
layout(location = 1) out vec4 out_normal;     // xyz interpolated vertex normal, w = triangle index
void main() {
    out_position = vec4(v_position, 1.0);
    out_normal = vec4(v_normal, float(gl_PrimitiveID));
}
"""

_DEPTH_VS = """
#version 330
uniform mat4 mvp;
uniform vec4 zrow;        // world mm -> depth along the device's axis (mm)
in vec3 in_position;
out float v_depth;
void main() {
    v_depth = dot(zrow, vec4(in_position, 1.0));
    gl_Position = mvp * vec4(in_position, 1.0);
}
"""

_DEPTH_FS = """
#version 330
in float v_depth;
out float out_depth;
void main() {
    out_depth = v_depth;
}
"""

_VIEW_VS = """
#version 330
uniform mat4 mvp;
in vec3 in_position;
in vec3 in_normal;
in vec2 in_uv;
out vec3 v_normal;
out vec2 v_uv;
void main() {
    v_normal = in_normal;
    v_uv = in_uv;
    gl_Position = mvp * vec4(in_position, 1.0);
}
"""

_VIEW_FS = """
#version 330
in vec3 v_normal;
in vec2 v_uv;
layout(location = 0) out vec4 out_uv;         // uv, 0, w = 1 where the mesh is seen
layout(location = 1) out vec4 out_normal;
void main() {
    out_uv = vec4(v_uv, 0.0, 1.0);
    out_normal = vec4(v_normal, 0.0);
}
"""

#: what the depth map holds where no surface is (mm)
NO_DEPTH = 1e30


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3) float32 unit normals, the area-weighted mean of the faces around each vertex.

    Faces wind counter-clockwise seen from outside (the mesh convention); a mesh wound the other
    way round (negative enclosed volume) gets its normals turned outwards all the same.
    """
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])     # length = 2 x area
    if np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() < 0:
        n = -n
    acc = np.zeros_like(v)
    for k in range(3):
        np.add.at(acc, f[:, k], n)
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    return (acc / np.where(norm > 0, norm, 1.0)).astype(np.float32)


def scaled_device(device: Pinhole, scale: int) -> Pinhole:
    """The same optics sampled ``scale`` times finer per axis (pixel centres stay registered:
    ``x' = scale (x + 0.5) - 0.5``)."""
    s = float(scale)
    S = np.array([[s, 0.0, 0.5 * s - 0.5], [0.0, s, 0.5 * s - 0.5], [0.0, 0.0, 1.0]])
    w, h = device.size
    return Pinhole(S @ device.K, device.R, device.t, (w * int(scale), h * int(scale)))


class CoverageRaster:
    """A mesh uploaded once, rasterised in UV space, from projectors (depth) and from viewpoints.

    Parameters
    ----------
    vertices : (V, 3) float32 world mm
    faces : (F, 3) uint32
    uvs : (V, 2) float32 in [0, 1], (0, 0) the content's top-left corner
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray):
        v = np.ascontiguousarray(vertices, np.float32)
        f = np.ascontiguousarray(faces, np.uint32)
        uv = np.ascontiguousarray(uvs, np.float32)
        if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or uv.shape != (len(v), 2):
            raise ValueError(f"need vertices (V, 3), faces (F, 3), uvs (V, 2); got {v.shape}, {f.shape}, {uv.shape}")
        self.vertices, self.faces, self.uvs = v, f, uv
        self.normals = vertex_normals(v, f)
        self.ctx = standalone_context(CalibrationError, "coverage")
        try:
            data = np.hstack([v, self.normals, uv]).astype("f4")
            self._vbo = self.ctx.buffer(data.tobytes())
            self._ibo = self.ctx.buffer(f.tobytes())
            self._tprog = self.ctx.program(vertex_shader=_TEXEL_VS, fragment_shader=_TEXEL_FS)
            self._dprog = self.ctx.program(vertex_shader=_DEPTH_VS, fragment_shader=_DEPTH_FS)
            self._vprog = self.ctx.program(vertex_shader=_VIEW_VS, fragment_shader=_VIEW_FS)
            layout = [(self._vbo, "3f 3f 2f", "in_position", "in_normal", "in_uv")]
            self._tvao = self.ctx.vertex_array(self._tprog, layout, self._ibo)
            self._dvao = self.ctx.vertex_array(self._dprog, [(self._vbo, "3f 20x", "in_position")], self._ibo)
            self._vvao = self.ctx.vertex_array(self._vprog, layout, self._ibo)
        except Exception:
            self.close()
            raise

    def _near_far(self, device: Pinhole) -> tuple[float, float] | None:
        depth = self.vertices.astype(np.float64) @ device.R[2] + device.t[2]
        if depth.max() <= 1.0:
            return None
        near = max(1.0, 0.9 * float(depth[depth > 1.0].min()))
        return near, max(1.1 * float(depth.max()) + 10.0, 1.5 * near)

    def _read(self, fbo, attachment: int, components: int, size: tuple[int, int]) -> np.ndarray:
        w, h = size
        raw = fbo.read(components=components, attachment=attachment, dtype="f4")
        return np.frombuffer(raw, np.float32).reshape(h, w, components).copy()

    def texels(self, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The surface at every texel centre of a ``size`` = (w, h) texture.

        Returns
        -------
        points : (h, w, 3) float32 world mm (0 where no triangle covers the texel)
        normals : (h, w, 3) float32 unit interpolated vertex normals
        face : (h, w) int64 triangle index, -1 where no triangle covers the texel
        hit : (h, w) bool
        """
        w, h = int(size[0]), int(size[1])
        tex = [self.ctx.texture((w, h), 4, dtype="f4") for _ in range(2)]
        fbo = self.ctx.framebuffer(color_attachments=tex)
        try:
            fbo.use()
            fbo.clear(0.0, 0.0, 0.0, 0.0)
            self.ctx.disable(self.ctx.DEPTH_TEST)
            self.ctx.disable(self.ctx.CULL_FACE)
            self._tvao.render()
            pos = self._read(fbo, 0, 4, (w, h))
            nrm = self._read(fbo, 1, 4, (w, h))
        finally:
            fbo.release()
            for t in tex:
                t.release()
        hit = pos[..., 3] > 0.5
        n = nrm[..., :3]
        length = np.linalg.norm(n, axis=-1, keepdims=True)
        n = np.where(length > 0, n / np.maximum(length, 1e-12), 0.0).astype(np.float32)
        face = np.where(hit, np.rint(nrm[..., 3]).astype(np.int64), -1)
        return pos[..., :3], n, face, hit

    def depth_map(self, device: Pinhole) -> np.ndarray:
        """(h, w) float32: the nearest mesh depth (mm along the device's axis) per pixel of
        ``device``; :data:`NO_DEPTH` where the mesh is not seen."""
        w, h = device.size
        planes = self._near_far(device)
        if planes is None:
            return np.full((h, w), NO_DEPTH, np.float32)
        tex = self.ctx.texture((w, h), 1, dtype="f4")
        rb = self.ctx.depth_renderbuffer((w, h))
        fbo = self.ctx.framebuffer(color_attachments=[tex], depth_attachment=rb)
        try:
            fbo.use()
            fbo.clear(NO_DEPTH, 0.0, 0.0, 0.0, depth=1.0)
            self.ctx.enable(self.ctx.DEPTH_TEST)
            self.ctx.disable(self.ctx.CULL_FACE)
            self._dprog["mvp"].write(gl_projection(device, near=planes[0], far=planes[1]).T.astype("f4").tobytes())
            self._dprog["zrow"].write(np.append(device.R[2], device.t[2]).astype("f4").tobytes())
            self._dvao.render()
            out = self._read(fbo, 0, 1, (w, h))[..., 0]
        finally:
            fbo.release()
            rb.release()
            tex.release()
        return out

    def view(self, device: Pinhole) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What each pixel of ``device`` sees of the mesh.

        Returns
        -------
        uv : (h, w, 2) float32 content uv of the nearest surface
        normals : (h, w, 3) float32 its interpolated normal (not renormalised)
        hit : (h, w) bool
        """
        w, h = device.size
        planes = self._near_far(device)
        if planes is None:
            return np.zeros((h, w, 2), np.float32), np.zeros((h, w, 3), np.float32), np.zeros((h, w), bool)
        tex = [self.ctx.texture((w, h), 4, dtype="f4") for _ in range(2)]
        rb = self.ctx.depth_renderbuffer((w, h))
        fbo = self.ctx.framebuffer(color_attachments=tex, depth_attachment=rb)
        try:
            fbo.use()
            fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
            self.ctx.enable(self.ctx.DEPTH_TEST)
            self.ctx.disable(self.ctx.CULL_FACE)
            self._vprog["mvp"].write(gl_projection(device, near=planes[0], far=planes[1]).T.astype("f4").tobytes())
            self._vvao.render()
            uv = self._read(fbo, 0, 4, (w, h))
            nrm = self._read(fbo, 1, 4, (w, h))
        finally:
            fbo.release()
            rb.release()
            for t in tex:
                t.release()
        return uv[..., :2], nrm[..., :3], uv[..., 3] > 0.5

    def close(self) -> None:
        ctx = getattr(self, "ctx", None)
        if ctx is not None:
            ctx.release()
            self.ctx = None

    def __enter__(self) -> "CoverageRaster":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
