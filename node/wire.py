"""The one place a node converts protobuf messages into its own plain types."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from protos import node_pb2


@dataclass(frozen=True)
class MeshData:
    mesh_id: str
    vertices: np.ndarray   # (V, 3) float32, world mm
    uvs: np.ndarray        # (V, 2) float32 in [0, 1]
    faces: np.ndarray      # (F, 3) uint32


@dataclass(frozen=True)
class NodeAssignment:
    revision: int
    slot: str
    width: int
    height: int
    pose_kind: str                       # "homography", "projection" or "none"
    homography: np.ndarray | None        # (3, 3) float64, content px -> projector px
    projection: np.ndarray | None        # (3, 4) float64, world mm -> projector px
    mesh: MeshData | None
    near_mm: float
    far_mm: float
    lut: np.ndarray | None               # (C, E) float32
    gain: float
    content_size: tuple[int, int]


@dataclass(frozen=True)
class FrameOrder:
    frame_id: int
    pts_ns: int
    content_id: str                      # "" = black
    space: str                           # "content" or "projector"
    apply_lut: bool
    tag: str


def assignment_from_message(msg: node_pb2.Assignment) -> NodeAssignment:
    kind = msg.WhichOneof("pose") or "none"
    homography = projection = None
    mesh = None
    near, far = 100.0, 10_000.0
    if kind == "homography":
        if len(msg.homography.m) != 9:
            raise ValueError(f"homography needs 9 values, got {len(msg.homography.m)}")
        homography = np.array(msg.homography.m, dtype=np.float64).reshape(3, 3)
    elif kind == "projection":
        if len(msg.projection.p) != 12:
            raise ValueError(f"projection needs 12 values, got {len(msg.projection.p)}")
        projection = np.array(msg.projection.p, dtype=np.float64).reshape(3, 4)
        m = msg.projection.mesh
        v = np.frombuffer(m.vertices, dtype="<f4").reshape(-1, 3).astype(np.float32)
        uv = np.frombuffer(m.uvs, dtype="<f4").reshape(-1, 2).astype(np.float32)
        f = np.frombuffer(m.faces, dtype="<u4").reshape(-1, 3).astype(np.uint32)
        if uv.shape[0] != v.shape[0] or (f.size and int(f.max()) >= v.shape[0]):
            raise ValueError("mesh arrays are inconsistent")
        mesh = MeshData(m.mesh_id, v, uv, f)
        near, far = msg.projection.near_mm or near, msg.projection.far_mm or far
    lut = None
    if msg.HasField("lut"):
        lut = np.frombuffer(msg.lut.values, dtype="<f4").astype(np.float32)
        if lut.size != msg.lut.channels * msg.lut.entries or msg.lut.channels not in (1, 3) or msg.lut.entries < 2:
            raise ValueError("LUT message is inconsistent")
        lut = lut.reshape(msg.lut.channels, msg.lut.entries)
    return NodeAssignment(
        revision=msg.revision, slot=msg.slot, width=msg.output_width, height=msg.output_height, pose_kind=kind,
        homography=homography, projection=projection, mesh=mesh, near_mm=near, far_mm=far, lut=lut,
        gain=msg.gain if msg.gain > 0 else 1.0, content_size=(msg.content_width, msg.content_height),
    )


def frame_for_slot(msg: node_pb2.Frame, slot: str) -> FrameOrder:
    cid = msg.slot_content[slot] if slot in msg.slot_content else msg.content_id
    space = "projector" if msg.space == node_pb2.SPACE_PROJECTOR else "content"
    return FrameOrder(frame_id=msg.frame_id, pts_ns=msg.pts_ns, content_id=cid, space=space,
                      apply_lut=msg.apply_lut, tag=msg.tag)
