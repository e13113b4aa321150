"""The room's static precomputation: what each camera sees, and how each projector lights it.

Done once per camera (:func:`precompute_view`), independent of frames and
occluders:

* :class:`View`: what every camera pixel looks at (the table, the mesh): surface
  point, normal, albedo, content uv, distance, the camera pixel's footprint.
  Arrays cover the view's ROI, the bounding box of the pixels that see a surface.
* :class:`Plan`, per projector and view: where each surface point falls in the
  projector's image (sub-pixel, as field coordinates for ``cv2.remap``), how much
  light reaches it (distance, incidence, lens fall-off, the projector's hot spot and
  vignetting at that image point, mesh self-occlusion) and
  how blurred it is (defocus + the camera pixel's footprint), plus a tile index
  of the projector image that :mod:`sim.occlusion` culls occluder tests with.
* :class:`MeshMaps`: rasterised mesh visibility (camera G-buffers, projector
  shadow maps) for rooms with a mesh.

Blur: a projector whose blur varies by less than :data:`SIGMA_TOLERANCE`
projector pixels over the surface the camera sees uses one blur (the RMS);
otherwise each pixel blends two levels of :data:`sim.optics.SIGMA_LEVELS`.

The per-point helpers (:func:`device_geometry`, :func:`footprint_area`,
:func:`blend_coefficients`) are shared with :mod:`sim.occlusion`, which samples
the occluder surface the same way.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sim.geometry import Pinhole, intersect_plane_z
from sim.optics import (
    REFERENCE_DISTANCE_MM,
    SIGMA_LEVELS,
    blend_levels,
    field_padding,
)
from sim.raster import MeshRaster
from sim.scene import ProjectorSpec, Scene
from sim.specular import SpecularView, specular_view

__all__ = [
    "NOTHING",
    "TABLE",
    "MESH",
    "SIGMA_TOLERANCE",
    "CAMERA_SIGMA_LIMIT",
    "SHADOW_MAP_SCALE",
    "Plan",
    "View",
    "MeshMaps",
    "precompute_view",
    "build_view",
    "build_plan",
    "device_geometry",
    "footprint_area",
    "blend_coefficients",
    "tile_index",
]

#: Kinds of surface a camera pixel sees.
NOTHING, TABLE, MESH = 0, 1, 2

#: Below this spread (projector px) of a projector's blur over the view, one blur level is used.
SIGMA_TOLERANCE = 0.1

#: Largest camera-footprint sigma (projector px) — a grazing camera pixel is not blurred further.
CAMERA_SIGMA_LIMIT = 2.0

#: Shadow-map texels per projector pixel and axis (mesh self-occlusion).
SHADOW_MAP_SCALE = 2

#: Views with more ROI pixels than this keep single-channel coefficients (memory over speed).
_COEF3_LIMIT = 700_000


@dataclass(eq=False)
class Plan:
    """How one projector lights the static surface seen by one camera.

    ``(hr, wr)`` is the view's ROI shape; ``n`` the number of lit ROI pixels.
    """

    upsample: int
    pad: int
    sigmas: tuple[float, ...]  # blur of each level, projector px
    mapx: np.ndarray  # (hr, wr) float32 field coordinates (-10: unlit)
    mapy: np.ndarray
    weight: np.ndarray  # (hr, wr) float32 (albedo + gloss's pi f_s) * peak * irradiance * profile * static visibility
    lo: np.ndarray  # (hr, wr) int8 level
    alpha: np.ndarray  # (hr, wr) float32 blend towards level lo + 1
    coef: dict[int, np.ndarray]  # level -> (hr, wr, 3) or (hr, wr) float32
    lit: np.ndarray  # (n,) int64 flat ROI indices with weight > 0 or light spill
    order: np.ndarray  # (n,) int32 positions into ``lit``, sorted by tile
    starts: np.ndarray  # (ntiles + 1,) int64
    tiles: tuple[int, int, float, int]  # tiles across, down, origin (px), tile size (px)
    uv: np.ndarray  # (n, 2) float32 projector coordinates of ``lit``
    tile_dirs: np.ndarray  # (nty, ntx, 3) unit world directions through tile centres
    tile_ang: float  # bound on a tile's angular radius, rad

    def coef_2d(self, level: int) -> np.ndarray:
        """(hr, wr) float32: the coefficients of blur ``level`` (one channel; channels are equal)."""
        c = self.coef[level]
        return c[:, :, 0] if c.ndim == 3 else c


@dataclass(eq=False)
class View:
    """What one camera sees of the static room (ROI-shaped arrays).

    ``roi`` is ``(x0, y0, x1, y1)`` in camera pixels; ``(hr, wr) = (y1 - y0, x1 - x0)``.
    ``plans`` maps each projector slot to its :class:`Plan`.
    """

    camera: int
    roi: tuple[int, int, int, int]
    kind: np.ndarray  # (hr, wr) uint8 NOTHING, TABLE or MESH
    points: np.ndarray  # (hr, wr, 3) float64
    normals: np.ndarray  # (hr, wr, 3) float64
    albedo: np.ndarray  # (hr, wr) float32
    content_uv: np.ndarray  # (hr, wr, 2) float32
    distance: np.ndarray  # (hr, wr) float64 from the camera centre (inf: nothing)
    cam_area: np.ndarray  # (hr, wr) float64 camera pixel footprint, mm^2
    plans: dict[str, Plan] = field(default_factory=dict)
    surf: np.ndarray = field(default=None)  # (n,) flat ROI indices that see a surface
    scratch: np.ndarray = field(default=None)  # (hr, wr, 3) float32 work buffer of captures
    specular: SpecularView | None = None  # the glossy surface's lobe towards this camera (sim.specular); None: matte

    def __post_init__(self) -> None:
        self.surf = np.flatnonzero(self.kind.reshape(-1) != NOTHING)
        # Surface-only copies, contiguous, for the per-projector precomputation.
        flat_p = self.points.reshape(-1, 3)
        flat_n = self.normals.reshape(-1, 3)
        self.s_points = tuple(np.ascontiguousarray(flat_p[self.surf, k]) for k in range(3))
        self.s_normals = tuple(np.ascontiguousarray(flat_n[self.surf, k]) for k in range(3))
        self.s_albedo = self.albedo.reshape(-1)[self.surf]
        self.s_cam_area = self.cam_area.reshape(-1)[self.surf]
        self.scratch = np.empty((*self.kind.shape, 3), np.float32)

    @property
    def shape(self) -> tuple[int, int]:
        """(hr, wr): the ROI's shape."""
        return self.kind.shape


