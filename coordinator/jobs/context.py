"""The one thing a job sees: :class:`JobContext`.

A job is ``async def run(ctx: JobContext, opts: SomeOptions) -> dict``. Through its context it

* picks projectors (:meth:`JobContext.select_slots`), shows patterns in projector pixels
  (:meth:`~JobContext.show`) or content through the poses (:meth:`~JobContext.show_content`),
  shows or plays the rig's content (:meth:`~JobContext.show_still`, :meth:`~JobContext.play`);
* captures (:meth:`~JobContext.capture`), which owns the capture discipline: a capture sees
  only the pattern shown last, ``frames`` captures are averaged (the pattern is shown again
  before each, so a camera that waits for a newer swap gets one), a per-capture exposure is
  refused clearly by a camera that cannot change it, and camera failures become
  :class:`JobError`;
* persists results for a slot (:meth:`~JobContext.set_pose`, :meth:`~JobContext.set_slot`),
  reports progress and log lines (callable from worker threads too) and runs heavy numerical
  work off the event loop (:meth:`~JobContext.compute`).

Behind it is a :class:`coordinator.jobs.driver.RigDriver`: the coordinator for a real rig,
the in-process room harness for tests and benchmarks.
"""
from __future__ import annotations

import asyncio
import logging
import math
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Awaitable, Callable, Mapping, Sequence

import numpy as np

from coordinator.api import PlayResult
from coordinator.camera import Camera, CameraError, CaptureRecorder
from coordinator.jobs.driver import RigDriver
from coordinator.jobs.errors import JobError
from coordinator.rig import HomographyPose, Rig

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Progress:
    """One progress event of a job: ``done`` of ``total`` in ``stage`` (for ``item``, e.g. a slot)."""

    stage: str
    item: str = ""
    done: int = 0
    total: int = 0
    message: str = ""
    value: float = math.nan


#: What a job emits: a Progress event or a log line.
Event = Progress | str


