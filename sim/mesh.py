"""Triangle meshes: normals, the procedural bust, OBJ/PLY files (through protos.mesh_files).

A :class:`Mesh` holds ``vertices (V, 3) float32`` in world millimetres,
``faces (F, 3) uint32`` (counter-clockwise seen from outside), and optionally
``uvs (V, 2) float32`` in [0, 1] with (0, 0) the top-left corner of the content
image (the project's convention). OBJ and PLY store texture v growing upwards,
so reading and writing flip v (``v_ours = 1 - v_file``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from protos.mesh_files import MeshFileError, format_obj, format_ply, read_mesh
from sim.errors import MeshError


@dataclass(frozen=True, eq=False)
class Mesh:
    """An indexed triangle mesh (world millimetres)."""

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None = None

    def __post_init__(self) -> None:
        v = np.ascontiguousarray(self.vertices, dtype=np.float32)
        f = np.asarray(self.faces)
        if v.ndim != 2 or v.shape[1] != 3:
            raise ValueError(f"vertices must be (V, 3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3:
            raise ValueError(f"faces must be (F, 3), got {f.shape}")
        if f.size and (f.min() < 0 or f.max() >= len(v)):
            raise MeshError(f"faces reference vertex {int(f.max())} but the mesh has {len(v)} vertices")
        if not np.all(np.isfinite(v)):
            raise MeshError("vertices contain NaN or infinite coordinates")
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", np.ascontiguousarray(f, dtype=np.uint32))
        if self.uvs is not None:
            uv = np.ascontiguousarray(self.uvs, dtype=np.float32)
            if uv.shape != (len(v), 2):
                raise ValueError(f"uvs must be (V, 2) = ({len(v)}, 2), got {uv.shape}")
            object.__setattr__(self, "uvs", uv)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min (3,), max (3,)) float64 corners of the axis-aligned bounding box."""
        return self.vertices.min(axis=0).astype(np.float64), self.vertices.max(axis=0).astype(np.float64)

    def triangles(self) -> np.ndarray:
        """(F, 3, 3) float64 corner coordinates of every face."""
        return self.vertices.astype(np.float64)[self.faces]

    def face_normals(self) -> np.ndarray:
        """(F, 3) float64 unit normals (right-hand rule on the face order)."""
        tri = self.triangles()
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        norm = np.linalg.norm(n, axis=1, keepdims=True)
        return n / np.where(norm > 0, norm, 1.0)

    def vertex_normals(self) -> np.ndarray:
        """(V, 3) float32 unit normals: area-weighted average of adjacent faces."""
        tri = self.triangles()
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length = 2 * area
        acc = np.zeros((len(self.vertices), 3))
        for k in range(3):
            np.add.at(acc, self.faces[:, k], n)
        norm = np.linalg.norm(acc, axis=1, keepdims=True)
        return (acc / np.where(norm > 0, norm, 1.0)).astype(np.float32)

    def signed_volume(self) -> float:
        """Enclosed volume in mm^3 (positive when faces wind outwards)."""
        tri = self.triangles()
        return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)

    def transformed(self, *, rotation: np.ndarray | None = None, translation=(0.0, 0.0, 0.0), scale: float = 1.0) -> "Mesh":
        """A copy moved by ``x -> scale * rotation @ x + translation``."""
        R = np.eye(3) if rotation is None else np.asarray(rotation, np.float64)
        v = (scale * self.vertices.astype(np.float64)) @ R.T + np.asarray(translation, np.float64)
        return Mesh(v, self.faces, self.uvs)


# ---------------------------------------------------------------- OBJ / PLY


def load_mesh(path: str | Path) -> Mesh:
    """Read a triangle mesh from ``.obj`` or ``.ply`` (ASCII or binary), through
    :mod:`protos.mesh_files`. Raises :class:`MeshError` naming the file and the problem."""
    try:
        m = read_mesh(path)
    except MeshFileError as exc:
        raise MeshError(str(exc)) from None
    return Mesh(m.vertices, m.faces, m.uvs)


