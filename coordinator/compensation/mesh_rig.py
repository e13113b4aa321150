"""A mesh rig's geometry for the compensation jobs: the posed camera, the mesh, and the texture-space
maps rendered from them (:mod:`imaging.compensation.texture_space`).

The camera's pinhole comes from ``calibration/cameras.json`` (3D calibration poses every camera
in the world); several cameras measure the rig together as one (:class:`MeshCameras`: their
images stacked top to bottom into one tall camera image); the mesh is the one the projectors' poses render (one for the whole rig). Every
map is rendered again from these inputs whenever a job needs it (a fraction of a second), so
only the light transport is stored; its fingerprint covers the camera's projection and the mesh
(:func:`geometry_key`).
"""
from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
from scipy import ndimage

from imaging.compensation.errors import CompensationError
from imaging.compensation.texture_space import (
    DeviceView,
    MeshCaster,
    TexelMap,
    padded,
    padding_index,
    texel_camera_map,
)
from coordinator.rig import Mesh, ProjectionPose, Rig

__all__ = ["MIN_COS", "MeshGeometry", "MeshCameras", "reaching_texels", "camera_projection", "rig_mesh", "geometry_key",
           "mesh_geometry", "mesh_cameras"]

#: texels and camera pixels seen more obliquely than this cosine (about 75 degrees) are not used
MIN_COS = 0.25


@dataclass(frozen=True, eq=False)
class MeshGeometry:
    """What the mesh jobs need of a mesh rig with one camera.

    ``P``: (3, 4) float64 camera projection; ``camera_shape``: (Hc, Wc); ``view``: the camera's
    view of the mesh; ``texels``: each texel's camera position and visibility; ``projectors``:
    each slot's view through its pose at its projector size (when asked for); ``padding``: the
    texture's edge padding (:func:`~imaging.compensation.texture_space.padding_index`), applied
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


@dataclass(frozen=True, eq=False)
class MeshCameras:
    """One or several posed cameras of a mesh rig measuring it together, as one camera.

    Their images (one size for all) are stacked top to bottom into one tall image, camera
    ``cameras[k]`` in rows ``k Hc .. (k + 1) Hc - 1``: the rows of ``L``, its black capture, the
    target and the solve's weights live on that image, so the solve and the store need nothing
    else; with one camera it is that camera's image. ``parts``: each camera's
    :class:`MeshGeometry` (the same mesh, content and projector views); ``reaching``: per camera,
    ``(n,) bool`` the texels whose light reaches it (:func:`reaching_texels`: in its image, not hidden,
    at any angle, or beside such a texel: the dots that must stay clear of its windows).
    """

    cameras: tuple[int, ...]
    parts: tuple[MeshGeometry, ...]
    reaching: tuple[np.ndarray, ...]

    def __post_init__(self) -> None:
        if not self.parts or len(self.parts) != len(self.cameras):
            raise ValueError(f"need one geometry per camera, got {len(self.parts)} for {self.cameras}")
        shapes = {g.camera_shape for g in self.parts}
        if len(shapes) != 1:
            sizes = ", ".join(f"camera {c}: {g.camera_shape[1]}x{g.camera_shape[0]}" for c, g in zip(self.cameras, self.parts))
            raise CompensationError(f"the cameras measured together must deliver one image size ({sizes})")

    @property
    def mesh(self) -> Mesh:
        return self.parts[0].mesh

    @property
    def content_size(self) -> tuple[int, int]:
        return self.parts[0].content_size

    @property
    def projectors(self) -> dict[str, DeviceView]:
        return self.parts[0].projectors

    @property
    def part_shape(self) -> tuple[int, int]:
        """(Hc, Wc) of one camera."""
        return self.parts[0].camera_shape

    @property
    def camera_shape(self) -> tuple[int, int]:
        """(K Hc, Wc): the stacked image."""
        hc, wc = self.part_shape
        return len(self.parts) * hc, wc

    @cached_property
    def view(self) -> DeviceView:
        """The cameras' views stacked: ``(K Hc, Wc)`` arrays."""
        if len(self.parts) == 1:
            return self.parts[0].view
        return DeviceView(*(np.vstack([getattr(g.view, k) for g in self.parts]) for k in ("x", "y", "depth", "cos")))

    @property
    def visible(self) -> np.ndarray:
        """(n,) bool: texels some camera sees."""
        return np.logical_or.reduce([g.texels.visible for g in self.parts])

    @property
    def on_mesh(self) -> np.ndarray:
        return self.parts[0].texels.on_mesh

    def key(self) -> np.ndarray:
        """:func:`geometry_key` of the cameras, in order (one camera: its own)."""
        return np.concatenate([geometry_key(g.P, g.mesh) for g in self.parts])

    def pad(self, image: np.ndarray) -> np.ndarray:
        return self.parts[0].pad(image)


