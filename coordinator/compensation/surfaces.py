"""Which :class:`~coordinator.compensation.surface.Surface` a job's projectors light."""
from __future__ import annotations

from coordinator.compensation.mesh_surface import MeshSurface
from coordinator.compensation.planar_surface import PlanarSurface
from coordinator.compensation.surface import Surface
from coordinator.jobs import JobContext, JobError
from coordinator.rig import ProjectionPose

__all__ = ["surface_for", "surface_of"]


def surface_of(ctx: JobContext, slots: list[str]) -> str:
    """``"table"`` when every slot has a homography pose, ``"mesh"`` when every one has a 3D pose; a rig
    with both is refused (its light transport would mix two content spaces)."""
    solid = [s for s in slots if isinstance(ctx.rig.slot(s).pose, ProjectionPose)]
    if not solid:
        return "table"
    if len(solid) == len(slots):
        return "mesh"
    flat = [s for s in slots if s not in solid]
    raise JobError(f"projector {solid[0]} has a 3D pose and {flat[0]} a homography: this job supports planar rigs "
                   "(a table) or a mesh, not both at once (choose the projectors with --slots)")


def surface_for(ctx: JobContext, slots: list[str]) -> Surface:
    """A new surface object for one job on ``slots`` (:func:`surface_of` decides which)."""
    return MeshSurface() if surface_of(ctx, slots) == "mesh" else PlanarSurface()
