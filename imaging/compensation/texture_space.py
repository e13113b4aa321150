"""Where texture, projector and camera pixels meet on a 3D object (a mesh rig).

On a mesh the content is the mesh's texture: content pixel ``(x, y)`` is the texel at
``uv = ((x + 0.5) / W, (y + 0.5) / H)``, uv ``(0, 0)`` the content's top-left corner. Two
renderings of the mesh (moderngl through EGL, like
:class:`imaging.calibration.threed.SurfaceCaster`) replace the planar rig's homographies:

* :meth:`MeshCaster.view`: the mesh seen through a device's 3x4 projection (a posed camera, or a
  projector's pose): per pixel the uv it sees, its depth and the cosine of the viewing angle
  (:class:`DeviceView`). For a camera this is the texture -> camera correspondence the target
  and the row weights come from; for a projector it is what the node's mesh shader samples
  (``node/render/mesh.*.glsl``: the content at ``uv * (W, H) - 0.5``, bilinear, the nearest
  surface only), so :func:`mesh_warp` computes a node's output for a mesh pose with numpy.
* :meth:`MeshCaster.atlas`: the mesh rasterised in texture space: the world point of every
  texel centre (NaN where no triangle covers it). Projected into a camera and compared with that
  camera's depth, it gives each texel's camera position and whether the camera sees it
  (:func:`texel_camera_map`), which places the light-transport windows.

A node samples texels bilinearly, so near the edge of a uv chart it reads texels no triangle
covers. Those are filled with their nearest chart texel (:func:`padding_index`, :func:`padded`:
a texture baker's edge padding) in every image sent to the nodes, dot patterns included, so a
texel's measured light holds its padding's and the edges show what the solve computed.

Both renderings use the node's pixel convention: pixel centres at integer coordinates,
``P`` scaled so that its third row gives the depth in mm.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from imaging.compensation.errors import CompensationError
from protos.spaces import as_linear, bilinear_taps, lut_lookup
from imaging.egl import standalone_context

__all__ = ["DeviceView", "TexelMap", "MeshCaster", "normalised_projection", "device_centre", "texel_camera_map",
           "content_at_view", "mesh_warp", "texels_per_pixel", "padding_index", "padded"]

_VIEW_VS = """
#version 330
uniform mat4 world_to_clip;
uniform vec4 depth_row;     // dot(depth_row, (X, 1)) = depth along the device's axis, mm
in vec3 in_position;        // world mm
in vec2 in_uv;
out vec2 v_uv;
out vec3 v_pos;
out float v_depth;
void main() {
    gl_Position = world_to_clip * vec4(in_position, 1.0);
    v_uv = in_uv;            // perspective-correct, as the node's mesh shader
    v_pos = in_position;
    v_depth = dot(depth_row, vec4(in_position, 1.0));
}
"""
_VIEW_FS = """
#version 330
uniform vec3 centre;        // the device's centre of projection, world mm
in vec2 v_uv;
in vec3 v_pos;
in float v_depth;
out vec4 out_view;          // u, v, depth (mm, > 0 on the mesh), cos(viewing angle)
void main() {
    vec3 n = normalize(cross(dFdx(v_pos), dFdy(v_pos)));   // the triangle's normal
    out_view = vec4(v_uv, v_depth, abs(dot(n, normalize(centre - v_pos))));
}
"""
_ATLAS_VS = """
#version 330
in vec3 in_position;
in vec2 in_uv;
out vec3 v_pos;
void main() {
    gl_Position = vec4(2.0 * in_uv - 1.0, 0.0, 1.0);   // read back, row y is content row y
    v_pos = in_position;
}
"""
_ATLAS_FS = """
#version 330
in vec3 v_pos;
out vec4 out_point;         // world mm of the texel centre, 1 where a triangle covers it
void main() {
    out_point = vec4(v_pos, 1.0);
}
"""


@dataclass(frozen=True, eq=False)
class DeviceView:
    """The mesh as one device (camera or projector) sees it; every array ``(h, w)`` float32.

    ``x, y``: content coordinates (texels, centres at integers) of the surface each pixel sees
    (``u * W - 0.5``, ``v * H - 0.5``; NaN off the mesh); ``depth``: mm along the device's axis
    (0 off the mesh); ``cos``: cosine of the angle between the surface normal and the ray to the
    device (0 off the mesh).
    """

    x: np.ndarray
    y: np.ndarray
    depth: np.ndarray
    cos: np.ndarray

    @property
    def on_mesh(self) -> np.ndarray:
        """(h, w) bool: pixels that see the mesh."""
        return self.depth > 0

    @property
    def shape(self) -> tuple[int, int]:
        return self.depth.shape


@dataclass(frozen=True, eq=False)
class TexelMap:
    """Where each texel lies in one camera (:func:`texel_camera_map`); ``n = W * H`` texels, row-major.

    ``position``: (n, 2) float64 camera ``(X, Y)`` of the texel centre (NaN where not on the mesh);
    ``visible``: (n,) bool, the camera sees the texel (nearest surface, inside the image, facing it
    at ``cos >= min_cos``); ``cos``: (n,) float32 cosine of its viewing angle (0 where not visible).
    """

    position: np.ndarray
    visible: np.ndarray
    cos: np.ndarray
    on_mesh: np.ndarray

    def at_least(self, min_cos: float) -> TexelMap:
        """The same map with texels seen more obliquely than ``min_cos`` counted as not seen: what
        :func:`texel_camera_map` gives with that ``min_cos`` when this map's is lower."""
        visible = self.visible & (self.cos >= min_cos)
        return TexelMap(self.position, visible, np.where(visible, self.cos, 0).astype(np.float32), self.on_mesh)