def reaching_texels(texels: TexelMap, content_size: tuple[int, int]) -> np.ndarray:
    """The texels whose light reaches a camera: ``(n,) bool``, those it sees at any angle (``texels`` from
    :func:`~imaging.compensation.texture_space.texel_camera_map` with ``min_cos=0``) and their 8
    neighbours in the texture (on the mesh, with a camera position).

    A node samples the texture bilinearly, so a texel's light covers its neighbours' span on the surface:
    a texel hidden just behind the camera's silhouette of the object lights the visible texel beside it,
    where a window of that camera may lie (hidden texels are lit for another camera that sees them).
    """
    w, h = (int(v) for v in content_size)
    vis = np.asarray(texels.visible, bool)
    if vis.shape != (w * h,):
        raise ValueError(f"texels must hold {w * h} texels for a {w}x{h} texture, got {vis.shape}")
    near = ndimage.binary_dilation(vis.reshape(h, w), structure=np.ones((3, 3), bool)).reshape(-1)
    return near & texels.on_mesh & np.isfinite(texels.position).all(axis=1)


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
    return mesh_cameras(rig, slots, [camera], projectors=projectors, camera_size=camera_size).parts[0]


def mesh_cameras(rig: Rig, slots: list[str], cameras: Sequence[int], *, projectors: bool = False,
                 camera_size: tuple[int, int] | None = None) -> MeshCameras:
    """:func:`mesh_geometry` for each of ``cameras`` (one rendering context; the projectors' views once).

    Raises
    ------
    CompensationError
        A camera not posed in 3D or that does not see the mesh, or cameras of different sizes.
    """
    if not cameras or len(set(cameras)) != len(cameras):
        raise CompensationError(f"cameras must be distinct calibrated camera indices, got {list(cameras)}")
    posed = []
    for camera in cameras:
        P, size = camera_projection(rig.path, camera)
        if camera_size is not None and tuple(camera_size) != tuple(size):
            raise CompensationError(f"camera {camera} delivers {camera_size[0]}x{camera_size[1]} images but was "
                                    f"calibrated at {size[0]}x{size[1]}: calibrate again")
        posed.append((camera, P, size))
    mesh = rig_mesh(rig, slots)
    content = (rig.config.content_width, rig.config.content_height)
    seen = []
    with MeshCaster(mesh.vertices, mesh.uvs, mesh.faces) as caster:
        atlas = caster.atlas(content)
        for camera, P, size in posed:
            view = caster.view(P, size, content)
            if not view.on_mesh.any():
                raise CompensationError(f"camera {camera} does not see the mesh: check its pose (calibration)")
            every = texel_camera_map(atlas, P, view, min_cos=0.0)     # at any angle: whose light reaches it
            seen.append((view, every.at_least(MIN_COS), reaching_texels(every, content)))
        views = {}
        if projectors:
            for s in slots:
                st = rig.slot(s)
                pose = st.pose
                views[s] = caster.view(pose.matrix, (st.width, st.height), content, near=pose.near_mm, far=pose.far_mm)
    pad = padding_index(seen[0][1].on_mesh.reshape(content[1], content[0]))
    parts = tuple(MeshGeometry(mesh, P, (size[1], size[0]), content, view, texels, views, pad)
                  for (_, P, size), (view, texels, _) in zip(posed, seen))
    return MeshCameras(tuple(int(c) for c in cameras), parts, tuple(r for _, _, r in seen))