class JobContext:
    """What a job may use (see the module docstring).

    Parameters
    ----------
    driver : RigDriver
        The rig the job runs on.
    emit : callable, optional
        Receives :class:`Progress` events and log lines (``str``), always on the job's loop.
    cameras : list of str, optional
        Camera specs for this job (default: the driver's).
    """

    def __init__(self, driver: RigDriver, *, emit: Callable[[Event], None] | None = None,
                 cameras: Sequence[str] | None = None):
        self.driver = driver
        self._emit = emit or (lambda ev: None)
        self.camera_specs: list[str] = list(cameras if cameras else driver.camera_specs)
        self._cameras: dict[int, Camera] = {}
        self._recorders: dict[int, CaptureRecorder] = {}
        self._record_dir: Path | None = None
        self._reshow: Callable[[], Awaitable[None]] | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread: int | None = None
        try:
            self._loop = asyncio.get_running_loop()
            self._loop_thread = threading.get_ident()
        except RuntimeError:
            pass
        #: captures taken so far (each of ``frames`` averaged captures counts)
        self.captures = 0
        #: patterns shown so far (projector-space and content-space)
        self.shows = 0

    # ------------------------------------------------------------------ the rig
    @property
    def rig(self) -> Rig:
        return self.driver.rig

    def live_slots(self) -> list[str]:
        """Slots whose node is connected and showing frames, in rig order."""
        return self.driver.live_slots()

    def projector_size(self, slot: str) -> tuple[int, int]:
        """(width, height) of the slot's projector."""
        st = self.rig.slot(slot)
        return st.width, st.height

    def require_live(self, slots: Sequence[str]) -> None:
        """Refuse, naming them, slots that are not in the rig or whose node is not connected."""
        unknown = [s for s in slots if s not in self.rig.slots]
        if unknown:
            raise JobError(f"slot(s) {', '.join(unknown)} not in rig {self.rig.config.name!r} "
                           f"(slots: {', '.join(self.rig.slots)})")
        live = set(self.live_slots())
        missing = [s for s in slots if s not in live]
        if missing:
            raise JobError(f"projector(s) {', '.join(missing)} not connected: start their nodes (see `shadowless status`)")

    def select_slots(self, requested: Sequence[str] | None = None, *, need_pose: bool = False,
                     planar: bool = False) -> list[str]:
        """The projectors a job works on.

        ``requested`` (slot names) must all be connected; by default every connected slot (with
        ``need_pose``, every connected slot that has a pose). ``need_pose``: each must be
        calibrated; ``planar``: each pose must be a homography (a table, not a 3D object).
        """
        if requested is not None:
            slots = list(requested)
            if not slots:
                raise JobError("slots must name at least one projector")
            self.require_live(slots)
        else:
            slots = self.live_slots()
            if not slots:
                raise JobError("no projector is connected: start the nodes (see `shadowless status`)")
            if need_pose:
                slots = [s for s in slots if self.rig.slot(s).pose is not None]
                if not slots:
                    raise JobError("no connected projector has a pose: calibrate first (`shadowless calibrate`)")
        if need_pose or planar:
            for s in slots:
                pose = self.rig.slot(s).pose
                if pose is None:
                    plan = " (only the pose a layout planned, which is not a calibration)" if self.rig.slot(s).planned else ""
                    raise JobError(f"projector {s} has no pose{plan}: calibrate it first (`shadowless calibrate`)")
                if planar and not isinstance(pose, HomographyPose):
                    raise JobError(f"projector {s} has a 3D pose: this job supports planar rigs (a table) only")
        return slots

    # ------------------------------------------------------------------ showing
    async def show(self, images: Mapping[str, np.ndarray | None], *, settle_s: float = 0.05,
                   require: Sequence[str] | None = None) -> None:
        """Show projector-space images and wait until every live node swapped them in, plus ``settle_s``.

        ``images[slot]``: (h, w) or (h, w, C) uint8/uint16/float32 in that slot's projector pixels,
        or None for black; live slots not named show black. ``require``: slots that must be
        connected (default: every slot given an image).
        """
        need = [s for s, img in images.items() if img is not None] if require is None else list(require)
        self.require_live(need)
        for s, img in images.items():
            if img is not None:
                w, h = self.projector_size(s)
                if np.shape(img)[:2] != (h, w):
                    raise JobError(f"pattern for {s} is {np.shape(img)[1]}x{np.shape(img)[0]}, its projector is {w}x{h}")
        images = dict(images)

        async def again() -> None:
            await self._show(self.driver.show_patterns(images, settle_s=settle_s))

        self._reshow = again
        await again()

    async def show_content(self, image: np.ndarray | None, *, apply_lut: bool = True, settle_s: float = 0.05) -> None:
        """Show one content-space image (None: black) on every live projector through its pose
        (and its LUT and gain when ``apply_lut``), and wait for the swaps plus ``settle_s``."""

        async def again() -> None:
            await self._show(self.driver.show_patterns({}, content=image, apply_lut=apply_lut, settle_s=settle_s))

        self._reshow = again
        await again()

    async def _show(self, call: Awaitable[None]) -> None:
        try:
            await call
        except JobError:
            raise
        except (CameraError, ValueError) as exc:
            raise JobError(str(exc)) from exc
        self.shows += 1

    def show_still(self, image: np.ndarray, *, name: str, persist: bool = True) -> None:
        """Show a content-space still on every projector (through poses, LUTs and gains); with
        ``persist`` (default) it becomes the rig's content, shown again after the job and restarts."""
        self._reshow = None
        self.driver.show_still(np.ascontiguousarray(image), name=name, persist=persist)

    async def play(self, frames: Sequence[np.ndarray], *, fps: float, loops: int = 0) -> PlayResult:
        """Play content-space frames in step on every node; the figures once played."""
        if not frames:
            raise JobError("nothing to play")
        if not 0.1 <= fps <= 1000:
            raise JobError(f"fps must be in 0.1..1000, got {fps:g}")
        self._reshow = None
        return await self.driver.play(list(frames), fps=fps, loops=loops)

    # ------------------------------------------------------------------ cameras
    @property
    def camera_count(self) -> int:
        return len(self.camera_specs)

    def camera_spec(self, index: int = 0) -> str:
        """The spec of camera ``index``; a clear error when the job has fewer cameras."""
        if not 0 <= index < len(self.camera_specs):
            raise JobError(f"no camera {index}: this job has {len(self.camera_specs)} (set `cameras = "
                           "[\"room://HOST:PORT\"]` in rig.toml, or pass --camera)")
        return self.camera_specs[index]

    def camera(self, index: int = 0) -> Camera:
        """Camera ``index``, opened on first use (closed when the job ends)."""
        if index not in self._cameras:
            spec = self.camera_spec(index)
            try:
                self._cameras[index] = self.driver.open_camera(spec)
            except CameraError as exc:
                raise JobError(str(exc)) from exc
        return self._cameras[index]

    def supports_exposure(self, index: int = 0) -> bool:
        """Whether camera ``index`` can change its exposure per capture."""
        return bool(self.camera(index).supports_exposure)

    def record_captures(self, directory: str | Path) -> None:
        """Save every later capture of camera ``i`` into ``directory/camera{i}`` (16-bit PNG), so the
        run can be replayed with ``folder:`` cameras; captures are returned as the replay reads them."""
        self._record_dir = Path(directory)

    def _recorder(self, index: int) -> CaptureRecorder | None:
        if self._record_dir is None:
            return None
        if index not in self._recorders:
            try:
                self._recorders[index] = CaptureRecorder(self._record_dir / f"camera{index}")
            except CameraError as exc:
                raise JobError(str(exc)) from exc
        return self._recorders[index]

    async def _grab(self, index: int, exposure: float | None) -> np.ndarray:
        cam = self.camera(index)
        if exposure is not None and not cam.supports_exposure:
            raise JobError(f"camera {index} ({self.camera_spec(index)}) cannot change its exposure per capture; "
                           "use a camera that can (the virtual room's), or average more frames instead")
        try:
            img = await asyncio.to_thread(cam.capture, exposure=exposure)
            img = np.asarray(img, np.float32)
            if img.ndim != 3 or img.shape[2] != 3:
                raise JobError(f"camera {index} delivered an image of shape {img.shape}; expected (H, W, 3)")
            recorder = self._recorder(index)
            if recorder is not None:
                img = await asyncio.to_thread(recorder.record, img)
        except CameraError as exc:
            raise JobError(str(exc)) from exc
        self.captures += 1
        return img

    async def capture(self, camera: int = 0, *, frames: int = 1, exposure: float | None = None) -> np.ndarray:
        """A capture of what was shown last: ``(H, W, 3) float32``, the mean of ``frames`` captures.

        Between averaged captures the last pattern is shown again (a camera that waits for a swap
        newer than its previous capture gets one). ``exposure``: relative to the camera's own.
        """
        if frames < 1:
            raise JobError(f"frames must be at least 1, got {frames}")
        acc: np.ndarray | None = None
        for k in range(frames):
            if k and self._reshow is not None:
                await self._reshow()
            img = await self._grab(camera, exposure)
            acc = img if acc is None else acc + img
        assert acc is not None
        return acc / np.float32(frames) if frames > 1 else acc

    async def capture_all(self, cameras: Sequence[int], *, exposure: float | None = None) -> list[np.ndarray]:
        """One capture from each of ``cameras`` of what was shown last."""
        return [await self._grab(i, exposure) for i in cameras]

    # ------------------------------------------------------------------ results
    def set_pose(self, slot: str, pose, *, source: str = "calibration") -> None:
        """Persist a slot's pose (a homography, a projection or None) and push it to its node."""
        self.driver.update_slot(slot, pose=pose, source=source)

    def set_slot(self, slot: str, **changes: Any) -> None:
        """Persist any of ``pose``/``lut``/``gain`` of a slot and push the new assignment to its node."""
        self.driver.update_slot(slot, **changes)

    # ------------------------------------------------------------------ reporting
    def _deliver(self, event: Event) -> None:
        if self._loop is None or threading.get_ident() == self._loop_thread:
            self._emit(event)
        else:
            self._loop.call_soon_threadsafe(self._emit, event)

    def progress(self, stage: str, item: str = "", done: int = 0, total: int = 0, message: str = "",
                 value: float = math.nan) -> None:
        """Report progress (from the loop or a worker thread)."""
        self._deliver(Progress(stage, item, int(done), int(total), message, float(value)))

    def log(self, message: str) -> None:
        """A line for the operator (from the loop or a worker thread)."""
        log.info("job: %s", message)
        self._deliver(str(message))

    async def compute(self, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        """Run CPU-heavy ``fn`` on a worker thread (numpy, OpenCV and SciPy release the GIL)."""
        return await asyncio.to_thread(fn, *args, **kwargs)

    def close(self) -> None:
        """Close the cameras this job opened."""
        for cam in self._cameras.values():
            try:
                cam.close()
            except Exception:  # pragma: no cover - best effort
                log.exception("closing camera failed")
        self._cameras.clear()