def normalised_projection(P: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """``P`` (3, 4) scaled so that its third row gives the depth in mm, the mesh in front (as the node does).

    Raises
    ------
    CompensationError
        If ``P`` has no depth axis.
    """
    pm = np.asarray(P, np.float64)
    if pm.shape != (3, 4) or not np.all(np.isfinite(pm)):
        raise CompensationError(f"a projection must be a finite (3, 4) matrix, got {pm.shape}")
    axis = float(np.linalg.norm(pm[2, :3]))
    if axis == 0:
        raise CompensationError("a projection needs a depth axis (its third row starts with zeros)")
    pm = pm / axis
    depth = np.asarray(vertices, np.float64) @ pm[2, :3] + pm[2, 3]
    return -pm if np.median(depth) < 0 else pm


def device_centre(P: np.ndarray) -> np.ndarray:
    """The centre of projection ``C`` (3,) float64 of ``P`` (``P (C, 1) = 0``)."""
    pm = np.asarray(P, np.float64)
    return -np.linalg.solve(pm[:, :3], pm[:, 3])


def _clip(pm: np.ndarray, size: tuple[int, int], near: float, far: float) -> np.ndarray:
    """(4, 4) world -> clip: NDC x = 2 (px + 0.5) / w - 1, NDC y = 2 (py + 0.5) / h - 1 (read back, row 0 is
    image row 0), the depth range [near, far] mm; the node's mapping without its vertical flip."""
    w, h = size
    x, y, d = pm
    clip = np.empty((4, 4))
    clip[0] = (2.0 * x + d) / w - d
    clip[1] = (2.0 * y + d) / h - d
    clip[2] = (far + near) / (far - near) * d
    clip[2, 3] -= 2.0 * far * near / (far - near)
    clip[3] = d
    return clip


class MeshCaster:
    """Renders a textured mesh's uv, depth and viewing angle (:meth:`view`) and its texel atlas (:meth:`atlas`).

    Parameters
    ----------
    vertices : (V, 3) float world mm
    uvs : (V, 2) float in [0, 1], (0, 0) the content's top-left corner
    faces : (F, 3) int

    Use from one thread; :meth:`close` when done (or use as a context manager).
    """

    def __init__(self, vertices: np.ndarray, uvs: np.ndarray, faces: np.ndarray):
        v = np.ascontiguousarray(vertices, np.float32)
        uv = np.ascontiguousarray(uvs, np.float32)
        f = np.ascontiguousarray(faces, np.uint32)
        if v.ndim != 2 or v.shape[1] != 3 or uv.shape != (len(v), 2) or f.ndim != 2 or f.shape[1] != 3:
            raise ValueError(f"mesh must be vertices (V, 3), uvs (V, 2), faces (F, 3); got {v.shape}, {uv.shape}, "
                             f"{f.shape}")
        self.vertices = v
        self.ctx = standalone_context(CompensationError, "compensation on a mesh")
        try:
            self._view = self.ctx.program(vertex_shader=_VIEW_VS, fragment_shader=_VIEW_FS)
            self._atlas = self.ctx.program(vertex_shader=_ATLAS_VS, fragment_shader=_ATLAS_FS)
            self._vbo = self.ctx.buffer(np.column_stack([v, uv]).astype("f4").tobytes())
            self._ibo = self.ctx.buffer(f.tobytes())
            self._view_vao = self.ctx.vertex_array(self._view, [(self._vbo, "3f 2f", "in_position", "in_uv")],
                                                   self._ibo, index_element_size=4)
            self._atlas_vao = self.ctx.vertex_array(self._atlas, [(self._vbo, "3f 2f", "in_position", "in_uv")],
                                                    self._ibo, index_element_size=4)
        except Exception:
            self.close()
            raise

    def _render(self, vao, size: tuple[int, int], *, depth_test: bool) -> np.ndarray:
        w, h = size
        tex = self.ctx.texture((w, h), 4, dtype="f4")
        rb = self.ctx.depth_renderbuffer((w, h))
        fbo = self.ctx.framebuffer(color_attachments=[tex], depth_attachment=rb)
        try:
            fbo.use()
            fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
            self.ctx.enable_only(self.ctx.DEPTH_TEST if depth_test else self.ctx.NOTHING)
            vao.render()
            return np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(h, w, 4).copy()
        finally:
            fbo.release()
            rb.release()
            tex.release()

    def view(self, P: np.ndarray, size: tuple[int, int], content_size: tuple[int, int], *, near: float = 10.0,
             far: float = 20_000.0) -> DeviceView:
        """The mesh through projection ``P`` (3, 4) (world mm -> pixels) into a ``size`` (w, h) image.

        ``near``/``far``: the depth range rendered (mm), as a node's pose clips it.
        """
        w, h = (int(v) for v in size)
        if w < 1 or h < 1 or not 0 < near < far:
            raise ValueError(f"need a positive size and 0 < near < far, got {size}, {near}, {far}")
        pm = normalised_projection(P, self.vertices)
        self._view["world_to_clip"].write(_clip(pm, (w, h), near, far).T.astype("f4").tobytes())
        self._view["depth_row"].value = tuple(float(v) for v in pm[2])
        self._view["centre"].value = tuple(float(v) for v in device_centre(pm))
        out = self._render(self._view_vao, (w, h), depth_test=True)
        depth = out[..., 2]
        on = depth > 0
        cw, ch = content_size
        x = np.where(on, out[..., 0] * np.float32(cw) - np.float32(0.5), np.nan).astype(np.float32)
        y = np.where(on, out[..., 1] * np.float32(ch) - np.float32(0.5), np.nan).astype(np.float32)
        return DeviceView(x, y, np.where(on, depth, 0).astype(np.float32), np.where(on, out[..., 3], 0).astype(np.float32))

    def atlas(self, content_size: tuple[int, int]) -> np.ndarray:
        """World point of every texel centre: ``(H, W, 3) float64`` mm, NaN where no triangle covers it."""
        w, h = (int(v) for v in content_size)
        out = self._render(self._atlas_vao, (w, h), depth_test=False)
        pts = out[..., :3].astype(np.float64)
        pts[out[..., 3] < 0.5] = np.nan
        return pts

    def close(self) -> None:
        ctx = getattr(self, "ctx", None)
        if ctx is not None:
            ctx.release()
            self.ctx = None

    def __enter__(self) -> MeshCaster:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def texel_camera_map(atlas: np.ndarray, P: np.ndarray, view: DeviceView, *, min_cos: float = 0.25,
                     depth_tolerance_mm: float = 2.0) -> TexelMap:
    """Each texel's camera position and whether the camera sees it.

    Parameters
    ----------
    atlas : (H, W, 3) float64
        World point per texel (:meth:`MeshCaster.atlas`).
    P : (3, 4) float
        The camera's projection (world mm -> camera px).
    view : DeviceView
        The camera's view of the same mesh (:meth:`MeshCaster.view`).
    min_cos : float
        Texels seen more obliquely (cosine of the viewing angle below it) count as not seen.
    depth_tolerance_mm : float
        A texel is the surface the camera sees when its depth matches the camera's depth at its
        pixel within this, plus the depth's change over one pixel there (a shadow-map test).
    """
    pts = atlas.reshape(-1, 3)
    on = np.isfinite(pts).all(axis=1)
    pm = np.asarray(P, np.float64)
    pm = pm / np.linalg.norm(pm[2, :3])
    q = np.where(on[:, None], pts, 0.0) @ pm[:, :3].T + pm[:, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        pos = q[:, :2] / q[:, 2:3]
    depth = np.abs(q[:, 2]) if np.median(q[on, 2]) < 0 else q[:, 2]
    hc, wc = view.shape
    X = np.rint(pos[:, 0])
    Y = np.rint(pos[:, 1])
    inside = on & np.isfinite(X) & np.isfinite(Y) & (X >= 0) & (X < wc) & (Y >= 0) & (Y < hc) & (depth > 0)
    ix = np.where(inside, X, 0).astype(np.int64)
    iy = np.where(inside, Y, 0).astype(np.int64)
    dmap = view.depth.astype(np.float64)
    gy, gx = np.gradient(np.where(dmap > 0, dmap, np.nan))
    slope = np.nan_to_num(np.hypot(gx, gy), nan=np.inf)
    seen_depth = dmap[iy, ix]
    cos = view.cos[iy, ix]
    visible = inside & (seen_depth > 0) & (np.abs(depth - seen_depth) <= depth_tolerance_mm + slope[iy, ix]) \
        & (cos >= min_cos)
    position = np.where(on[:, None], pos, np.nan)
    return TexelMap(position, visible, np.where(visible, cos, 0).astype(np.float32), on)


def texels_per_pixel(view: DeviceView) -> np.ndarray:
    """Texture area each pixel of a view covers, in texels: ``|det d(x, y) / d(X, Y)|``, ``(h, w) float32``
    (central differences; NaN off the mesh and where a neighbour is off it or across a uv seam)."""
    gxy = np.gradient(view.x.astype(np.float64))
    gyy = np.gradient(view.y.astype(np.float64))
    det = np.abs(gxy[1] * gyy[0] - gxy[0] * gyy[1])
    return det.astype(np.float32)


def content_at_view(content: np.ndarray, view: DeviceView) -> np.ndarray:
    """The content as a device sees it on the mesh, blur-free: ``(h, w, C) float32`` (0 off the mesh).

    ``content`` is ``(H, W)`` or ``(H, W, C)`` linear; sampled bilinearly at each pixel's texel
    coordinates (texels outside the content count as 0, as the node samples them).
    """
    img = as_linear(content)
    if img.ndim == 2:
        img = img[:, :, None]
    mx = np.nan_to_num(view.x, nan=-10.0).astype(np.float32)
    my = np.nan_to_num(view.y, nan=-10.0).astype(np.float32)
    out = cv2.remap(img, mx, my, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    if out.ndim == 2:
        out = out[:, :, None]
    return np.ascontiguousarray(out, dtype=np.float32)


def mesh_warp(content: np.ndarray, view: DeviceView, *, lut: np.ndarray | None = None, gain: float = 1.0,
              apply_lut: bool = True) -> np.ndarray:
    """What a node with a mesh pose outputs for ``content``: ``(h, w, 3) uint8``, computed with numpy.

    ``view`` is the mesh through the node's pose at its projector size (:meth:`MeshCaster.view`
    with the pose's near/far). Each pixel on the mesh samples the content bilinearly at its texel
    coordinates (:func:`protos.spaces.bilinear_taps`, texels outside count as 0), then gain and
    LUT as :func:`protos.spaces.warp_content`; pixels off the mesh are black (the node clears to 0).
    """
    img = as_linear(content)
    if img.ndim == 2:
        img = img[:, :, None]
    ch, cw = img.shape[:2]
    img = img[:, :, :1] if img.shape[2] < 3 else img[:, :, :3]
    h, w = view.shape
    x = np.nan_to_num(view.x, nan=-10.0)
    y = np.nan_to_num(view.y, nan=-10.0)
    flat = img.reshape(ch * cw, -1)
    out = np.zeros((h * w, flat.shape[1]), np.float64)
    for index, weight in bilinear_taps(x, y, (cw, ch)):
        out += weight[:, None] * flat[index]
    warped = out.reshape(h, w, -1).astype(np.float32)
    if warped.shape[2] == 1:
        warped = np.repeat(warped, 3, axis=2)
    off = ~view.on_mesh
    if not apply_lut:
        frame = np.floor(np.clip(warped, 0, 1) * 255.0 + 0.5).astype(np.uint8)
    else:
        table = np.array([[0.0, 1.0]] * 3, np.float32) if lut is None else np.asarray(lut, np.float32)
        if table.shape[0] == 1:
            table = np.repeat(table, 3, axis=0)
        frame = lut_lookup(table, warped, gain=gain)
    frame[off] = 0
    return frame



def padding_index(on_mesh: np.ndarray, *, reach: float = 2.0) -> np.ndarray:
    """Where each texel takes its value from: ``(H*W,) int64`` flat indices, row-major.

    ``on_mesh`` (H, W) bool: texels a triangle covers (their own index); a texel off the mesh
    within ``reach`` texels of one takes the nearest (Euclidean; ties as SciPy's distance
    transform breaks them); the rest keep their own index.
    """
    m = np.asarray(on_mesh, bool)
    if m.ndim != 2:
        raise ValueError(f"on_mesh must be (H, W), got {m.shape}")
    own = np.arange(m.size, dtype=np.int64)
    if not m.any() or m.all():
        return own
    dist, (iy, ix) = ndimage.distance_transform_edt(~m, return_indices=True)
    src = (iy.astype(np.int64) * m.shape[1] + ix).ravel()
    return np.where(dist.ravel() <= reach, src, own)


def padded(image: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``image`` (H, W) or (H, W, C) with every texel replaced by texel ``index`` (:func:`padding_index`)."""
    a = np.asarray(image)
    h, w = a.shape[:2]
    if index.shape != (h * w,):
        raise ValueError(f"index must be ({h * w},) for a {w}x{h} image, got {index.shape}")
    flat = a.reshape(h * w, *a.shape[2:])
    return np.ascontiguousarray(flat[index].reshape(a.shape))
