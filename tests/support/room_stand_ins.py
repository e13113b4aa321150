"""What the room-output tests hand to a node's room output (node/outputs/room_link.py): a stand-in for
the presenter's renderer, a swap's record, and a small room with one projector lit."""
from __future__ import annotations

import time

import numpy as np

from node.outputs import SwapInfo
from sim.room import Room
from sim.scene import reference_scene


class StandInRenderer:
    """What the presenter hands to an output: something with read() -> (h, w, 3) uint8 (reused buffer)."""

    def __init__(self, w: int, h: int) -> None:
        self.buffer = np.zeros((h, w, 3), np.uint8)

    def show(self, value: int) -> "StandInRenderer":
        self.buffer[:] = value
        return self

    def read(self) -> np.ndarray:
        return self.buffer


def info(frame_id: int, slot: str = "r2c2") -> SwapInfo:
    """The record of frame ``frame_id`` swapped on ``slot`` now."""
    now = time.monotonic_ns()
    return SwapInfo(slot=slot, frame_id=frame_id, tag=f"show-{frame_id}", pts_ns=now, swap_rig_ns=now, host_monotonic_ns=now)


def small_room() -> Room:
    """The reference scene at an eighth of its projectors' and camera's size, without noise, r2c2 lit."""
    room = Room(reference_scene(projector_scale=0.125, camera_scale=0.125), noise=False)
    room.set_active(["r2c2"])
    return room
