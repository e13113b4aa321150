"""A rig from a planned layout: ``shadowless rig init DIR --layout FILE``.

A layout (:mod:`protos.layout`; ``shadowless plan`` writes one) says where every projector
hangs and aims, at what resolution and focal length, and what it lights: the table, an object
on it, or both. Before any hardware exists it already fixes what an operator would otherwise
type: one slot per projector (the layout's names), each slot's resolution, and the content
size (one content pixel per millimetre of the surface, :func:`content_size_of`). It also fixes
each projector's pose as planned: ``K [R | t]`` onto the layout's surface (the object's mesh,
else the table as a two-triangle mesh, :func:`table_mesh`). The rig stores that as the slot's
``planned`` pose, which is not the slot's pose: nodes never render it and no job uses it (a
transport or a compensation still refuses an uncalibrated projector); ``shadowless coverage
--planned`` reads it, and calibrating or configuring the slot replaces it. A layout with an object
also leaves the object in the rig as ``object.obj`` (world millimetres, exactly as planned), named by
``rig.toml``'s ``[calibration] mesh``, so `shadowless calibrate` poses the projectors onto it
without being told.

The coordinator does not build the room's procedural meshes: a layout naming a builtin mesh
is read with a ``builtin_mesh`` callable the command's wiring supplies (``shadowless/rig.py``).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from coordinator.errors import RigError
from coordinator.rig import (
    MAX_SIDE,
    MIN_SIDE,
    Mesh,
    ProjectionPose,
    Rig,
    init_rig,
    mesh_with_id,
)
from protos.store import atomic_write_text
from protos.layout import Layout, LayoutFileError, read_layout
from protos.mesh_files import MeshFileError, format_obj, read_mesh
from protos.spaces import scale_intrinsics

__all__ = ["OBJECT_FILE", "BuiltinMesh", "PlannedRig", "content_size_of", "init_from_layout", "planned_rig", "table_mesh"]

#: the planned object's mesh in a rig made from a layout with one (rig.toml's [calibration] mesh)
OBJECT_FILE = "object.obj"

#: a builtin mesh by name -> (vertices (V, 3), uvs (V, 2), faces (F, 3)), or None when unknown
BuiltinMesh = Callable[[str], "tuple[np.ndarray, np.ndarray, np.ndarray] | None"]


@dataclass(frozen=True, eq=False)
class PlannedRig:
    """What a layout fixes of a rig: slot -> output size, the content size, the surface, the planned poses."""

    slots: dict[str, tuple[int, int]]
    content_size: tuple[int, int]
    surface: str                       # "table" or "mesh"
    planned: dict[str, ProjectionPose]
    #: projectors the layout places but leaves off (``powered = false``, as the room's bright single
    #: unit for the P1 comparison): not slots of the rig, as they are not lit in the room
    unpowered: tuple[str, ...] = ()


def table_mesh(size_mm: tuple[float, float]) -> Mesh:
    """The table as a mesh: two triangles on z = 0, facing up (+z), spanning ``size_mm`` (w, h)
    centred on the origin, uvs as the content lies on a table (:func:`protos.spaces.content_to_table`:
    uv (0, 0) at the corner (-w/2, +h/2), u along +x, v along -y)."""
    w, h = (float(v) for v in size_mm)
    vertices = np.array([[-w / 2, h / 2, 0.0], [w / 2, h / 2, 0.0], [w / 2, -h / 2, 0.0], [-w / 2, -h / 2, 0.0]])
    uvs = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    faces = np.array([[0, 3, 2], [0, 2, 1]])       # counter-clockwise seen from above
    return mesh_with_id(vertices, uvs, faces)


def content_size_of(vertices: np.ndarray, uvs: np.ndarray, faces: np.ndarray) -> tuple[int, int]:
    """The content size (w, h) that gives a mesh about one content pixel per millimetre.

    Per triangle, the texture map's Jacobian ``J = [dX/du, dX/dv]`` (3, 2) mm per unit of uv
    solves ``[X1 - X0, X2 - X0] = J [uv1 - uv0, uv2 - uv0]``; the width is the root mean square of
    ``|dX/du|`` over the surface (weighted by each triangle's area in mm^2), the height that of
    ``|dX/dv|``, each rounded and clipped to the rig's sides. On the table mesh this is the table's
    size in mm; on a cylinder of radius r and height h mapped by angle and height, (2 pi r, h).

    Parameters
    ----------
    vertices : (V, 3) float world mm; uvs : (V, 2) float in [0, 1]; faces : (F, 3) int
    """
    v = np.asarray(vertices, np.float64)
    uv = np.asarray(uvs, np.float64)
    f = np.asarray(faces, np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or uv.shape != (len(v), 2) or f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"mesh shapes must be (V,3), (V,2), (F,3); got {v.shape}, {uv.shape}, {f.shape}")
    E = np.stack([v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]], axis=2)          # (F, 3, 2)
    D = np.stack([uv[f[:, 1]] - uv[f[:, 0]], uv[f[:, 2]] - uv[f[:, 0]]], axis=2)      # (F, 2, 2)
    det = D[:, 0, 0] * D[:, 1, 1] - D[:, 0, 1] * D[:, 1, 0]
    area = 0.5 * np.linalg.norm(np.cross(E[:, :, 0], E[:, :, 1]), axis=1)
    ok = (np.abs(det) > 1e-12) & (area > 0)
    if not ok.any():
        raise ValueError("the mesh has no triangle with an area both in the world and in its uvs")
    J = E[ok] @ np.linalg.inv(D[ok])                                                  # (F', 3, 2)
    a = area[ok] / area[ok].sum()
    side = np.sqrt((a[:, None] * (J ** 2).sum(axis=1)).sum(axis=0))                   # (2,) mm per uv unit
    w, h = (int(np.clip(round(float(s)), MIN_SIDE, MAX_SIDE)) for s in side)
    return w, h


def _surface(layout: Layout, builtin_mesh: BuiltinMesh | None) -> tuple[str, Mesh]:
    spec = layout.mesh
    if spec is None:
        if layout.table is None:
            raise RigError("the layout has neither a [table] nor a [mesh]: nothing for the projectors to light")
        return "table", table_mesh(layout.table.size)
    if spec.builtin is not None:
        arrays = builtin_mesh(spec.builtin) if builtin_mesh is not None else None
        if arrays is None:
            raise RigError(f"the layout's [mesh] is the room's builtin {spec.builtin!r}, which this install cannot build "
                           "(it needs shadowless[sim]); save it as OBJ and give [mesh] path = \"FILE.obj\"")
        vertices, uvs, faces = arrays
    else:
        try:
            m = read_mesh(spec.path)
        except MeshFileError as exc:
            raise RigError(str(exc)) from None
        if m.uvs is None:
            raise RigError(f"mesh {spec.path} has no texture coordinates: content is mapped through them (UV space)")
        vertices, uvs, faces = m.vertices, m.uvs, m.faces
    return "mesh", mesh_with_id(spec.place(vertices), uvs, faces)


def planned_rig(layout: Layout, *, builtin_mesh: BuiltinMesh | None = None, resolution: tuple[int, int] | None = None,
                content_size: tuple[int, int] | None = None) -> PlannedRig:
    """What ``layout`` fixes of a rig. ``resolution`` gives every slot that output size instead of
    the layout's (the planned poses follow: the same optics sampled at that size, e.g. the room's
    scaled projectors); ``content_size`` replaces the one of the surface."""
    surface, mesh = _surface(layout, builtin_mesh)
    slots: dict[str, tuple[int, int]] = {}
    planned: dict[str, ProjectionPose] = {}
    unpowered: list[str] = []
    for d in layout.projectors:
        if d.name in slots or d.name in unpowered:
            raise RigError(f"the layout names projector {d.name!r} twice; slot names must be unique")
        if d.entry.get("powered", True) is False:
            unpowered.append(d.name)
            continue
        size = tuple(resolution) if resolution is not None else d.size
        K = d.K if size == d.size else scale_intrinsics(d.K, d.size, size)
        slots[d.name] = size
        try:
            planned[d.name] = ProjectionPose(K @ np.hstack([d.R, d.t[:, None]]), mesh)
        except ValueError as exc:
            raise RigError(f"projector {d.name}: {exc}") from None
    if not slots:
        raise RigError(f"every projector of the layout is unpowered ({', '.join(unpowered)}): nothing to make slots of")
    if content_size is None:
        content_size = content_size_of(mesh.vertices, mesh.uvs, mesh.faces)
    return PlannedRig(slots, tuple(content_size), surface, planned, tuple(unpowered))


def init_from_layout(path: str | Path, layout_file: str | Path, *, name: str | None = None,
                     builtin_mesh: BuiltinMesh | None = None, resolution: tuple[int, int] | None = None,
                     content_size: tuple[int, int] | None = None, latency_ms: float = 50.0,
                     force: bool = False) -> tuple[Path, PlannedRig]:
    """Create a rig directory from the layout at ``layout_file`` (:func:`coordinator.rig.init_rig`),
    then store each slot's planned pose. Refusals are one-line RigErrors; nothing is written
    unless the layout is whole."""
    try:
        layout = read_layout(layout_file)
    except LayoutFileError as exc:
        raise RigError(str(exc)) from None
    plan = planned_rig(layout, builtin_mesh=builtin_mesh, resolution=resolution, content_size=content_size)
    sizes = list(plan.slots.values())
    width, height = max(sizes, key=sizes.count)               # the most common size is the default
    mesh_file = OBJECT_FILE if plan.surface == "mesh" else None
    path = init_rig(path, name=name or Path(path).resolve().name, slots=list(plan.slots), width=width, height=height,
                    content_width=plan.content_size[0], content_height=plan.content_size[1], latency_ms=latency_ms,
                    force=force, sizes=plan.slots, calibration_mesh=mesh_file)
    if mesh_file is not None:
        # the object as placed in the room, exactly: calibration on it gives poses onto the planned mesh
        m = next(iter(plan.planned.values())).mesh
        atomic_write_text(Path(path) / mesh_file, format_obj(m.vertices, m.faces, m.uvs, exact=True,
                                                             comment="the object of the planned layout (millimetres, world)"))
    rig = Rig(path)
    for slot, pose in plan.planned.items():
        rig.update_slot(slot, planned=pose, size=plan.slots[slot], source="layout")
    return path, plan
