"""Long jobs that run inside the coordinator (calibration, luminance response,
light transport, compensation) and report progress to the operator's CLI.

A job is an ``async def job(ctx: JobContext, params: dict) -> dict``. It drives
the projectors through :meth:`JobContext.show` (which returns only once every
connected node has swapped the pattern in and the settle time has passed),
captures through cameras from :meth:`JobContext.camera`, persists what it
completes as it goes (so an interrupted run resumes), and returns a JSON-able
result. Heavy numerical work belongs in :meth:`JobContext.compute`, which runs
it on a worker thread so the coordinator keeps streaming and answering pings.
"""
from __future__ import annotations

import asyncio
import importlib
import logging
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Awaitable, Callable

import numpy as np

from coordinator.errors import CoordinatorError

if TYPE_CHECKING:  # pragma: no cover
    from coordinator.rig import Rig
    from coordinator.server import Coordinator

log = logging.getLogger(__name__)

#: job kind -> "module:function"; modules are imported when the job is first run
JOBS: dict[str, str] = {
    "calibrate": "coordinator.calibration.job:calibrate",
    "alignment": "coordinator.calibration.job:alignment_check",
    "response": "coordinator.compensation.job:measure_response",
    "transport": "coordinator.compensation.job:measure_transport",
    "compensate": "coordinator.compensation.job:compensate",
    "compensate_sequence": "coordinator.compensation.job:compensate_sequence",
}


class JobError(CoordinatorError):
    """A job cannot go on; the message names the slot, camera or file at fault."""


@dataclass
class Progress:
    stage: str
    item: str = ""
    done: int = 0
    total: int = 0
    message: str = ""
    value: float = math.nan


@dataclass
class JobContext:
    """What a job may use. Create through :meth:`Coordinator.job_context`."""

    coordinator: "Coordinator"
    emit: Callable[[object], None]          # Progress, str (log line)
    camera_specs: list[str] = field(default_factory=list)
    _cameras: dict[int, Any] = field(default_factory=dict)

    @property
    def rig(self) -> "Rig":
        return self.coordinator.rig

    def progress(self, stage: str, item: str = "", done: int = 0, total: int = 0, message: str = "",
                 value: float = math.nan) -> None:
        self.emit(Progress(stage, item, done, total, message, value))

    def log(self, message: str) -> None:
        log.info("job: %s", message)
        self.emit(message)

    def live_slots(self) -> list[str]:
        """Slots whose node is connected and streaming, in rig order."""
        live = {s.slot for s in self.coordinator.live_sessions()}
        return [s for s in self.rig.slots if s in live]

    def projector_size(self, slot: str) -> tuple[int, int]:
        st = self.rig.slot(slot)
        return st.width, st.height

    async def show(self, images: dict[str, np.ndarray | None], *, settle_s: float = 0.05,
                   require: list[str] | None = None) -> None:
        """Show projector-space images: ``images[slot]`` is (h, w) or (h, w, C) uint8/uint16/float32 in the
        slot's projector pixels, or None for black. Connected slots not named show black. Returns once every
        connected node swapped it in and ``settle_s`` passed. ``require``: slots that must be connected
        (default: every slot named with an image)."""
        need = [s for s, img in images.items() if img is not None] if require is None else require
        missing = [s for s in need if s not in self.live_slots()]
        if missing:
            raise JobError(f"projector(s) {', '.join(missing)} not connected: start their nodes (see `shadowless status`)")
        await self.coordinator.show_patterns(images, settle_s=settle_s)

    async def show_content(self, image: np.ndarray | None, *, apply_lut: bool = True, settle_s: float = 0.05) -> None:
        """Show one content-space image on every projector through its pose (None = black)."""
        await self.coordinator.show_patterns({}, content=image, apply_lut=apply_lut, settle_s=settle_s)

    def camera(self, index: int = 0):
        """Camera ``index`` (0 = the first ``--camera``/rig.toml camera), opened on first use."""
        if index not in self._cameras:
            if index >= len(self.camera_specs):
                raise JobError(f"no camera {index}: the coordinator knows {len(self.camera_specs)} "
                               "(set `cameras = [\"room://HOST:PORT\"]` in rig.toml or pass --camera to the job)")
            from coordinator.camera import open_camera

            self._cameras[index] = open_camera(self.camera_specs[index])
        return self._cameras[index]

    async def capture(self, index: int = 0) -> np.ndarray:
        """One capture from camera ``index``: (H, W, 3) float32 in [0, 1].

        A camera that can tell which frames it sees (the room) is told the last pattern's
        presentation time, so it never captures an older pattern."""
        cam = self.camera(index)
        if hasattr(cam, "not_before") and self.coordinator.last_pattern_pts_ns:
            cam.not_before(self.coordinator.last_pattern_pts_ns)
        return await asyncio.to_thread(cam.capture)

    def set_pose(self, slot: str, pose, *, source: str = "calibration") -> None:
        """Persist a slot's pose (HomographyPose, ProjectionPose or None) and push it to its node."""
        self.coordinator.update_slot(slot, pose=pose, source=source)

    def set_slot(self, slot: str, **changes) -> None:
        """Persist any of pose/lut/gain for a slot and push the new assignment to its node."""
        self.coordinator.update_slot(slot, **changes)

    async def compute(self, fn: Callable[..., Any], *args, **kwargs) -> Any:
        """Run CPU-heavy ``fn`` on a worker thread (numpy/OpenCV/SciPy release the GIL)."""
        return await asyncio.to_thread(fn, *args, **kwargs)

    def close(self) -> None:
        for cam in self._cameras.values():
            try:
                cam.close()
            except Exception:  # pragma: no cover - best effort
                log.exception("closing camera failed")
        self._cameras.clear()


def resolve(kind: str) -> Callable[[JobContext, dict], Awaitable[dict]]:
    if kind not in JOBS:
        raise JobError(f"unknown job {kind!r} (known: {', '.join(JOBS)})")
    module, _, fn = JOBS[kind].partition(":")
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        raise JobError(f"job {kind!r} is not available in this build ({exc.name} missing)") from exc
    return getattr(mod, fn)
