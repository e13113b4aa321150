"""The photometric watchdog: during a show, the coordinator now and then captures the camera and
fits each projector's effective gain; a dimmed or dead lamp is named and the rig re-blended.

It checks soon after a new still is on screen and then every ``interval_s`` (rig.toml's
``[blend] watchdog_interval_s``), when everything it needs holds: a camera (rig.toml's first),
no job (a job holds the camera and the projectors), a stored blend with its contributions, content
it knows shown through the poses of a planar rig, and no switch of maps under way. Known content is
a still (an operator's, or a timeline show of a still asset), or a span of a timeline show of an
image sequence whose frames are one and the same file (:func:`steady_span`: the manifest names
each frame's SHA-256, so identical frames are known without decoding; the capture must fall in the
span, which is checked after it). A video is not watched: which of its frames a camera exposed is
not known to within a frame (a real camera's frames reach the coordinator a few frames late by an
amount it does not report, and an exposure may span a swap), so only spans whose frames do not
change could be used, and finding them means decoding and comparing every frame of the video on
the coordinator; a played sequence is not either (its frames are streamed, not an asset). A mesh
rig's contributions have no homography to predict from. The fit is :func:`imaging.blending.watchdog.fit_changes` on the
contributions' camera grid, away from footprint edges: which one or two lamps changed from what
the last check found (all others held), each live projector's predicted light built from its
measured white and black, its maps on screen and the content it shows. The capture (the mean of
:data:`FRAMES` frames) and the fit run in a worker thread.

A lamp whose gain is off 1 by more than :data:`NAME_TOLERANCE` is named; a named lamp's gain is
updated when the fit finds it moved by more than :data:`CHANGE_TOLERANCE`, and forgotten when it
is back within the tolerance of 1. Each change is one log line and re-blends the rig
(:meth:`coordinator.blending.state.BlendState.set_lamps`): a dimmed lamp by its gain, a dead one
(gain below :data:`coordinator.blending.failover.DEAD_GAIN`) as a lost projector.
"""
from __future__ import annotations

import asyncio
import logging
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from coordinator.blending.failover import DEAD_GAIN
from coordinator.blending.state import BlendState
from coordinator.camera import Camera, CameraError, open_camera
from coordinator.rig import HomographyPose
from protos.timeline import Timeline

__all__ = ["CHANGE_TOLERANCE", "NAME_TOLERANCE", "LampWatchdog", "WatchdogCheck", "steady_span"]

log = logging.getLogger(__name__)

#: a lamp is named when its gain is off 1 by more than this
NAME_TOLERANCE = 0.1
#: a named lamp's gain is updated (and the rig re-blended) when it moved by more than this
CHANGE_TOLERANCE = 0.05
#: captures averaged per check
FRAMES = 2
#: after a still's presentation time or a switch of maps, the camera waits this long (ns)
SETTLE_NS = 100_000_000
#: the loop's tick (s): how soon a new still is checked
TICK_S = 0.2


@dataclass(frozen=True)
class WatchdogCheck:
    """One check: the fit's figures, or why it was skipped.

    ``gains``/``stderr``: slot -> effective gain and its standard error; ``condition``: the
    design's condition number (:class:`imaging.blending.watchdog.GainFit`); ``named``: the lamps
    named after it (slot -> gain); ``at_ns``: the rig instant of the capture; ``seconds``: the
    check's time, capture included."""

    at_ns: int
    skipped: str = ""
    gains: dict[str, float] = field(default_factory=dict)
    stderr: dict[str, float] = field(default_factory=dict)
    condition: float = float("nan")
    inliers: float = float("nan")
    residual: float = float("nan")
    named: dict[str, float] = field(default_factory=dict)
    seconds: float = 0.0


