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


def bust(*, segments: int = 96, rings: int = 140, center=(0.0, 0.0), yaw_deg: float = 0.0,
         atlas: tuple[int, int] | None = None, padding: int = 3) -> Mesh:
    """A procedural bust-like object, about 300 x 250 x 600 mm (width x depth x height).

    Built as a closed surface of revolution with elliptical cross-sections:
    a plinth, chest and shoulders (300 mm wide, 250 mm deep), a neck, and a
    head whose jaw overhangs the neck (a downward-facing ring under the chin)
    and a nose bump on the face. The face looks towards +y before ``yaw_deg``
    (counter-clockwise about +z) is applied; the base stands on z = 0 at
    ``center`` (x, y). UVs are cylindrical: u = angle around the vertical axis
    (seam at the back), v = 1 - z / 600 (top of the head at v = 0).

    With ``atlas = (W, H)`` the same surface gets an even-density uv atlas for a W x H texture
    instead, as a scan's texture would have (:func:`_ring_atlas`): the cylindrical map stretches
    a texel over tens of millimetres on the near-horizontal crown and shoulders (v is height)
    and crowds texels around the crown's pole, which a texture-space measurement cannot use.
    Charts are kept ``padding`` texels apart, so a bilinear lookup never mixes two charts.

    Returns
    -------
    Mesh with uvs, outward-facing, watertight (positions; the uv seams duplicate vertices).
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
    yaw = math.radians(yaw_deg)
    Rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]])
    shift = np.array([center[0], center[1], 0.0])
    if atlas is not None:
        rings_xyz = np.stack(verts)
        V, UV, F = _ring_atlas(rings_xyz, np.array([0.0, 0.0, 0.0]), np.array([0.0, head_cy, head_c + head_h]),
                               atlas, padding=padding)
        return _weld_seam_positions(Mesh(V @ Rz.T + shift, F, UV))
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
    return _weld_seam_positions(Mesh(V @ Rz.T + shift, F, UV))


#: a band of a surface of revolution faces up (down) when its normal's z exceeds this (is below minus it)
_CAP_NZ = 0.6


def _ring_atlas(rings: np.ndarray, bottom: np.ndarray, top: np.ndarray, texture: tuple[int, int], *,
                padding: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An even-density uv atlas for a closed surface of revolution given as rings.

    ``rings`` (R, S+1, 3) float: ring r's points bottom to top (the last point of a ring repeats
    its first); ``bottom``/``top`` (3,): the poles the caps fan to. The bands between rings are
    grouped into charts by the direction they face (their normal's z against :data:`_CAP_NZ`):
    a run facing up (down) is projected orthographically onto the xy plane (seen from above, or
    mirrored as from below): injective, since the radius is monotonic wherever the surface faces
    up or down, and a texel spans at most ``1 / _CAP_NZ`` times its width on the surface; a run
    facing sideways is unrolled: v is the arc length along each meridian, u the arc length
    around each ring scaled to the run's mean circumference (the seam where the rings start).
    Charts are packed in shelves, the same millimetres per texel along u and v, ``padding``
    texels apart and from the border, for a ``texture`` (W, H) image.

    Returns vertices (V', 3) float64, uvs (V', 2) float64 in [0, 1] ((0, 0) the top-left
    corner) and faces (F, 3) int64, counter-clockwise seen from outside.
    """
    P = np.asarray(rings, np.float64)
    n_rings, n_ring = P.shape[:2]
    seg = n_ring - 1
    centre = P[:, :seg].mean(axis=1)                                       # (R, 3)
    radius = np.linalg.norm((P[:, :seg] - centre[:, None])[..., :2], axis=2).mean(axis=1)
    dz, dr = np.diff(P[:, 0, 2]), np.diff(radius)
    nz = -dr / np.maximum(np.hypot(dz, dr), 1e-12)
    kind = np.where(nz > _CAP_NZ, 1, np.where(nz < -_CAP_NZ, -1, 0))      # per band: up, down, side
    # band b joins ring b and b + 1; band -1 is the bottom cap (down), band R - 1 the crown cap (up)
    kinds = np.concatenate([[-1], kind, [1]])
    runs, start = [], 0
    for b in range(1, len(kinds) + 1):
        if b == len(kinds) or kinds[b] != kinds[start]:
            runs.append((start - 1, b - 1, int(kinds[start])))             # bands start-1 .. b-2
            start = b
    charts = []                                                           # (vertices, planar mm, faces)
    for b0, b1, k in runs:
        r0, r1 = max(b0, 0), min(b1, n_rings - 1)                          # rings of the run
        pts = P[r0:r1 + 1].reshape(-1, 3)
        local = np.arange((r1 - r0 + 1) * n_ring).reshape(r1 - r0 + 1, n_ring)
        faces = []
        for r in range(r1 - r0):
            a, bb, c = local[r, :seg], local[r, 1:], local[r + 1, :seg]
            d = local[r + 1, 1:]
            faces += [np.column_stack([a, bb, d]), np.column_stack([a, d, c])]
        if k == 0:
            steps = np.linalg.norm(np.diff(P[r0:r1 + 1], axis=0), axis=2)  # (rings-1, S+1) along meridians
            v = np.concatenate([np.cumsum(steps[::-1], axis=0)[::-1], np.zeros((1, n_ring))])  # top ring at 0
            around = np.linalg.norm(np.diff(P[r0:r1 + 1], axis=1), axis=2)                    # (rings, S)
            frac = np.concatenate([np.zeros((r1 - r0 + 1, 1)), np.cumsum(around, axis=1)], axis=1)
            length = frac[:, -1:]
            u = frac / length * float(length.mean())
            flat = np.column_stack([u.ravel(), v.ravel()])
        else:
            flat = np.column_stack([pts[:, 0], -k * pts[:, 1]])             # from above; from below mirrored
        if b0 < 0:                                                        # the bottom cap: fan to the pole
            pole = len(pts)
            pts = np.vstack([pts, bottom])
            flat = np.vstack([flat, [bottom[0], -k * bottom[1]]])
            faces.append(np.column_stack([np.full(seg, pole), local[0, 1:], local[0, :seg]]))
        if b1 > n_rings - 1:                                              # the crown cap
            pole = len(pts)
            pts = np.vstack([pts, top])
            flat = np.vstack([flat, [top[0], -k * top[1]]])
            last = local[-1]
            faces.append(np.column_stack([last[:seg], last[1:], np.full(seg, pole)]))
        charts.append((pts, flat - flat.min(axis=0), np.vstack(faces)))
    offsets, (width, height) = _pack_shelves([c[1].max(axis=0) for c in charts], texture, padding)
    V, UV, F, base = [], [], [], 0
    for (pts, flat, faces), off in zip(charts, offsets):
        V.append(pts)
        UV.append((flat + off) / np.array([width, height]))
        F.append(faces + base)
        base += len(pts)
    return np.vstack(V), np.clip(np.vstack(UV), 0.0, 1.0), np.vstack(F)


