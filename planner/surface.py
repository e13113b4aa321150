"""What the planner lights: samples of the surface, each candidate's light on them, and the hands over it.

A :class:`Surface` is a set of points with normals and the area each stands
for: the table as a regular :class:`~sim.sop_shadows.Grid` (its shadows are
rasterised as polygons, fast), or a mesh sampled at face centres (shadows by
ray tests; the mesh's own shadows by depth maps rendered with OpenGL through
:class:`sim.raster.MeshRaster`, the room's test).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.mesh import Mesh
from sim.hand import Hand
from sim.precompute import MeshMaps
from sim.raster import MeshRaster
from studies.proxies import PoseSet
from sim.sop_shadows import Grid, Source, surface_irradiance

#: resolution of the planner's mesh depth maps (the mesh's own shadows)
DEPTH_MAP_SIZE = (512, 320)


@dataclass(frozen=True, eq=False)
class Surface:
    """Sample points of the lit surface.

    Attributes
    ----------
    points, normals : (n, 3) float64
    area : (n,) float64
        mm^2 per sample.
    target : (3,) float64
        Where candidates aim.
    corners : (m, 3) float64
        Points a fitted projector's image must contain.
    grid : Grid or None
        For the table: the samples are ``grid.points()`` (row-major).
    mesh : Mesh or None
    name : str
    """

    points: np.ndarray
    normals: np.ndarray
    area: np.ndarray
    target: np.ndarray
    corners: np.ndarray
    grid: Grid | None = None
    mesh: Mesh | None = None
    name: str = "table"

    @property
    def size(self) -> int:
        return len(self.points)


def table_surface(size: tuple[float, float], *, pitch: float = 10.0) -> Surface:
    """The table (``size`` mm, centred on the origin) sampled every ``pitch`` mm."""
    grid = Grid.covering(size, pitch)
    pts = grid.points()
    normals = np.broadcast_to(np.array([0.0, 0.0, 1.0]), pts.shape).copy()
    w, h = size[0] / 2 + 40.0, size[1] / 2 + 40.0
    corners = np.array([[sx * w, sy * h, 0.0] for sx in (-1, 1) for sy in (-1, 1)])
    return Surface(pts, normals, np.full(len(pts), grid.cell_area), np.zeros(3), corners, grid=grid, name="table")


def mesh_surface(mesh: Mesh, *, samples: int = 3000, name: str = "mesh") -> Surface:
    """A mesh sampled at the centres of about ``samples`` faces (every k-th), less faces resting on the table."""
    tri = mesh.triangles()
    normals = mesh.face_normals()
    centres = tri.mean(axis=1)
    areas = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    keep = ~((normals[:, 2] < -0.9) & (centres[:, 2] < 1.0)) & (areas > 0)
    idx = np.flatnonzero(keep)
    stride = max(1, math.ceil(len(idx) / samples))
    pick = idx[::stride]
    # Each picked face stands for the area of the faces it was picked among.
    share = np.add.reduceat(areas[idx], np.arange(0, len(idx), stride))[: len(pick)]
    lo, hi = mesh.bounds
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]) * 1.1
    target = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2])
    return Surface(centres[pick], normals[pick], share, target, corners, mesh=mesh, name=name)


def irradiance(surface: Surface, sources: list[Source]) -> np.ndarray:
    """Full-white irradiance of each source at each sample, 0 where it does not reach (image, facing, the mesh itself).

    Returns
    -------
    (len(sources), n) float32
    """
    out = np.zeros((len(sources), surface.size), np.float32)
    for i, s in enumerate(sources):
        out[i] = surface_irradiance(s, surface.points, surface.normals)
    if surface.mesh is not None:
        maps = MeshMaps()
        with MeshRaster(surface.mesh) as raster:
            for i, s in enumerate(sources):
                device = s.device.scaled(DEPTH_MAP_SIZE)
                maps.shadow_maps[s.name] = (device, raster.depth_map(device))
                hidden = maps.shadowed(s.name, surface.points, surface.normals)
                out[i, hidden] = 0.0
    return out


def table_poses(poses: PoseSet | None = None) -> list[Hand]:
    """Hands over the table: ``poses`` (default 3 x 3 positions, 200 mm up, fingers -30, 0, 30 deg: 27)."""
    return (poses or PoseSet(heights=(200.0,))).hands()


def bust_poses(*, radius: float = 210.0, heights: tuple[float, ...] = (250.0, 420.0), angles: tuple[float, ...] = (0, 60, 120, 180, 240, 300)) -> list[Hand]:
    """Pointing hands around an object standing at the origin: fingertips ``radius`` mm from its axis, pointing at it."""
    out = []
    for a in angles:
        rad = math.radians(a)
        for h in heights:
            out.append(Hand(position=(radius * math.cos(rad), radius * math.sin(rad)), height=h, yaw_deg=a + 90.0, pose="point"))
    return out