def steady_span(timeline: Timeline, shas: Sequence[str], now_ns: int) -> tuple[int, int, int | None] | None:
    """Where a timeline show of an image sequence (``shas``: each frame's SHA-256, in order) shows
    one unchanging picture around rig time ``now_ns``: ``(frame, since_ns, until_ns)``, the frame on
    screen and the rig span over which the frames shown are that same file (``until_ns`` None: as long
    as the show runs); a show that starts later is taken at its anchor; None after its end."""
    tick = timeline.tick_at(max(now_ns, timeline.anchor_ns))
    k = None if tick is None else timeline.frame_of_tick(tick)
    if k is None:
        return None
    if timeline.paused:
        return k, timeline.anchor_ns, None
    if len(set(shas)) == 1:         # every frame the same picture: steady while the show runs
        return k, timeline.anchor_ns, timeline.end_ns()
    sha = shas[k]

    def same(t: int) -> bool:
        f = timeline.frame_of_tick(t)
        return f is not None and shas[f] == sha

    t0 = tick
    while t0 > 0 and same(t0 - 1):
        t0 -= 1
    t1 = tick + 1
    while same(t1):
        t1 += 1
    return k, timeline.pts(t0), timeline.pts(t1)


def _grid_to_camera_matrix(camera_size: tuple[int, int], shape: tuple[int, int]) -> np.ndarray:
    """(3, 3): camera-grid pixel -> camera pixel (the grid convention of
    :func:`imaging.blending.contributions.grid_to_camera`)."""
    W, H = camera_size
    h, w = shape
    sx, sy = W / w, H / h
    return np.array([[sx, 0.0, 0.5 * sx - 0.5], [0.0, sy, 0.5 * sy - 0.5], [0.0, 0.0, 1.0]])