def _pack_shelves(sizes: list[np.ndarray], texture: tuple[int, int], padding: int
                  ) -> tuple[list[np.ndarray], tuple[float, float]]:
    """Shelf packing of rectangles ``sizes`` (w, h) mm into the smallest ``W : H`` (``texture``) rectangle.

    Returns each rectangle's top-left offset (mm) and the atlas's extent (mm); rectangles are
    ``padding`` texels apart and from the border (the texel size follows from the extent).
    """
    tw, th = (int(v) for v in texture)
    if tw < 8 or th < 8:
        raise ValueError(f"an atlas needs a texture of at least 8 x 8 texels, got {tw} x {th}")
    order = sorted(range(len(sizes)), key=lambda i: -sizes[i][1])
    widest = max(float(s[0]) for s in sizes)
    best = None
    for limit in np.linspace(widest, sum(float(s[0]) for s in sizes), 64):
        # the gap in mm depends on the texel size, which depends on the packing: iterate to a fixed point
        gap = 0.0
        for _ in range(6):
            x = y = shelf = used = 0.0
            offsets = [np.zeros(2)] * len(sizes)
            for i in order:
                w, h = float(sizes[i][0]), float(sizes[i][1])
                if x > 0 and x + w > limit + 1e-9:
                    y, x, shelf = y + shelf + gap, 0.0, 0.0
                offsets[i] = np.array([x + gap, y + gap])
                x += w + gap
                used = max(used, x)
                shelf = max(shelf, h)
            W, H = used + gap, y + shelf + 2 * gap
            W, H = max(W, H * tw / th), max(H, W * th / tw)
            gap = padding * W / tw
        if best is None or W < best[1][0]:
            best = (offsets, (W, H))
    return best[0], best[1]


def _weld_seam_positions(mesh: Mesh) -> Mesh:
    """Keep seam duplicates (they carry different u) but make their positions bit-identical."""
    v = mesh.vertices.copy()
    rounded = np.round(v.astype(np.float64), 3)
    _, first, inverse = np.unique(rounded, axis=0, return_index=True, return_inverse=True)
    v = v[first][inverse.reshape(-1)]
    return Mesh(v, mesh.faces, mesh.uvs)
