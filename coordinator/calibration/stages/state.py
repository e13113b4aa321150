"""What the stages of one ``calibrate`` job share: :class:`State`."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from imaging.calibration import threed
from coordinator.calibration.options import CalibrateOptions, Inputs
from coordinator.calibration.runs import Run, rounded
from coordinator.jobs import JobContext, JobError
from coordinator.rig import Mesh

SATURATED = 0.995           # a channel at or above this is saturated


class Abort(JobError):
    """A problem no other projector can avoid (a camera's exposure): the run stops."""


@dataclass
class CameraSetup:
    """Per camera: table -> camera homography (planar) and/or a posed pinhole (3D); plus the mesh (3D)."""

    table_to_camera: dict[int, np.ndarray] = field(default_factory=dict)
    table_rms: dict[int, float] = field(default_factory=dict)
    devices: dict[int, threed.Pinhole] = field(default_factory=dict)
    device_rms: dict[int, float] = field(default_factory=dict)
    sizes: dict[int, tuple[int, int]] = field(default_factory=dict)
    mesh: threed.MeshData | None = None
    rig_mesh: Mesh | None = None
    mesh_rms: float | None = None

    def summary(self) -> list[dict]:
        return [{"camera": i, "size": list(self.sizes[i]),
                 "table_rms_px": rounded(self.table_rms.get(i, math.nan)),
                 "pose_rms_px": rounded(self.device_rms.get(i, math.nan))}
                for i in sorted(self.sizes)]


@dataclass(eq=False)
class State:
    """One calibrate job: its context, settings and run, and what the stages found so far."""

    ctx: JobContext
    opts: CalibrateOptions
    inputs: Inputs
    run: Run
    slots: list[str]                        # the projectors of this job
    todo: list[str]                         # those this run has still to calibrate
    sizes: dict[str, tuple[int, int]]       # projector (w, h) per slot
    cameras: list[int]
    content_size: tuple[int, int]
    saved_table: dict[int, dict] = field(default_factory=dict)   # camera -> mapping an earlier run saved
    dark: list[np.ndarray] = field(default_factory=list)         # per camera: every projector black
    white: list[np.ndarray] = field(default_factory=list)        # per camera: every projector white
    setup: CameraSetup = field(default_factory=CameraSetup)
    results: dict[str, dict] = field(default_factory=dict)       # slot -> figures (runs.slot_doc)
    failed: dict[str, str] = field(default_factory=dict)         # slot -> why
    shots: int = 0                                               # patterns shown and captured

    async def shoot(self, images: dict[str, np.ndarray | None], *, require: list[str]) -> list[np.ndarray]:
        """Show ``images`` (projector space, the others black), wait for every swap and the settle
        time, and capture every camera: one (H, W, 3) float32 per camera."""
        await self.ctx.show(images, settle_s=self.opts.settle_s, require=require)
        caps = await self.ctx.capture_all(self.cameras)
        self.shots += 1
        return caps


def full(size: tuple[int, int], value: int) -> np.ndarray:
    """A (h, w) uint8 pattern of one level for a projector of ``size`` (w, h)."""
    return np.full((size[1], size[0]), value, np.uint8)
