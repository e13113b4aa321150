"""The one place the coordinator converts between protobuf messages and its own types."""
from __future__ import annotations

import numpy as np

from coordinator.rig import Content, HomographyPose, ProjectionPose, SlotState, validate_lut
from protos import codec, node_pb2


def assignment_message(st: SlotState, *, content_size: tuple[int, int]) -> node_pb2.Assignment:
    msg = node_pb2.Assignment(
        revision=st.revision, slot=st.name, output_width=st.width, output_height=st.height,
        gain=st.gain, content_width=content_size[0], content_height=content_size[1],
    )
    if isinstance(st.pose, HomographyPose):
        msg.homography.m.extend(st.pose.matrix.ravel().tolist())
    elif isinstance(st.pose, ProjectionPose):
        mesh = st.pose.mesh
        msg.projection.p.extend(st.pose.matrix.ravel().tolist())
        msg.projection.near_mm = st.pose.near_mm
        msg.projection.far_mm = st.pose.far_mm
        msg.projection.mesh.mesh_id = mesh.mesh_id
        msg.projection.mesh.vertices = mesh.vertices.astype("<f4").tobytes()
        msg.projection.mesh.uvs = mesh.uvs.astype("<f4").tobytes()
        msg.projection.mesh.faces = mesh.faces.astype("<u4").tobytes()
    if st.lut is not None:
        msg.lut.CopyFrom(lut_message(st.lut))
    return msg


def lut_message(lut: np.ndarray) -> node_pb2.Lut:
    lut = np.ascontiguousarray(lut, dtype="<f4")
    return node_pb2.Lut(channels=lut.shape[0], entries=lut.shape[1], values=lut.tobytes())


def lut_from_message(msg: node_pb2.Lut) -> np.ndarray:
    if msg.channels * msg.entries * 4 != len(msg.values):
        raise ValueError(f"LUT says {msg.channels}x{msg.entries} but carries {len(msg.values)} bytes")
    lut = np.frombuffer(msg.values, dtype="<f4").reshape(msg.channels, msg.entries).astype(np.float32)
    validate_lut(lut)
    return lut


def homography_from_message(msg: node_pb2.Homography) -> HomographyPose:
    if len(msg.m) != 9:
        raise ValueError(f"a homography has 9 values, got {len(msg.m)}")
    return HomographyPose(np.array(msg.m, dtype=np.float64).reshape(3, 3))


def content_message(content: Content, *, compress: bool = False) -> node_pb2.Content:
    """The wire form of ``content`` (encode once, reuse for every packet)."""
    return node_pb2.Content(content_id=content.content_id, image=codec.encode_image(content.image, compress=compress))
