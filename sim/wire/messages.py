"""The one place where room messages (``protos.room_pb2``) meet sim objects and numpy arrays."""
from __future__ import annotations

import numpy as np
import scipy.sparse

from protos import room_pb2
from sim.hand import Hand, HandPath
from sim.occluders import Box


def hand_to_msg(hand: Hand) -> room_pb2.HandSpec:
    return room_pb2.HandSpec(
        x=hand.position[0], y=hand.position[1], height=hand.height, yaw_deg=hand.yaw_deg, pose=hand.pose, scale=hand.scale, side=hand.side
    )


def hand_from_msg(msg: room_pb2.HandSpec) -> Hand:
    """Raises ValueError for impossible hands (bad pose, negative height)."""
    return Hand(
        position=(msg.x, msg.y),
        height=msg.height,
        yaw_deg=msg.yaw_deg,
        pose=msg.pose or "flat",
        scale=msg.scale or 1.0,
        side=msg.side or "right",
    )


def box_to_msg(box: Box) -> room_pb2.BoxSpec:
    yaw = float(np.degrees(np.arctan2(box.rotation[1, 0], box.rotation[0, 0])))
    return room_pb2.BoxSpec(center=list(box.center), size=list(box.size), yaw_deg=yaw)


def box_from_msg(msg: room_pb2.BoxSpec) -> Box:
    if len(msg.center) != 3 or len(msg.size) != 3:
        raise ValueError("a box needs 3 centre and 3 size values (mm)")
    return Box.yawed(tuple(msg.center), tuple(msg.size), msg.yaw_deg)


def path_to_msg(path: HandPath) -> room_pb2.HandPathSpec:
    return room_pb2.HandPathSpec(
        keyframes=[room_pb2.HandKeyframe(time_s=t, x=x, y=y, height=h) for t, x, y, h in path.keyframes],
        loop=path.loop,
        hand=hand_to_msg(path.template),
    )


def path_from_msg(msg: room_pb2.HandPathSpec) -> HandPath:
    template = hand_from_msg(msg.hand) if msg.HasField("hand") else Hand()
    return HandPath(tuple((k.time_s, k.x, k.y, k.height) for k in msg.keyframes), loop=msg.loop, template=template)


def occluders_to_msg(occluders=None, *, path: HandPath | None = None) -> room_pb2.SetOccludersRequest:
    """A SetOccludersRequest for hands and boxes, or for a moving hand."""
    req = room_pb2.SetOccludersRequest()
    if path is not None:
        req.path.CopyFrom(path_to_msg(path))
    for occ in occluders or []:
        if isinstance(occ, Hand):
            req.hands.append(hand_to_msg(occ))
        elif isinstance(occ, Box):
            req.boxes.append(box_to_msg(occ))
        else:
            raise TypeError(f"only hands and boxes travel over the wire, not {type(occ).__name__}")
    return req


def occluders_from_msg(msg: room_pb2.SetOccludersRequest):
    """A list of occluders, or a HandPath (what :meth:`sim.room.Room.set_occluders` takes)."""
    if msg.HasField("path") and msg.path.keyframes:
        if msg.hands or msg.boxes:
            raise ValueError("give either a moving hand (path) or still hands and boxes, not both")
        return path_from_msg(msg.path)
    return [hand_from_msg(h) for h in msg.hands] + [box_from_msg(b) for b in msg.boxes]


def sparse_to_msg(m: scipy.sparse.spmatrix) -> room_pb2.SparseMatrix:
    csr = scipy.sparse.csr_matrix(m)
    return room_pb2.SparseMatrix(
        rows=csr.shape[0],
        cols=csr.shape[1],
        indptr=np.asarray(csr.indptr, "<i8").tobytes(),
        indices=np.asarray(csr.indices, "<i4").tobytes(),
        values=np.asarray(csr.data, "<f4").tobytes(),
    )


def sparse_from_msg(msg: room_pb2.SparseMatrix) -> scipy.sparse.csr_matrix:
    """(rows, cols) float32 CSR; ValueError if the arrays do not fit together."""
    indptr = np.frombuffer(msg.indptr, "<i8")
    indices = np.frombuffer(msg.indices, "<i4")
    values = np.frombuffer(msg.values, "<f4")
    if len(indptr) != msg.rows + 1 or len(indices) != len(values) or (len(indptr) and indptr[-1] != len(values)):
        raise ValueError("malformed sparse matrix: indptr, indices and values do not fit together")
    return scipy.sparse.csr_matrix((values.astype(np.float32), indices.astype(np.int32), indptr.astype(np.int64)), shape=(int(msg.rows), int(msg.cols)))


def matrix(values, shape: tuple[int, ...]) -> np.ndarray:
    """A repeated double field as a float64 array of ``shape``."""
    arr = np.asarray(list(values), np.float64)
    if arr.size != int(np.prod(shape)):
        raise ValueError(f"expected {int(np.prod(shape))} values for shape {shape}, got {arr.size}")
    return arr.reshape(shape)
