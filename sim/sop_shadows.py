"""Hard shadows of occluders on the table plane, as polygons and rasters, and each projector's light there.

The sense-of-projection proxies (:mod:`studies.proxies`) and the planner
(:mod:`planner`) need the shadow every projector casts of a hand on the table
for many projectors and many hand poses; ray tests per table point
(:func:`sim.occluders.segment_blocked`) are exact but cost a ray per point,
primitive and projector. A projector is a point source (its lens aperture
only blurs the edge, see :mod:`studies.proxies`), every occluder primitive is convex,
and a central projection maps a convex solid to a convex region: the shadow
of a primitive on the plane z = 0 is the convex hull of the projections of
points on its surface. So a shadow is a handful of convex polygons, filled by
OpenCV at any resolution in well under a millisecond each.

Surface samples: a sphere, and each end of a capsule, by a Fibonacci lattice
of :data:`SPHERE_SAMPLES` directions (the hull of the samples falls short of
the true outline by at most ``r (1 - cos(dtheta / 2))``, about 0.5 % of the
radius); an ellipsoid by the same lattice stretched; a box by its corners.

A :class:`Grid` is a regular lattice of table points (world mm, z = 0): row
``i`` at ``y = y0 + i pitch``, column ``j`` at ``x = x0 + j pitch``, so rows
grow along +y (the raster is the table seen from below; pictures flip it).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from sim.geometry import Pinhole
from sim.occluders import Box, Capsule, Ellipsoid, Primitive, Sphere
from sim.optics import irradiance_factor

#: Directions sampled on each spherical part of a primitive.
SPHERE_SAMPLES = 400

#: OpenCV's fixed-point bits for polygon vertices (1/16 of a grid step).
_SHIFT = 4


@lru_cache(maxsize=4)
def unit_sphere(n: int = SPHERE_SAMPLES) -> np.ndarray:
    """(n, 3) float64 unit vectors, a Fibonacci lattice (nearly uniform on the sphere)."""
    k = np.arange(n, dtype=np.float64) + 0.5
    z = 1.0 - 2.0 * k / n
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    out = np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
    out.setflags(write=False)
    return out


def primitive_points(prim: Primitive) -> np.ndarray:
    """Points on the surface of a convex primitive whose convex hull is (nearly) the solid.

    Returns
    -------
    (m, 3) float64 world mm.

    Raises
    ------
    TypeError
        For a primitive this module does not know.
    """
    u = unit_sphere()
    if isinstance(prim, Sphere):
        return prim.center + prim.radius * u
    if isinstance(prim, Ellipsoid):
        return prim.center + (u * prim.radii) @ prim.rotation.T
    if isinstance(prim, Capsule):
        return np.vstack([prim.a + prim.radius * u, prim.b + prim.radius * u])
    if isinstance(prim, Box):
        return prim.corners()
    raise TypeError(f"no shadow outline for {type(prim).__name__}")


def project_to_table(source: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Central projection of ``points`` from ``source`` onto the plane z = 0.

    Parameters
    ----------
    source : (3,) float64
        The projector's optical centre, above every point.
    points : (m, 3) float64

    Returns
    -------
    (m, 2) float64 table (x, y) mm.

    Raises
    ------
    ValueError
        When a point is not below the source (it casts no shadow on the table).
    """
    s = np.asarray(source, np.float64).reshape(3)
    p = np.asarray(points, np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must be (m, 3), got {p.shape}")
    depth = s[2] - p[:, 2]
    if np.any(depth <= 1e-9):
        raise ValueError("an occluder point is at or above the projector: it casts no shadow on the table")
    scale = s[2] / depth
    return s[:2] + (p[:, :2] - s[:2]) * scale[:, None]


def shadow_polygons(source: np.ndarray, primitives) -> list[np.ndarray]:
    """The shadow of each primitive cast from ``source`` on z = 0, as a convex polygon.

    Returns
    -------
    list of (k, 2) float64 vertex arrays (table mm, counter-clockwise), one per primitive.
    """
    out = []
    for prim in primitives:
        xy = project_to_table(source, primitive_points(prim)).astype(np.float32)
        hull = cv2.convexHull(xy, clockwise=False).reshape(-1, 2)
        out.append(hull.astype(np.float64))
    return out


@dataclass(frozen=True, eq=False)
class Source:
    """A projector as a light source: its optics (native resolution), relative output and lens fall-off."""

    name: str
    device: Pinhole
    peak: float = 1.0
    falloff: float = 1.0

    @classmethod
    def from_spec(cls, spec) -> Source:
        """From a :class:`sim.scene.ProjectorSpec` (its native optics, peak and fall-off)."""
        return cls(spec.slot, spec.native, float(spec.peak), float(spec.falloff))

    @property
    def center(self) -> np.ndarray:
        """(3,) float64 optical centre, world mm."""
        return self.device.center


@dataclass(frozen=True)
class Grid:
    """A regular lattice of table points (see the module docstring for the orientation).

    Attributes
    ----------
    x0, y0 : float
        World mm of sample ``[0, 0]``.
    pitch : float
        mm between neighbouring samples.
    shape : (int, int)
        (rows, columns).
    """

    x0: float
    y0: float
    pitch: float
    shape: tuple[int, int]

    def __post_init__(self) -> None:
        if self.pitch <= 0 or self.shape[0] < 1 or self.shape[1] < 1:
            raise ValueError(f"need a positive pitch and shape, got {self.pitch}, {self.shape}")

    @classmethod
    def covering(cls, size: tuple[float, float], pitch: float) -> Grid:
        """Samples at the centres of ``pitch``-sized cells tiling a table of ``size`` (mm) centred on the origin."""
        cols = max(1, round(size[0] / pitch))
        rows = max(1, round(size[1] / pitch))
        px, py = size[0] / cols, size[1] / rows
        if abs(px - py) > 1e-6 * pitch:
            raise ValueError(f"pitch {pitch} mm does not tile the table {size} evenly in both directions")
        return cls(-size[0] / 2 + px / 2, -size[1] / 2 + py / 2, px, (rows, cols))

    @property
    def cell_area(self) -> float:
        """mm^2 each sample stands for."""
        return self.pitch * self.pitch

    def xy(self) -> tuple[np.ndarray, np.ndarray]:
        """(rows, cols) float64 x and y of every sample."""
        rows, cols = self.shape
        return np.meshgrid(self.x0 + self.pitch * np.arange(cols), self.y0 + self.pitch * np.arange(rows))

    def points(self) -> np.ndarray:
        """(rows * cols, 3) float64 samples on z = 0, row-major."""
        x, y = self.xy()
        return np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])

    def window(self, lo: tuple[float, float], hi: tuple[float, float]) -> Grid | None:
        """The sub-lattice of samples inside the box ``lo``-``hi`` (mm), or None when it holds none."""
        rows, cols = self.shape
        j0 = max(0, math.ceil((lo[0] - self.x0) / self.pitch - 1e-9))
        j1 = min(cols - 1, math.floor((hi[0] - self.x0) / self.pitch + 1e-9))
        i0 = max(0, math.ceil((lo[1] - self.y0) / self.pitch - 1e-9))
        i1 = min(rows - 1, math.floor((hi[1] - self.y0) / self.pitch + 1e-9))
        if j1 < j0 or i1 < i0:
            return None
        return Grid(self.x0 + j0 * self.pitch, self.y0 + i0 * self.pitch, self.pitch, (i1 - i0 + 1, j1 - j0 + 1))


