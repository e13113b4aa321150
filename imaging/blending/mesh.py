"""A mesh rig's light on the blend's camera grid: where each projector's pixels land, and the part of
its light that the surface's shape sets.

On a mesh the light a projector gives a surface point ``X`` is its lamp's light along the ray
(smooth in the projector's pixels: fall-off, hot spot, brightness, white point) times the
irradiance's geometric factor ``cos(theta) / d^2`` (the angle between the surface's normal and
the ray to the projector, the distance to it), which changes as fast as the surface bends. The
blend measures the first with a few blob samples and takes the second from the geometry.

Both are evaluated where the camera grid's points lie on the surface. The camera's view of the
mesh is rasterised at the grid's own size (:class:`SurfaceRaster`: each grid point's world point
and interpolated vertex normal: the smooth surface the mesh stands for, not its flat facets);
each point is projected through each projector's 3x4 pose, and a shadow-map test against the
projector's own view of the mesh says whether that projector reaches it (:func:`placement`).

Results (:func:`mesh_placement`), all on the grid ``(h, w)``:

* ``xy[slot]``: ``(h, w, 2) float32`` the projector pixel showing each grid point's surface point,
  NaN where the projector does not light it (outside its frame, facing away, hidden by the mesh);
  the :class:`~imaging.blending.contributions.Contributions`' ``projector_xy``;
* ``shading[slot]``: ``(h, w) float32`` ``cos(theta) (1000 mm / d)^2`` times the share of the point's grid
  cell that the projector's drawn pixels light (:func:`placement`'s ``hit``), 0 where not lit;
* ``surface``: ``(h, w) bool`` grid points that see the mesh.

OpenGL (moderngl on EGL) is imported on use; run it from one thread.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from imaging.blending.errors import BlendError
from imaging.blending.mesh_maps import FOOTPRINT_SAMPLES, footprint_points, snap_pixels
from imaging.egl import standalone_context

__all__ = ["SurfaceView", "SurfaceRaster", "MeshPlacement", "vertex_normals", "grid_projection", "placement",
           "mesh_placement", "REFERENCE_MM"]

#: the distance at which ``shading`` is the cosine alone, mm
REFERENCE_MM = 1000.0

_VS = """
#version 330
uniform mat4 world_to_clip;
uniform vec4 depth_row;       // dot(depth_row, (X, 1)) = depth along the device's axis, mm
in vec3 in_position;
in vec3 in_normal;
out vec3 v_pos;
out vec3 v_normal;
out float v_depth;
void main() {
    gl_Position = world_to_clip * vec4(in_position, 1.0);
    v_pos = in_position;
    v_normal = in_normal;
    v_depth = dot(depth_row, vec4(in_position, 1.0));
}
"""
_FS = """
#version 330
in vec3 v_pos;
in vec3 v_normal;
in float v_depth;
layout(location = 0) out vec4 out_pos;      // world mm, w = 1 on the mesh
layout(location = 1) out vec4 out_normal;   // interpolated vertex normal, w = depth (mm)
void main() {
    out_pos = vec4(v_pos, 1.0);
    out_normal = vec4(v_normal, v_depth);
}
"""


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(V, 3) float32`` unit normals: the area-weighted mean of the faces around each vertex, turned
    outwards (a mesh wound clockwise, of negative enclosed volume, is turned round).

    Vertices at the same position are one point of the surface: a mesh with a texture atlas repeats a
    vertex once per chart that meets there, and each copy sees only its own chart's faces. Their faces are
    pooled, so that the normal does not jump along the atlas's seams (on the room's bust by 15 degrees in the
    median, 1 to 2 degrees on the crown, where 1 degree is 7 % of the light a projector grazing it at 13
    degrees gives)."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])      # length: twice the area
    if np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() < 0:
        n = -n
    _, point = np.unique(v, axis=0, return_inverse=True)
    point = point.reshape(-1)
    acc = np.zeros((int(point.max()) + 1 if len(point) else 0, 3))
    for k in range(3):
        np.add.at(acc, point[f[:, k]], n)
    acc = acc[point]
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    return (acc / np.where(norm > 0, norm, 1.0)).astype(np.float32)


def _normalised(P: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """``P`` scaled so that its third row gives the depth in mm with the mesh in front."""
    pm = np.asarray(P, np.float64)
    if pm.shape != (3, 4) or not np.all(np.isfinite(pm)) or not np.linalg.norm(pm[2, :3]) > 0:
        raise BlendError(f"a projection must be a finite (3, 4) matrix with a depth axis, got shape {pm.shape}")
    pm = pm / np.linalg.norm(pm[2, :3])
    depth = np.asarray(vertices, np.float64) @ pm[2, :3] + pm[2, 3]
    return -pm if np.median(depth) < 0 else pm


def grid_projection(P: np.ndarray, camera_size: tuple[int, int], shape: tuple[int, int]) -> np.ndarray:
    """``(3, 4) float64``: the camera's projection ``P`` (world -> camera pixels) onto the grid ``(h, w)`` over
    its ``(W, H)`` image (:mod:`imaging.blending.contributions`' convention: grid pixel ``g`` has its centre at
    camera pixel ``(g + 0.5) W / w - 0.5``)."""
    W, H = camera_size
    h, w = shape
    S = np.array([[w / W, 0.0, 0.5 * w / W - 0.5], [0.0, h / H, 0.5 * h / H - 0.5], [0.0, 0.0, 1.0]])
    return S @ np.asarray(P, np.float64)


@dataclass(frozen=True, eq=False)
class SurfaceView:
    """What each pixel of a device sees of the mesh: ``points`` (h, w, 3) float64 world mm, ``normals``
    (h, w, 3) float64 unit interpolated vertex normals, ``depth`` (h, w) float64 mm along the device's axis
    (``inf`` off the mesh), ``hit`` (h, w) bool."""

    points: np.ndarray
    normals: np.ndarray
    depth: np.ndarray
    hit: np.ndarray


class SurfaceRaster:
    """A mesh uploaded once and rasterised from any pinhole (:meth:`view`); a context manager."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        v = np.ascontiguousarray(vertices, np.float32)
        f = np.ascontiguousarray(faces, np.uint32)
        if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or not len(f):
            raise BlendError(f"a mesh needs vertices (V, 3) and faces (F, 3), got {v.shape} and {f.shape}")
        self.vertices = v
        self.ctx = standalone_context(BlendError, "a mesh rig's blend")
        try:
            self._prog = self.ctx.program(vertex_shader=_VS, fragment_shader=_FS)
            data = np.hstack([v, vertex_normals(v, f)]).astype("f4")
            self._vbo = self.ctx.buffer(data.tobytes())
            self._ibo = self.ctx.buffer(f.tobytes())
            self._vao = self.ctx.vertex_array(self._prog, [(self._vbo, "3f 3f", "in_position", "in_normal")],
                                              self._ibo, index_element_size=4)
        except Exception:
            self.close()
            raise

    def view(self, P: np.ndarray, size: tuple[int, int], *, near: float = 10.0, far: float = 20_000.0) -> SurfaceView:
        """The mesh through ``P`` (3, 4) (world mm -> pixels) into a ``size`` = (w, h) image, depths in
        ``[near, far]`` mm. Pixel ``(x, y)``'s sample is at its centre."""
        w, h = (int(v) for v in size)
        if w < 1 or h < 1 or not 0 < near < far:
            raise BlendError(f"need a positive size and 0 < near < far, got {size}, {near}, {far}")
        pm = _normalised(P, self.vertices)
        x, y, d = pm
        clip = np.empty((4, 4))
        clip[0] = (2.0 * x + d) / w - d         # NDC x = 2 (px + 0.5) / w - 1; read-back row 0 is image row 0
        clip[1] = (2.0 * y + d) / h - d
        clip[2] = (far + near) / (far - near) * d
        clip[2, 3] -= 2.0 * far * near / (far - near)
        clip[3] = d
        self._prog["world_to_clip"].write(clip.T.astype("f4").tobytes())
        self._prog["depth_row"].value = tuple(float(v) for v in pm[2])
        tex = [self.ctx.texture((w, h), 4, dtype="f4") for _ in range(2)]
        rb = self.ctx.depth_renderbuffer((w, h))
        fbo = self.ctx.framebuffer(color_attachments=tex, depth_attachment=rb)
        try:
            fbo.use()
            fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
            self.ctx.enable_only(self.ctx.DEPTH_TEST)
            self._vao.render()
            pos, nrm = (np.frombuffer(fbo.read(components=4, attachment=k, dtype="f4"), np.float32).reshape(h, w, 4)
                        for k in range(2))
        finally:
            fbo.release()
            rb.release()
            for t in tex:
                t.release()
        hit = pos[..., 3] > 0.5
        n = nrm[..., :3].astype(np.float64)
        n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
        depth = np.where(hit, nrm[..., 3].astype(np.float64), np.inf)
        return SurfaceView(np.where(hit[..., None], pos[..., :3], np.nan).astype(np.float64),
                           np.where(hit[..., None], n, np.nan), depth, hit)

    def close(self) -> None:
        ctx = getattr(self, "ctx", None)
        if ctx is not None:
            ctx.release()
            self.ctx = None

    def __enter__(self) -> "SurfaceRaster":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def placement(surface: SurfaceView, P: np.ndarray, size: tuple[int, int], depth: np.ndarray, *,
              vertices: np.ndarray, hit: np.ndarray | None = None,
              samples: int = FOOTPRINT_SAMPLES) -> tuple[np.ndarray, np.ndarray]:
    """One projector at the points of ``surface``: ``(xy (h, w, 2) float32, shading (h, w) float32)``.

    ``P``: the projector's (3, 4) pose; ``size``: its (W, H); ``depth``: ``(H, W)`` its own view's depth
    (:meth:`SurfaceRaster.view`'s, ``inf`` off the mesh). A point is lit when it lies inside the frame, faces
    the projector, and is not hidden: it is hidden only when all four depth texels around its pixel are
    nearer than it by more than a bias (one texel's span at the point's slope, 1 to 25 mm), so that the
    test neither speckles a lit surface nor eats its silhouette.

    ``hit``: ``(H, W) bool``, the projector's pixels whose centre sees the mesh (its own view's), which are the
    pixels a node draws the mesh's content on (it clears the others to black). Given, ``shading`` is multiplied
    by the share of each point's grid cell whose light comes from such pixels (``samples`` x ``samples`` points
    of the cell's footprint, :func:`imaging.blending.mesh_maps.footprint_points`): along the projector's own
    silhouette, which the crown of a bust is for a projector grazing it, its pixels' staircase stretches over
    many camera pixels, and points lit by none of its drawn pixels are not lit (``xy`` NaN)."""
    pm = _normalised(P, vertices)
    W, H = size
    X = surface.points
    on = surface.hit
    Xs = np.where(on[..., None], X, 0.0)
    q = Xs @ pm[:, :3].T + pm[:, 3]
    z = q[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = q[..., :2] / z[..., None]
    centre = -np.linalg.solve(pm[:, :3], pm[:, 3])
    ray = centre - Xs
    dist = np.linalg.norm(ray, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        cos = np.einsum("...i,...i->...", np.nan_to_num(surface.normals), ray) / dist
    inside = on & (z > 0) & np.isfinite(u).all(axis=-1) & (u[..., 0] >= -0.5) & (u[..., 0] <= W - 0.5) \
        & (u[..., 1] >= -0.5) & (u[..., 1] <= H - 0.5) & (cos > 0)
    # the shadow-map test
    dm = np.asarray(depth, np.float64)
    if dm.shape != (H, W):
        raise BlendError(f"a projector's depth map must be its size {(H, W)}, got {dm.shape}")
    x0 = np.clip(np.floor(np.nan_to_num(u[..., 0])).astype(np.int64), 0, max(W - 2, 0))
    y0 = np.clip(np.floor(np.nan_to_num(u[..., 1])).astype(np.int64), 0, max(H - 2, 0))
    x1, y1 = np.minimum(x0 + 1, W - 1), np.minimum(y0 + 1, H - 1)
    far = np.maximum.reduce([dm[y0, x0], dm[y0, x1], dm[y1, x0], dm[y1, x1]])
    focal = float(np.linalg.norm(np.cross(pm[1, :3], pm[2, :3])))        # the vertical focal length, pixels
    c = np.clip(cos, 0.05, 1.0)
    bias = np.minimum(1.0 + 2.0 * (z / max(focal, 1e-9)) * np.sqrt(1.0 - c * c) / c, 25.0)
    lit = inside & ~(z > far + bias)
    xy = np.where(lit[..., None], u, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        shade = np.where(lit, cos * (REFERENCE_MM / dist) ** 2, 0.0)
    if hit is not None and lit.any():
        hm = np.asarray(hit, bool)
        if hm.shape != (H, W):
            raise BlendError(f"a projector's hit mask must be its size {(H, W)}, got {hm.shape}")
        rows = np.flatnonzero(lit)
        pix = snap_pixels(footprint_points(xy, rows, samples=max(int(samples), 1)), (W, H)).astype(np.int64)
        cover = hm[pix[..., 1], pix[..., 0]].mean(axis=1)
        shade.reshape(-1)[rows] *= cover
        dark = rows[cover == 0]
        xy.reshape(-1, 2)[dark] = np.nan
    return xy.astype(np.float32), shade.astype(np.float32)


@dataclass(frozen=True, eq=False)
class MeshPlacement:
    """:func:`mesh_placement`'s result (see the module docstring)."""

    surface: np.ndarray
    xy: dict
    shading: dict


def mesh_placement(vertices: np.ndarray, faces: np.ndarray, camera_P: np.ndarray, camera_size: tuple[int, int],
                   shape: tuple[int, int], projectors: Mapping[str, tuple[np.ndarray, tuple[int, int], float, float]]
                   ) -> MeshPlacement:
    """Each projector's placement and shading on the grid ``shape`` = (h, w) over a camera of ``camera_size``.

    ``camera_P``: the camera's (3, 4) projection (world mm -> camera pixels); ``projectors``: slot ->
    ``(P (3, 4), (W, H), near_mm, far_mm)``."""
    h, w = shape
    with SurfaceRaster(vertices, faces) as raster:
        surface = raster.view(grid_projection(camera_P, camera_size, shape), (w, h))
        if not surface.hit.any():
            raise BlendError("the camera does not see the mesh: check its pose (calibrate again)")
        xy, shading = {}, {}
        for s, (P, size, near, far) in projectors.items():
            own = raster.view(P, size, near=near, far=far)
            xy[s], shading[s] = placement(surface, P, size, own.depth, vertices=vertices, hit=own.hit)
    return MeshPlacement(surface.hit, xy, shading)