class LampWatchdog:
    """Checks the lamps now and then (see the module docstring).

    Parameters
    ----------
    state : BlendState
    camera_specs : callable
        The rig's camera specs (the first is used).
    busy : callable
        The running job's kind, or None.
    on_screen : callable
        ``(content image, the rig instant it is on screen from)`` of the still shown through the
        poses, or ``(image, from, until)`` for a picture shown until rig instant ``until`` (a
        steady span of a sequence), or None; the image may be a function that reads it (called in
        the worker thread).
    live_slots : callable
    last_swap_ns : callable
        ``slot -> rig ns`` of the last frame its node swapped in (0: none); a node that has not
        swapped the still in yet is waited for.
    interval_s : float
    clock_ns : callable
        The rig clock.
    open_camera : callable
        ``spec -> Camera`` (tests may hand another).
    """

    def __init__(self, state: BlendState, *, camera_specs: Callable[[], list[str]], busy: Callable[[], str | None],
                 on_screen: Callable[[], tuple[np.ndarray, int] | None], live_slots: Callable[[], list[str]],
                 interval_s: float, clock_ns: Callable[[], int], last_swap_ns: Callable[[str], int] | None = None,
                 open_camera: Callable[[str], Camera] = open_camera):
        self.state = state
        self.camera_specs = camera_specs
        self.busy = busy
        self.on_screen = on_screen
        self.live_slots = live_slots
        self.last_swap_ns = last_swap_ns
        self.interval_s = float(interval_s)
        self.clock_ns = clock_ns
        self.open_camera = open_camera
        self.last: WatchdogCheck | None = None
        self.checks = 0
        self._checked_pts = 0
        self._warned: set[str] = set()

    async def run(self) -> None:
        """Check whenever a new still settled, and every ``interval_s``; forever."""
        next_at = 0.0
        while True:
            await asyncio.sleep(TICK_S)
            screen = self.on_screen()
            fresh = screen is not None and screen[1] != self._checked_pts
            if not fresh and time.monotonic() < next_at:
                continue
            result = await self.check()
            if not result.skipped or result.skipped.startswith(("camera:", "no fit:")):
                # checked, or the camera or the fit failed: the next try waits an interval (no retry storm)
                next_at = time.monotonic() + self.interval_s
                self._checked_pts = screen[1] if screen is not None else 0

    def _skip(self, why: str) -> WatchdogCheck:
        if why not in self._warned and why.startswith("!"):
            self._warned.add(why)
            log.info("watchdog: %s", why[1:])
        return WatchdogCheck(at_ns=self.clock_ns(), skipped=why.lstrip("!"))

    def why_not(self) -> str:
        """Why a check cannot run now ("" when it can)."""
        st = self.state
        if not self.camera_specs():
            return "!off: the rig has no camera"
        if self.busy() is not None:
            return f"a {self.busy()} job holds the camera"
        if st.variants is None or st.contributions is None:
            return "no blend with contributions"
        if self.clock_ns() < st.switched_at_ns + SETTLE_NS:
            return "maps are switching"
        screen = self.on_screen()
        if screen is None:
            return "no still shown through the poses"
        if self.clock_ns() < screen[1] + SETTLE_NS:
            return "the still is not on screen yet"
        until = screen[2] if len(screen) > 2 else None
        if until is not None and self.clock_ns() + SETTLE_NS + int(TICK_S * 1e9) > until:
            return "the sequence changes its picture before a capture would end"
        slots = self.slots()
        if not slots:
            return "no live projector of the blend"
        live = set(self.live_slots())
        unknown = [s for s in st.slots if s not in live and s not in st.lost_nodes]
        if unknown:     # a projector with no node in the rig (yet): what it shows is not known
            return f"waiting for the node of {', '.join(sorted(unknown))}"
        if self.last_swap_ns is not None:
            behind = [s for s in slots if self.last_swap_ns(s) < screen[1]]
            if behind:
                return f"waiting for {', '.join(sorted(behind))} to show the still"
        if any(not isinstance(self.state.rig.slot(s).pose, HomographyPose) for s in slots):
            return "!off: the watchdog predicts light through planar poses only (this rig has a mesh)"
        return ""

    def slots(self) -> list[str]:
        """The projectors the fit is over: live, blended, measured, their node not lost."""
        st = self.state
        live = set(self.live_slots())
        c = st.contributions
        return [s for s in st.slots if s in live and c is not None and s in c.white and s not in st.lost_nodes]

    async def check(self) -> WatchdogCheck:
        """One check now (skipped with a reason when it cannot run); names lamps and re-blends."""
        why = self.why_not()
        if why:
            self.last = self._skip(why)
            return self.last
        t0 = time.perf_counter()
        st = self.state
        screen = self.on_screen()
        assert screen is not None
        content, pts = screen[:2]
        until = screen[2] if len(screen) > 2 else None
        not_before = max(pts, st.switched_at_ns)
        slots = self.slots()
        maps = {s: st.rig.slot(s).blend for s in slots}
        poses = {s: st.rig.slot(s).pose.matrix for s in slots}
        baseline = [st.lamp_gains.get(s, 1.0) for s in slots]
        spec = self.camera_specs()[0]
        contributions = st.contributions
        try:
            result = await asyncio.to_thread(self._measure, spec, not_before, contributions, content, slots, maps, poses,
                                             baseline)
        except CameraError as exc:
            if self.last is None or self.last.skipped != f"camera: {exc}":     # once until something changes
                log.warning("watchdog: %s", exc)
            self.last = WatchdogCheck(at_ns=self.clock_ns(), skipped=f"camera: {exc}")
            return self.last
        except ValueError as exc:
            self.last = WatchdogCheck(at_ns=self.clock_ns(), skipped=f"no fit: {exc}")
            return self.last
        if self.busy() is not None or contributions is not st.contributions:
            self.last = WatchdogCheck(at_ns=self.clock_ns(), skipped="the rig changed during the check")
            return self.last
        at_ns, fit = result
        if until is not None and at_ns >= until:
            self.last = WatchdogCheck(at_ns=self.clock_ns(), skipped="the sequence changed its picture during the capture")
            return self.last
        gains = {s: float(g) for s, g in zip(slots, fit.gains)}
        stderr = {s: float(e) for s, e in zip(slots, fit.stderr)}
        named = self._decide(gains, stderr)
        self.checks += 1
        self.last = WatchdogCheck(at_ns=at_ns, gains=gains, stderr=stderr, condition=fit.condition,
                                  inliers=fit.inliers, residual=fit.residual, named=named,
                                  seconds=time.perf_counter() - t0)
        return self.last

    def _measure(self, spec: str, not_before: int, contributions, content: np.ndarray, slots: list[str],
                 maps: dict, poses: dict, baseline: list[float]):
        """Capture and fit (worker thread): (rig ns of the capture, GainFit)."""
        # the fit's numerics (OpenCV) on the first check, not at every coordinator's start
        from imaging.blending.watchdog import (content_on_grid, fit_changes, grid_mean, maps_on_grid,
                                               predicted_light, steady_cells)
        c = contributions
        shape = c.shape

        def grab() -> list[np.ndarray]:
            cam = self.open_camera(spec)
            try:
                if hasattr(cam, "not_before"):     # a room camera: one capture per opening, of frames
                    cam.not_before(not_before)      # swapped in after the still and the maps
                    return [cam.capture()]
                return [cam.capture() for _ in range(FRAMES)]
            finally:
                cam.close()

        frames: list[np.ndarray] = []
        while len(frames) < FRAMES:
            frames += [grid_mean(np.asarray(f, np.float32), shape) for f in grab()]
        at_ns = self.clock_ns()
        capture = np.mean(frames, axis=0)
        value = _linear(content() if callable(content) else content)
        G2C = _grid_to_camera_matrix(c.camera_size, shape)
        columns = []
        for s in slots:
            G2P = c.camera_to_projector[s] @ G2C
            seen = content_on_grid(value, np.linalg.inv(poses[s]) @ G2P, shape)
            m = maps.get(s)
            alpha, beta = (None, None) if m is None else maps_on_grid(m, G2P, c.projector_size[s], shape)[:2]
            columns.append(predicted_light(c.white[s], c.black[s], seen, alpha, beta))
        valid = np.any(sum(c.white[s] for s in slots) > 0, axis=-1) & steady_cells([c.white[s] for s in slots])
        return at_ns, fit_changes(capture, columns, valid=valid, baseline=baseline)

    def _decide(self, gains: dict[str, float], stderr: dict[str, float]) -> dict[str, float]:
        """The named lamps after a fit; tells the blend state (one log line per change)."""
        current = dict(self.state.lamp_gains)
        named: dict[str, float] = {}
        for s, g in gains.items():
            if abs(g - 1.0) > NAME_TOLERANCE:
                old = current.get(s)
                named[s] = round(g, 2) if old is None or abs(g - old) > CHANGE_TOLERANCE else old
        for s in current:           # a lamp not in the fit (its node lost) stays as it was
            if s not in gains:
                named[s] = current[s]
        if named == current:
            return named
        for s, g in sorted(named.items()):
            if current.get(s) == g:
                continue
            err = stderr.get(s, 0.0)
            if g < DEAD_GAIN:
                log.warning("watchdog: lamp of %s is dead (gain %.2f ± %.2f): re-blending without it", s, g, err)
            else:
                log.warning("watchdog: lamp of %s at %.0f %% (± %.0f %%) of its measured light: re-blending",
                            s, 100 * g, 100 * err)
        for s in sorted(set(current) - set(named)):
            log.info("watchdog: lamp of %s is back at %.0f %%: re-blending", s, 100 * gains.get(s, 1.0))
        self.state.set_lamps(named)
        return named


def _linear(content: np.ndarray) -> np.ndarray:
    """A content image as the nodes' linear values: (H, W, C) float32 in 0..1."""
    a = np.asarray(content)
    if a.dtype == np.uint8:
        return a.astype(np.float32) / 255.0
    if a.dtype == np.uint16:
        return a.astype(np.float32) / 65535.0
    return np.clip(a.astype(np.float32), 0.0, 1.0)