def rasterize(polygons, grid: Grid) -> np.ndarray:
    """Samples of ``grid`` inside any of the convex ``polygons`` (table mm).

    OpenCV's fill at 1/16-step vertex precision: every sample inside a
    polygon, plus samples its outline passes through (a shadow grows by at
    most one sample at its outline, about half a sample on average; against
    exact ray tests the test suite finds no other difference).

    Returns
    -------
    (rows, cols) bool
    """
    mask = np.zeros(grid.shape, np.uint8)
    scale = float(1 << _SHIFT) / grid.pitch
    for poly in polygons:
        pix = np.round((np.asarray(poly, np.float64) - (grid.x0, grid.y0)) * scale).astype(np.int32)
        cv2.fillConvexPoly(mask, pix, 1, lineType=cv2.LINE_8, shift=_SHIFT)
    return mask.astype(bool)


def polygons_bounds(polygons) -> tuple[np.ndarray, np.ndarray]:
    """((2,), (2,)) float64 lower and upper corners of the box around ``polygons``."""
    allp = np.vstack(polygons)
    return allp.min(axis=0), allp.max(axis=0)


def table_irradiance(grid: Grid, source: Source) -> np.ndarray:
    """A projector's full-white irradiance at the grid's samples; 0 outside its image.

    Same model as the room (:func:`sim.optics.irradiance_factor` on an upward
    surface, times ``peak``), so the shares of the projectors at a point are the
    room's.

    Returns
    -------
    (rows, cols) float64
    """
    pts = grid.points()
    return surface_irradiance(source, pts, np.broadcast_to(np.array([0.0, 0.0, 1.0]), pts.shape)).reshape(grid.shape)


def surface_irradiance(source: Source, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """A projector's full-white irradiance at surface points (0 outside its image or facing away).

    Parameters
    ----------
    points, normals : (n, 3) float64
        World mm and unit normals.

    Returns
    -------
    (n,) float64
    """
    dev = source.device
    e = source.peak * irradiance_factor(dev.center, dev.axis, points, normals, falloff=source.falloff)
    pix, depth = dev.project(points)
    w, h = dev.size
    inside = (depth > 0) & (pix[..., 0] >= -0.5) & (pix[..., 0] <= w - 0.5) & (pix[..., 1] >= -0.5) & (pix[..., 1] <= h - 0.5)
    return np.where(inside, e, 0.0)


def resample(values: np.ndarray, grid: Grid, target: Grid) -> np.ndarray:
    """Bilinear interpolation of a smooth field sampled on ``grid`` at the samples of ``target``.

    Irradiance varies over hundreds of millimetres, shadows over one: the
    proxies compute each projector's irradiance on a coarse grid once and read
    it at fine shadow rasters through this. Samples beyond the coarse grid take
    its border values.

    Parameters
    ----------
    values : (rows, cols) float
        On ``grid``.

    Returns
    -------
    (target rows, target cols) float32
    """
    v = np.asarray(values, np.float32)
    if v.shape != grid.shape:
        raise ValueError(f"values must have the grid's shape {grid.shape}, got {v.shape}")
    rows, cols = target.shape
    mx = ((target.x0 - grid.x0) + target.pitch * np.arange(cols, dtype=np.float64)) / grid.pitch
    my = ((target.y0 - grid.y0) + target.pitch * np.arange(rows, dtype=np.float64)) / grid.pitch
    map_x = np.broadcast_to(mx.astype(np.float32)[None, :], (rows, cols))
    map_y = np.broadcast_to(my.astype(np.float32)[:, None], (rows, cols))
    return cv2.remap(v, np.ascontiguousarray(map_x), np.ascontiguousarray(map_y), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
