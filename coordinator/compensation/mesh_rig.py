"""A mesh rig's geometry for the compensation jobs: the posed camera, the mesh, and the texture-space
maps rendered from them (:mod:`coordinator.compensation.texture_space`).

The camera's pinhole comes from ``calibration/cameras.json`` (3D calibration poses every camera
in the world); the mesh is the one the projectors' poses render (one for the whole rig). Every
map is rendered again from these inputs whenever a job needs it (a fraction of a second), so
only the light transport is stored; its fingerprint covers the camera's projection and the mesh
(:func:`geometry_key`).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from coordinator.compensation.errors import CompensationError
from coordinator.compensation.texture_space import (
    DeviceView,
    MeshCaster,
    TexelMap,
    padded,
    padding_index,
    texel_camera_map,
)
from coordinator.rig import Mesh, ProjectionPose, Rig

__all__ = ["MIN_COS", "MeshGeometry", "camera_projection", "rig_mesh", "geometry_key", "mesh_geometry"]

#: texels and camera pixels seen more obliquely than this cosine (about 75 degrees) are not used
MIN_COS = 0.25


@dataclass(frozen=True, eq=False)
class MeshGeometry:
    """What the mesh jobs need of a mesh rig with one camera.

    ``P``: (3, 4) float64 camera projection; ``camera_shape``: (Hc, Wc); ``view``: the camera's
    view of the mesh; ``texels``: each texel's camera position and visibility; ``projectors``:
    each slot's view through its pose at its projector size (when asked for); ``padding``: the
    texture's edge padding (:func:`~coordinator.compensation.texture_space.padding_index`), applied
    to every image the nodes are sent (:meth:`pad`).
    """

    mesh: Mesh
    P: np.ndarray
    camera_shape: tuple[int, int]
    content_size: tuple[int, int]
    view: DeviceView
    texels: TexelMap
    projectors: dict[str, DeviceView]
    padding: np.ndarray

    def pad(self, image: np.ndarray) -> np.ndarray:
        """``image`` (H, W[, C]) in texture space with its chart edges padded."""
        return padded(image, self.padding)


def camera_projection(rig_dir: str | Path, camera: int) -> tuple[np.ndarray, tuple[int, int]]:
    """Camera ``camera``'s world -> pixel projection ``(3, 4) float64`` and image size ``(w, h)``, from
    ``calibration/cameras.json``.

    Raises
    ------
    CompensationError
        No calibration, or the camera was not posed in 3D.
    """
    f = Path(rig_dir) / "calibration" / "cameras.json"
    try:
        doc = json.loads(f.read_text())
    except FileNotFoundError:
        raise CompensationError(f"{f}: no camera calibration; run `shadowless calibrate` with the mesh first") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise CompensationError(f"{f}: unreadable camera calibration ({exc}); run `shadowless calibrate` again") from exc
    entry = next((c for c in doc.get("cameras", []) if int(c.get("camera", -1)) == camera), None)
    if entry is None or "pinhole" not in entry:
        raise CompensationError(f"{f}: camera {camera} was not posed in 3D; calibrate the mesh with it "
                                "(`shadowless calibrate --mesh ...`)")
    try:
        p = entry["pinhole"]
        K, R, t = (np.asarray(p[k], np.float64) for k in ("K", "R", "t"))
        P = K @ np.column_stack([R, t.reshape(3)])
        size = tuple(int(v) for v in p["size"])
    except (KeyError, TypeError, ValueError) as exc:
        raise CompensationError(f"{f}: camera {camera}'s pose is malformed ({exc}); calibrate again") from exc
    if not np.all(np.isfinite(P)) or len(size) != 2 or min(size) < 1:
        raise CompensationError(f"{f}: camera {camera}'s pose is degenerate; calibrate again")
    return P, size  # type: ignore[return-value]


def rig_mesh(rig: Rig, slots: list[str]) -> Mesh:
    """The mesh every one of ``slots`` renders (their poses must share it)."""
    meshes = {}
    for s in slots:
        pose = rig.slot(s).pose
        if not isinstance(pose, ProjectionPose):
            raise CompensationError(f"projector {s} has no 3D pose")
        meshes.setdefault(pose.mesh.mesh_id, pose.mesh)
    if len(meshes) != 1:
        raise CompensationError(f"the projectors render different meshes ({', '.join(sorted(meshes))}): calibrate "
                                "them together")
    return next(iter(meshes.values()))


def geometry_key(P: np.ndarray, mesh: Mesh) -> np.ndarray:
    """What a mesh rig's ``L`` depends on beyond the slots: the camera's projection and the mesh, as a float64
    array for :func:`coordinator.compensation.store.rig_state_fingerprint`."""
    digest = [float(int(mesh.mesh_id[i:i + 8], 16)) for i in range(0, min(len(mesh.mesh_id), 16), 8)] \
        if all(c in "0123456789abcdef" for c in mesh.mesh_id) else [float(len(mesh.vertices)), float(len(mesh.faces))]
    return np.concatenate([np.asarray(P, np.float64).ravel(), digest])


def mesh_geometry(rig: Rig, slots: list[str], camera: int, *, projectors: bool = False,
                  camera_size: tuple[int, int] | None = None) -> MeshGeometry:
    """Render the maps of a mesh rig (blocking, OpenGL: run it on a worker thread).

    ``camera_size``: the size the camera delivers now (w, h), checked against its calibration.
    """
    P, size = camera_projection(rig.path, camera)
    if camera_size is not None and tuple(camera_size) != tuple(size):
        raise CompensationError(f"camera {camera} delivers {camera_size[0]}x{camera_size[1]} images but was calibrated "
                                f"at {size[0]}x{size[1]}: calibrate again")
    mesh = rig_mesh(rig, slots)
    content = (rig.config.content_width, rig.config.content_height)
    with MeshCaster(mesh.vertices, mesh.uvs, mesh.faces) as caster:
        view = caster.view(P, size, content)
        texels = texel_camera_map(caster.atlas(content), P, view, min_cos=MIN_COS)
        views = {}
        if projectors:
            for s in slots:
                st = rig.slot(s)
                pose = st.pose
                views[s] = caster.view(pose.matrix, (st.width, st.height), content, near=pose.near_mm, far=pose.far_mm)
    if not view.on_mesh.any():
        raise CompensationError(f"camera {camera} does not see the mesh: check its pose (calibration)")
    pad = padding_index(texels.on_mesh.reshape(content[1], content[0]))
    return MeshGeometry(mesh, P, (size[1], size[0]), content, view, texels, views, pad)
