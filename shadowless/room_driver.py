"""An in-process rig in the virtual room: a :class:`~coordinator.jobs.driver.RigDriver` that
tests and benchmarks run the coordinator's jobs on, without gRPC or node processes.

What every node would output is computed with the node's own convention
(:func:`protos.spaces.warp_content`: the warp through the slot's stored pose, its gain and
LUT, ``round(255 v)``; on a 3x4 pose the mesh's texture as the node's mesh shader samples it,
:func:`imaging.compensation.texture_space.mesh_warp`) and given to the room; captures come
from the room's cameras. So the figures measured through it are the method's, not the transport's.

    room = Room(reference_scene(...))
    driver = RoomDriver(room, rig)
    result = await driver.run("calibrate", {"table_points": ...})
"""
from __future__ import annotations

import asyncio
import time
from typing import Any, Mapping, Sequence

import numpy as np

from coordinator.api import PlayResult
from coordinator.camera import CameraError
from imaging.compensation.texture_space import DeviceView, MeshCaster, content_at_view, mesh_warp
from coordinator.jobs.context import Event
from coordinator.jobs.registry import run_job
from coordinator.rig import Content, ProjectionPose, Rig
from protos.spaces import blended_output, warp_content
from sim.room import Room

__all__ = ["RoomDriver", "RoomCamera"]


class RoomCamera:
    """Camera ``index`` of an in-process room (blocking; the job calls it from a worker thread).

    ``base_exposure``: the exposure a capture uses when the job asks for none (None: the room
    camera's own); a job's relative ``exposure`` multiplies it.
    """

    supports_exposure = True

    def __init__(self, room: Room, index: int, *, base_exposure: float | None = None,
                 on_capture: Any = None):
        if not 0 <= index < len(room.scene.cameras):
            raise CameraError(f"the room has {len(room.scene.cameras)} camera(s), not {index + 1}")
        self.room, self.index = room, index
        self.spec = f"room-in-process:{index}"
        self.base_exposure = base_exposure
        self._on_capture = on_capture

    @property
    def size(self) -> tuple[int, int]:
        return self.room.camera_size(self.index)

    def capture(self, *, exposure: float | None = None) -> np.ndarray:
        if self._on_capture is not None:
            self._on_capture()
        if exposure is None:
            return self.room.capture(self.index, exposure=self.base_exposure)
        base = self.base_exposure if self.base_exposure is not None else self.room.truth.camera(self.index).exposure
        return self.room.capture(self.index, exposure=base * float(exposure))

    def close(self) -> None:
        pass