@dataclass(eq=False)
class MeshMaps:
    """Rasterised visibility of a room's mesh.

    Attributes
    ----------
    shadow_maps : dict
        slot -> (device, (h', w') float32 depth map) at :data:`SHADOW_MAP_SCALE` x the projector's size.
    gbuffers : dict
        camera index -> (position (H, W, 3), normal (H, W, 3), uv (H, W, 2), hit (H, W) bool),
        as :meth:`sim.raster.MeshRaster.gbuffer` returns them.
    """

    shadow_maps: dict[str, tuple[Pinhole, np.ndarray]] = field(default_factory=dict)
    gbuffers: dict[int, tuple] = field(default_factory=dict)

    @classmethod
    def render(cls, scene: Scene) -> "MeshMaps":
        """Rasterise ``scene.mesh`` from every projector (shadow maps) and camera (G-buffers)."""
        maps = cls()
        with MeshRaster(scene.mesh) as raster:
            for p in scene.projectors:
                w, h = p.pinhole.size
                device = p.pinhole.scaled((w * SHADOW_MAP_SCALE, h * SHADOW_MAP_SCALE))
                maps.shadow_maps[p.slot] = (device, raster.depth_map(device))
            for i, c in enumerate(scene.cameras):
                maps.gbuffers[i] = raster.gbuffer(c.pinhole)
        return maps

    def shadowed(self, slot: str, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """(n,) bool: the mesh hides ``points`` from projector ``slot`` (shadow-map test).

        Parameters
        ----------
        points, normals : (n, 3) float64
        """
        if slot not in self.shadow_maps or len(points) == 0:
            return np.zeros(len(points), bool)
        device, depth = self.shadow_maps[slot]
        pix, z = device.project(points)
        h, w = depth.shape
        inside = (pix[:, 0] >= 0) & (pix[:, 0] <= w - 1) & (pix[:, 1] >= 0) & (pix[:, 1] <= h - 1) & (z > 0)
        x2 = np.clip(np.floor(np.nan_to_num(pix[:, 0])).astype(np.int64), 0, w - 2)
        y2 = np.clip(np.floor(np.nan_to_num(pix[:, 1])).astype(np.int64), 0, h - 2)
        # Occluded only if all four texels around the point are nearer: no acne, slight leaks at silhouettes.
        dmax = np.maximum.reduce([depth[y2, x2], depth[y2, x2 + 1], depth[y2 + 1, x2], depth[y2 + 1, x2 + 1]])
        # Slope-scaled bias: one texel spans z / f mm; a tilted surface changes depth by tan(theta) per mm.
        to_dev = device.center - points
        dist = np.linalg.norm(to_dev, axis=1)
        cos_t = np.clip(np.einsum("ij,ij->i", normals, to_dev) / dist, 0.05, 1.0)
        tan_t = np.sqrt(1.0 - cos_t**2) / cos_t
        bias = np.minimum(1.0 + 2.0 * (z / device.K[0, 0]) * tan_t, 25.0)
        return inside & (z > dmax + bias)


# ---------------------------------------------------------------- views and plans


def precompute_view(scene: Scene, camera: int, *, upsample: int | None = None, mesh_maps: MeshMaps | None = None) -> View:
    """The :class:`View` of ``camera`` with the :class:`Plan` of every projector of ``scene``.

    Parameters
    ----------
    upsample : int, optional
        Field samples per projector pixel and axis (see :func:`build_plan`).
    mesh_maps : MeshMaps
        Required when ``scene`` has a mesh.
    """
    view = build_view(scene, camera, mesh_maps)
    for p in scene.projectors:
        view.plans[p.slot] = build_plan(view, p, upsample=upsample, mesh_maps=mesh_maps if scene.mesh is not None else None)
    return view


def build_view(scene: Scene, camera: int, mesh_maps: MeshMaps | None = None) -> View:
    """What ``camera`` sees of the static room: the nearest of table and mesh per pixel (no plans yet).

    ``mesh_maps`` (its camera G-buffers) is required when ``scene`` has a mesh.
    """
    cam = scene.camera(camera).pinhole
    W, H = cam.size
    rays = cam.rays(cam.pixel_grid())
    kind = np.zeros((H, W), np.uint8)
    points = np.zeros((H, W, 3))
    normals = np.zeros((H, W, 3))
    albedo = np.zeros((H, W), np.float32)
    content = np.full((H, W, 2), np.nan, np.float32)
    dist = np.full((H, W), np.inf)
    if scene.table is not None:
        tw, th = scene.table.size
        pts, s = intersect_plane_z(np.broadcast_to(cam.center, rays.shape), rays, z=0.0)
        on = np.isfinite(s) & (np.abs(pts[..., 0]) <= tw / 2) & (np.abs(pts[..., 1]) <= th / 2)
        kind[on] = TABLE
        points[on] = pts[on]
        normals[on] = (0.0, 0.0, 1.0)
        albedo[on] = scene.table.albedo
        content[on, 0] = (pts[on, 0] + tw / 2) / tw
        content[on, 1] = (th / 2 - pts[on, 1]) / th
        dist[on] = s[on]
    if scene.mesh is not None:
        mpos, mnrm, muv, mhit = mesh_maps.gbuffers[camera]
        md = np.linalg.norm(mpos.astype(np.float64) - cam.center, axis=-1)
        front = mhit & (md < dist)
        kind[front] = MESH
        points[front] = mpos[front]
        n = mnrm[front].astype(np.float64)
        normals[front] = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        albedo[front] = scene.mesh_albedo
        content[front] = muv[front]
        dist[front] = md[front]
    ys, xs = np.nonzero(kind)
    roi = (0, 0, 1, 1) if len(ys) == 0 else (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
    x0, y0, x1, y1 = roi
    sl = (slice(y0, y1), slice(x0, x1))
    pts, nrm = points[sl].copy(), normals[sl].copy()
    cam_area = np.full(pts.shape[:2], np.inf)
    surf = kind[sl] != NOTHING
    cam_area[surf] = footprint_area(cam, pts[surf], nrm[surf])
    view = View(camera, roi, kind[sl].copy(), pts, nrm, albedo[sl].copy(), content[sl].copy(), dist[sl].copy(), cam_area)
    view.specular = specular_view(scene.gloss, view.kind.reshape(-1)[view.surf], {"table": TABLE, "mesh": MESH}, cam.center)
    return view


def build_plan(view: View, spec: ProjectorSpec, *, upsample: int | None = None, mesh_maps: MeshMaps | None = None) -> Plan:
    """How projector ``spec`` lights the surface of ``view``.

    Parameters
    ----------
    upsample : int, optional
        Field samples per projector pixel and axis (the square footprint); by
        default about the projector pixel's size in camera pixels, 1 to 4.
    mesh_maps : MeshMaps, optional
        Given, the mesh's shadows are taken out of the lit surface.
    """
    dev = spec.pinhole
    w, h = dev.size
    surf = view.surf
    pts = view.s_points
    nrm = view.s_normals
    g = device_geometry(dev, pts, nrm, falloff=spec.falloff)
    proj_area = g["area"]
    cam_area = view.s_cam_area
    ok = np.isfinite(proj_area) & np.isfinite(cam_area)
    if upsample is not None:
        s = int(upsample)
    elif ok.any():
        some = np.flatnonzero(ok)[:: max(1, int(ok.sum()) // 20000)]  # a sample is plenty for a median
        s = int(np.clip(round(float(np.median(np.sqrt(proj_area[some] / cam_area[some])))), 1, 4))
    else:
        s = 1
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(ok, cam_area / proj_area, 0.0)
    sigma_cam = np.minimum(np.sqrt(np.maximum(ratio, 0.0) / 12.0), CAMERA_SIGMA_LIMIT)
    d = g["distance"]
    with np.errstate(divide="ignore", invalid="ignore"):
        sigma_def = np.where(d > 0, spec.aperture * dev.K[0, 0] * np.abs(d - spec.focus) / (4.0 * spec.focus * d), 0.0)
    sigma = np.sqrt(sigma_def**2 + sigma_cam**2)
    u, v, depth, e = g["u"], g["v"], g["depth"], g["irradiance"]
    margin = 3.0 * float(np.max(sigma, initial=0.0)) + 1.0
    lit = (depth > 0) & (e > 0) & (u > -0.5 - margin) & (u < w - 0.5 + margin) & (v > -0.5 - margin) & (v < h - 0.5 + margin)
    if mesh_maps is not None and lit.any():
        idx = np.flatnonzero(lit)
        sub_p = np.column_stack([a[idx] for a in pts])
        sub_n = np.column_stack([a[idx] for a in nrm])
        lit[idx[mesh_maps.shadowed(spec.slot, sub_p, sub_n)]] = False
    # Blur levels: one if the blur hardly varies, else a blend of two ladder levels per pixel.
    sl = sigma[lit]
    if len(sl) == 0 or float(sl.max() - sl.min()) <= SIGMA_TOLERANCE:
        rms = float(np.sqrt(np.mean(sl**2))) if len(sl) else 0.0
        sigmas: tuple[float, ...] = (rms,)
        lo = np.zeros(len(surf), np.int32)
        alpha = np.zeros(len(surf), np.float32)
    else:
        glo, galpha = blend_levels(sigma)
        first = int(glo[lit].min())
        last = int(np.max(np.where(galpha > 0, glo + 1, glo)[lit]))
        sigmas = tuple(SIGMA_LEVELS[first : last + 1])
        lo = glo - first
        alpha = galpha
    pad = field_padding(max(sigmas), s)
    shape = view.shape
    n_roi = shape[0] * shape[1]

    def roi_map(values, fill, dtype):
        out = np.full(n_roi, fill, dtype)
        out[surf] = values
        return out.reshape(shape)

    fx = np.where(lit, s * (u + 0.5) - 0.5 + pad, -10.0)
    fy = np.where(lit, s * (v + 0.5) - 0.5 + pad, -10.0)
    mapx = roi_map(fx, -10.0, np.float32)
    mapy = roi_map(fy, -10.0, np.float32)
    light = view.s_albedo * spec.peak * e
    if view.specular is not None:  # a glossy surface: its lobe towards this camera, lit by the same irradiance
        light = light + view.specular.reflectance(dev.center, pts, nrm) * spec.peak * e
    profile = spec.profile_at(u, v)  # a hot spot and vignetting (sim.photometry); None when even
    if profile is not None:
        light = light * profile
    weight = roi_map(np.where(lit, light, 0.0), 0.0, np.float32)
    lo_map = roi_map(lo, 0, np.int8)
    alpha_map = roi_map(np.where(lit, alpha, 0.0), 0.0, np.float32)
    coef = blend_coefficients(weight, lo_map, alpha_map, len(sigmas), three=n_roi <= _COEF3_LIMIT)
    lit_roi = surf[lit]
    uv = np.empty((len(lit_roi), 2), np.float32)
    uv[:, 0] = u[lit]
    uv[:, 1] = v[lit]
    order, starts, tiles, tile_dirs, tile_ang = tile_index(uv, dev)
    return Plan(s, pad, sigmas, mapx, mapy, weight, lo_map, alpha_map, coef, lit_roi, order, starts, tiles, uv, tile_dirs, tile_ang)


# ---------------------------------------------------------------- per-point helpers


def _soa(a) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, y, z) component arrays of (n, 3) points or of a tuple of three arrays."""
    if isinstance(a, tuple):
        return a
    return a[:, 0], a[:, 1], a[:, 2]


def _affine_row(row: np.ndarray, X: np.ndarray, Y: np.ndarray, Z: np.ndarray) -> np.ndarray:
    out = row[0] * X
    out += row[1] * Y
    out += row[2] * Z
    out += row[3]
    return out


def device_geometry(dev: Pinhole, pts, nrm, *, falloff: float) -> dict[str, np.ndarray]:
    """Per-point projection and photometry of one device, component-wise and in place for speed.

    ``pts``, ``nrm``: (n, 3) arrays or (x, y, z) tuples of (n,) arrays.
    Returns u, v (pixels), depth (mm along the axis), distance (mm), irradiance
    (:func:`sim.optics.irradiance_factor`) and area (:func:`sim.geometry.pixel_footprint_area`),
    each (n,) float64.
    """
    P = dev.P
    X, Y, Z = _soa(pts)
    NX, NY, NZ = _soa(nrm)
    hz = _affine_row(P[2], X, Y, Z)
    c = dev.center
    vx = c[0] - X
    vy = c[1] - Y
    vz = c[2] - Z
    d2 = vx * vx
    d2 += vy * vy
    d2 += vz * vz
    d = np.sqrt(d2)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = _affine_row(P[0], X, Y, Z)
        u /= hz
        v = _affine_row(P[1], X, Y, Z)
        v /= hz
        cos_t = NX * vx
        cos_t += NY * vy
        cos_t += NZ * vz
        cos_t /= d
        cos_a = hz / d  # depth / distance (K's last row is (0, 0, 1))
        valid = (cos_t > 0) & (cos_a > 1e-6)
        k = falloff - 3.0
        if k == -2.0:
            e = 1.0 / (cos_a * cos_a)
        elif k == -3.0:
            e = 1.0 / (cos_a * cos_a * cos_a)
        else:
            e = np.power(cos_a, k)
        e *= cos_t
        e *= REFERENCE_DISTANCE_MM * REFERENCE_DISTANCE_MM
        e /= d2
        e[~valid] = 0.0
        area = cos_a * cos_a * cos_a
        area *= d2
        area /= dev.K[0, 0] * dev.K[1, 1]
        area /= cos_t
        area[~valid] = np.inf
    return {"u": u, "v": v, "depth": hz, "distance": d, "irradiance": e, "area": area}


def footprint_area(dev: Pinhole, pts: np.ndarray, nrm: np.ndarray) -> np.ndarray:
    """(n,) float64: mm^2 of surface one pixel of ``dev`` covers at ``pts`` (inf: facing away)."""
    return device_geometry(dev, pts, nrm, falloff=0.0)["area"]


def blend_coefficients(weight: np.ndarray, lo: np.ndarray, alpha: np.ndarray, n_levels: int, *, three: bool) -> dict[int, np.ndarray]:
    """level -> weight x blend coefficient; levels that carry nothing are left out.

    ``weight``, ``lo``, ``alpha`` share one shape ``S``; the coefficients are
    ``S`` float32, or ``(*S, 3)`` float32 with ``three``.
    """
    coef = {}
    for L in range(n_levels):
        if n_levels == 1:
            c = weight.astype(np.float32)
        else:
            c = (weight * (np.where(lo == L, 1.0 - alpha, 0.0) + np.where(lo + 1 == L, alpha, 0.0))).astype(np.float32)
        if not np.any(c):
            continue
        coef[L] = np.repeat(c[..., None], 3, axis=-1) if three else c
    return coef


def _tile_size(width: int) -> int:
    return max(4, width // 80)


def tile_index(uv: np.ndarray, dev: Pinhole) -> tuple[np.ndarray, np.ndarray, tuple[int, int, float, int], np.ndarray, float]:
    """Sort lit points by the projector tile they fall in.

    Parameters
    ----------
    uv : (n, 2) float32
        Projector coordinates of the points.

    Returns
    -------
    Positions into ``uv`` sorted by tile ((n,) int32), each tile's start
    ((ntiles + 1,) int64), the grid (tiles across, down, origin px, tile px),
    the unit world direction through every tile centre (nty, ntx, 3) and a
    bound on a tile's angular radius. Points outside the grid are clipped
    into its border tiles.
    """
    w, h = dev.size
    T = _tile_size(w)
    origin = -4.0 * T
    ntx = int(math.ceil((w - origin + 4 * T) / T))
    nty = int(math.ceil((h - origin + 4 * T) / T))
    # Truncation equals floor for the non-negative values that survive the clamp below.
    tx = ((uv[:, 0] - origin) * (1.0 / T)).astype(np.int32)
    ty = ((uv[:, 1] - origin) * (1.0 / T)).astype(np.int32)
    np.clip(tx, 0, ntx - 1, out=tx)
    np.clip(ty, 0, nty - 1, out=ty)
    tid = ty * ntx + tx
    # A stable sort of small integers is a radix sort in numpy: linear time.
    order = np.argsort(tid.astype(np.uint16) if ntx * nty < 65536 else tid, kind="stable").astype(np.int32)
    starts = np.searchsorted(tid[order], np.arange(ntx * nty + 1))
    cx = origin + (np.arange(ntx) + 0.5) * T
    cy = origin + (np.arange(nty) + 0.5) * T
    dirs = dev.rays(np.stack(np.meshgrid(cx, cy), axis=-1))
    # A tile reaches T * sqrt(2) / 2 px from its centre; one pixel subtends at most 1 / f radians.
    ang = T * math.sqrt(2.0) / 2.0 / min(dev.K[0, 0], dev.K[1, 1])
    return order, starts, (ntx, nty, origin, T), dirs, ang
