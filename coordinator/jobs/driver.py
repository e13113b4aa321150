"""The rig as a job drives it: the :class:`RigDriver` protocol.

Two implementations exist: the :class:`coordinator.server.Coordinator` (real nodes over
gRPC, cameras from specs) and the in-process virtual-room harness
(:class:`shadowless.room_driver.RoomDriver`) that tests and benchmarks use. Jobs never see
either: they see a :class:`coordinator.jobs.context.JobContext` built on one.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Mapping, Protocol, Sequence

import numpy as np

from coordinator.api import PlayResult

if TYPE_CHECKING:  # pragma: no cover - types only
    from coordinator.camera import Camera
    from coordinator.rig import Rig


class RigDriver(Protocol):
    """What a rig offers the jobs that run on it."""

    @property
    def rig(self) -> "Rig":
        """The rig's persisted state (slots, poses, LUTs, gains, content, directory)."""

    @property
    def camera_specs(self) -> list[str]:
        """The rig's cameras, in order (specs, see :mod:`coordinator.camera`)."""

    def live_slots(self) -> list[str]:
        """Slots whose node is connected and showing frames, in rig order."""

    async def show_patterns(self, images: Mapping[str, np.ndarray | None], *, content: np.ndarray | None = None,
                            apply_lut: bool = False, settle_s: float = 0.05) -> None:
        """Show per-slot projector-space images (``None``/absent: black) or, with ``content``, one
        content-space image through every slot's pose; return once every live node swapped it in
        and ``settle_s`` passed. Raises :class:`coordinator.errors.CoordinatorError` when a node
        never shows it."""

    def show_still(self, image: np.ndarray, *, name: str, persist: bool) -> None:
        """Show a content-space still on every projector (through poses, LUTs and gains); with
        ``persist`` it becomes the rig's content, shown again after restarts."""

    async def play(self, frames: Sequence[np.ndarray], *, fps: float, loops: int = 0) -> PlayResult:
        """Play content-space frames in step on every node; return once played."""

    def update_slot(self, slot: str, **changes) -> None:
        """Persist any of ``pose``, ``lut``, ``gain``, ``size`` of a slot and push it to its node."""

    def open_camera(self, spec: str) -> "Camera":
        """Open the camera ``spec`` names for the running job (closed by the job's end)."""