class RoomDriver:
    """A rig whose projectors and cameras are an in-process :class:`sim.room.Room`.

    Parameters
    ----------
    room : sim.room.Room
    rig : coordinator.rig.Rig
        Its slots must be room projectors; each is connected unless listed in ``offline``.
    cameras : int
        How many of the room's cameras jobs see (default 1).
    exposure : float, optional
        Camera exposure for every capture (None: the room camera's own).
    unpowered : slots whose projector stays dark whatever it is shown (a projector that is off).
    offline : slots whose node is not connected.
    """

    def __init__(self, room: Room, rig: Rig, *, cameras: int = 1, exposure: float | None = None,
                 unpowered: Sequence[str] = (), offline: Sequence[str] = ()):
        self.room = room
        self._rig = rig
        self._specs = [f"room-in-process:{i}" for i in range(cameras)]
        self.exposure = exposure
        self.offline = set(offline)
        self.events: list[Event] = []
        #: captures taken through this driver's cameras so far
        self.captures = 0
        #: the last still shown (content-space) and the frames of the last play
        self.shown: Content | None = None
        self.played: list[np.ndarray] = []
        self._mesh_views: dict[str, tuple[bytes, DeviceView]] = {}
        room.set_active([s for s in rig.slots if s not in set(unpowered)])

    # ------------------------------------------------------------------ RigDriver
    @property
    def rig(self) -> Rig:
        return self._rig

    @property
    def camera_specs(self) -> list[str]:
        return list(self._specs)

    def live_slots(self) -> list[str]:
        return [s for s in self._rig.slots if s not in self.offline]

    def open_camera(self, spec: str) -> RoomCamera:
        prefix = "room-in-process:"
        if not spec.startswith(prefix) or not spec[len(prefix):].isdigit():
            raise CameraError(f"camera {spec}: the in-process room offers cameras {', '.join(self._specs)}")
        return RoomCamera(self.room, int(spec[len(prefix):]), base_exposure=self.exposure, on_capture=self._count)

    def _count(self) -> None:
        self.captures += 1

    async def show_patterns(self, images: Mapping[str, np.ndarray | None], *, content: np.ndarray | None = None,
                            apply_lut: bool = False, settle_s: float = 0.05) -> None:
        if content is not None:
            await asyncio.to_thread(self.render_content, content, apply_lut=apply_lut)
            return
        for s in self.live_slots():
            st = self._rig.slot(s)
            img = images.get(s)
            frame = np.zeros((st.height, st.width, 3), np.uint8) if img is None else np.asarray(img)
            if frame.ndim == 2:
                frame = np.repeat(frame[:, :, None], 3, axis=2)
            if frame.shape[:2] != (st.height, st.width):
                raise ValueError(f"pattern for {s} is {frame.shape[1]}x{frame.shape[0]}, "
                                 f"its projector is {st.width}x{st.height}")
            self.room.set_frame(s, frame)

    def show_still(self, image: np.ndarray, *, name: str, persist: bool) -> None:
        content = Content(np.ascontiguousarray(image), name=name)
        if persist:
            self._rig.set_content(content)
        self.render_content(content.image)
        self.shown = content

    async def play(self, frames: Sequence[np.ndarray], *, fps: float, loops: int = 0) -> PlayResult:
        t0 = time.monotonic()
        count = len(frames) * (loops + 1)
        for i in range(count):
            await asyncio.to_thread(self.render_content, frames[i % len(frames)])
        self.played = list(frames)
        return PlayResult(frames_sent=count, frames_shown=count, nodes=len(self.live_slots()),
                          wall_s=time.monotonic() - t0)

    def update_slot(self, slot: str, **changes: Any) -> None:
        self._rig.update_slot(slot, **changes)

    # ------------------------------------------------------------------ helpers
    def render_content(self, image: np.ndarray | None, *, apply_lut: bool = True) -> None:
        """Give the room what every live node would output for content ``image`` (None: black)."""
        cw, ch = self._rig.config.content_width, self._rig.config.content_height
        img = None if image is None else np.asarray(image)
        if img is not None and img.shape[:2] != (ch, cw):
            raise ValueError(f"content is {img.shape[1]}x{img.shape[0]}, the rig's is {cw}x{ch}")
        for s in self.live_slots():
            st = self._rig.slot(s)
            if img is None or st.pose is None:
                frame = np.zeros((st.height, st.width, 3), np.uint8)
            elif isinstance(st.pose, ProjectionPose):
                view = self.mesh_view(s)
                if apply_lut and st.blend is not None:      # the node's blended pipeline on the mesh's pixels
                    vals = content_at_view(img, view)
                    vals = np.repeat(vals, 3, axis=2) if vals.shape[2] == 1 else vals[:, :, :3]
                    frame = blended_output(vals, st.blend.alpha, st.blend.beta, lut=st.lut, gain=st.gain)
                    frame[~view.on_mesh] = 0
                else:
                    frame = mesh_warp(img, view, lut=st.lut, gain=st.gain, apply_lut=apply_lut)
            else:
                frame = warp_content(img, st.pose.matrix, (st.width, st.height), lut=st.lut, gain=st.gain,
                                     apply_lut=apply_lut,
                                     blend=None if st.blend is None else (st.blend.alpha, st.blend.beta))
            self.room.set_frame(s, frame)

    def mesh_view(self, slot: str) -> DeviceView:
        """The mesh as ``slot``'s 3x4 pose renders it at its projector size (uv per pixel; rendered again only
        when the pose, its mesh or the projector size changed)."""
        st = self._rig.slot(slot)
        pose = st.pose
        if not isinstance(pose, ProjectionPose):
            raise ValueError(f"{slot} has no 3D pose")
        key = pose.matrix.tobytes() + pose.mesh.mesh_id.encode() + repr(
            (pose.near_mm, pose.far_mm, st.width, st.height, self._rig.config.content_width,
             self._rig.config.content_height)).encode()
        hit = self._mesh_views.get(slot)
        if hit is None or hit[0] != key:
            content = (self._rig.config.content_width, self._rig.config.content_height)
            with MeshCaster(pose.mesh.vertices, pose.mesh.uvs, pose.mesh.faces) as caster:
                view = caster.view(pose.matrix, (st.width, st.height), content, near=pose.near_mm, far=pose.far_mm)
            hit = self._mesh_views[slot] = (key, view)
        return hit[1]

    async def run(self, kind: str, params: Mapping[str, Any] | None = None) -> dict:
        """Run the coordinator's job ``kind`` on this rig; its events go to :attr:`events`."""
        return await run_job(self, kind, params or {}, emit=self.events.append)