def save_mesh(mesh: Mesh, path: str | Path, *, binary: bool = True) -> None:
    """Write ``mesh`` as ``.obj`` (text) or ``.ply`` (binary little-endian, or ASCII)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".obj":
        path.write_text(format_obj(mesh.vertices, mesh.faces, mesh.uvs, comment="shadowless sim mesh (millimetres)"))
    elif suffix == ".ply":
        path.write_bytes(format_ply(mesh.vertices, mesh.faces, mesh.uvs, binary=binary,
                                   comment="shadowless sim mesh (millimetres)"))
    else:
        raise MeshError(f"{path}: unknown mesh format {suffix!r}; use .obj or .ply")


# ---------------------------------------------------------------- primitives


def table_mesh(size: tuple[float, float] = (1200.0, 600.0)) -> Mesh:
    """The table top as two triangles at z = 0, uv (0, 0) at the (-x, +y) corner.

    The content image of a planar rig is a metric grid on the table seen from
    above: content x along world +x, content y along world -y.
    """
    w, h = size
    v = np.array([[-w / 2, h / 2, 0], [w / 2, h / 2, 0], [w / 2, -h / 2, 0], [-w / 2, -h / 2, 0]], np.float64)
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float64)
    return Mesh(v, np.array([[0, 2, 1], [0, 3, 2]]), uv)


def bust(*, segments: int = 96, rings: int = 140, center=(0.0, 0.0), yaw_deg: float = 0.0) -> Mesh:
    """A procedural bust-like object, about 300 x 250 x 600 mm (width x depth x height).

    Built as a closed surface of revolution with elliptical cross-sections:
    a plinth, chest and shoulders (300 mm wide, 250 mm deep), a neck, and a
    head whose jaw overhangs the neck (a downward-facing ring under the chin)
    and a nose bump on the face. The face looks towards +y before ``yaw_deg``
    (counter-clockwise about +z) is applied; the base stands on z = 0 at
    ``center`` (x, y). UVs are cylindrical: u = angle around the vertical axis
    (seam at the back), v = 1 - z / 600 (top of the head at v = 0).

    Returns
    -------
    Mesh with uvs, outward-facing, watertight.
    """
    from scipy.interpolate import PchipInterpolator

    if segments < 8 or rings < 20:
        raise ValueError("need segments >= 8 and rings >= 20")
    chest_z = [40.0, 150.0, 240.0, 285.0, 310.0, 320.0]
    chest_rx = PchipInterpolator(chest_z, [135.0, 145.0, 150.0, 130.0, 85.0, 52.0])
    chest_ry = PchipInterpolator(chest_z, [110.0, 125.0, 115.0, 95.0, 68.0, 50.0])
    chest_cy = PchipInterpolator(chest_z, [0.0, 0.0, 0.0, 4.0, 8.0, 10.0])
    head_c, head_h, head_rx, head_ry, head_cy = 480.0, 120.0, 80.0, 88.0, 20.0

    def section(z: float, part: str) -> tuple[float, float, float]:
        if part == "plinth":
            return 115.0, 100.0, 0.0
        if part == "chest":
            return float(chest_rx(z)), float(chest_ry(z)), float(chest_cy(z))
        if part == "neck":
            return 52.0, 50.0, 10.0
        s = math.sqrt(max(0.0, 1.0 - ((z - head_c) / head_h) ** 2))
        return head_rx * s, head_ry * s, head_cy

    # Ring list (z, part); duplicated z where the profile steps (plinth top, under the chin).
    n_chest = max(8, rings * 40 // 100)
    n_neck = max(3, rings * 8 // 100)
    n_head = max(10, rings - n_chest - n_neck - 4)
    ring_defs: list[tuple[float, str]] = [(0.0, "plinth"), (40.0, "plinth")]
    ring_defs += [(z, "chest") for z in np.linspace(40.0, 320.0, n_chest)]
    ring_defs += [(z, "neck") for z in np.linspace(320.0, 390.0, n_neck)[1:]]
    # Head rings: uniform in the polar angle so the crown is well sampled, stopping short of the pole.
    t0 = math.acos((390.0 - head_c) / head_h)
    ring_defs += [(head_c + head_h * math.cos(t), "head") for t in np.linspace(t0, 0.06, n_head)]

    phis = np.linspace(-math.pi / 2, 3 * math.pi / 2, segments + 1)  # seam at the back (-y), duplicated
    verts: list[np.ndarray] = []
    uvs: list[np.ndarray] = []
    for z, part in ring_defs:
        rx, ry, cy = section(z, part)
        scale = np.ones_like(phis)
        if part == "head":  # the nose: a bump on the face (phi = +90 deg points to +y)
            scale = 1.0 + 0.18 * np.exp(-(((phis - math.pi / 2) / 0.16) ** 2) - ((z - 470.0) / 28.0) ** 2)
        x = rx * np.cos(phis) * scale
        y = cy + ry * np.sin(phis) * scale
        verts.append(np.column_stack([x, y, np.full_like(phis, z)]))
        uvs.append(np.column_stack([(phis + math.pi / 2) / (2 * math.pi), np.full_like(phis, 1.0 - z / 600.0)]))
    n_ring = segments + 1
    V = np.vstack(verts)
    UV = np.vstack(uvs)
    faces = []
    for r in range(len(ring_defs) - 1):
        a = r * n_ring + np.arange(segments)
        b = a + 1
        c = a + n_ring
        d = c + 1
        # ring r is below ring r+1; counter-clockwise from outside: (a, b, d), (a, d, c)
        faces.append(np.column_stack([a, b, d]))
        faces.append(np.column_stack([a, d, c]))
    # Caps: bottom centre (facing down) and the crown pole.
    bottom = len(V)
    top = bottom + 1
    V = np.vstack([V, [[0.0, 0.0, 0.0], [0.0, head_cy, head_c + head_h]]])
    UV = np.vstack([UV, [[0.5, 1.0], [0.5, 0.0]]])
    first = np.arange(segments)
    faces.append(np.column_stack([np.full(segments, bottom), first + 1, first]))
    last = (len(ring_defs) - 1) * n_ring + np.arange(segments)
    faces.append(np.column_stack([last, last + 1, np.full(segments, top)]))
    F = np.vstack(faces)
    yaw = math.radians(yaw_deg)
    Rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]])
    mesh = Mesh(V @ Rz.T + np.array([center[0], center[1], 0.0]), F, UV)
    return _weld_seam_positions(mesh)


def _weld_seam_positions(mesh: Mesh) -> Mesh:
    """Keep seam duplicates (they carry different u) but make their positions bit-identical."""
    v = mesh.vertices.copy()
    rounded = np.round(v.astype(np.float64), 3)
    _, first, inverse = np.unique(rounded, axis=0, return_index=True, return_inverse=True)
    v = v[first][inverse.reshape(-1)]
    return Mesh(v, mesh.faces, mesh.uvs)
