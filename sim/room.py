"""The Room: what the camera sees when the projectors show their frames.

For every camera the room precomputes, once, what each camera pixel looks at
(the table, the mesh), and for every projector where that surface point falls
in the projector's image (sub-pixel), how much light reaches it (distance,
incidence, lens fall-off, mesh self-occlusion) and how blurred it is
(defocus + the camera pixel's footprint): :mod:`sim.precompute`. A capture is
then, per powered projector: response(frame) x white point x lamp ->
footprint/blur-filtered light field (cached while the frame and the lamp are
unchanged) -> ``cv2.remap`` at the camera pixels -> x irradiance (with the
projector's hot spot and vignetting) x visibility; summed; then exposure, sensor
noise and quantisation (:class:`sim.optics.Sensor`). Uneven light is
:mod:`sim.photometry`'s; :meth:`Room.set_lamp` dims or kills a lamp while its
projector keeps showing its frames.

Occluders (hands, boxes) only change visibility (:mod:`sim.occlusion`). Per
projector, the camera pixels whose line of sight to it crosses an occluder are
found with exact ray tests, culled through a tile index of the projector image;
camera pixels that see the occluder itself are rendered with the occluder's
surface and albedo (lit, and shadowed, by the same projectors).

Blur: a projector whose blur varies by less than :data:`sim.precompute.SIGMA_TOLERANCE`
projector pixels over the surface the camera sees uses one blur (the RMS);
otherwise each pixel blends two levels of :data:`sim.optics.SIGMA_LEVELS`.

Everything before the sensor is linear in the emitted luminance of the
frames, and :meth:`sim.truth.Truth.transport` returns exactly the matrix the
capture applies; it reads the room through :meth:`Room.view`,
:meth:`Room.dynamic_state`, :meth:`Room.occluder_samples` and :attr:`Room.lock`.

Example::

    room = Room(reference_scene())
    for slot in room.slots:
        w, h = room.projector_size(slot)
        room.set_frame(slot, np.full((h, w, 3), 255, np.uint8))
    room.set_occluders([Hand(position=(0, 0), height=200)])
    image = room.capture()          # (H, W, 3) float32
"""
from __future__ import annotations

import threading
import time
from typing import Callable, Iterable

import cv2
import numpy as np

from sim.errors import FrameError, UnknownSlotError
from sim.hand import HandPath
from sim.occluders import flatten
from sim.occlusion import DynamicState, OccluderSamples, occlude, occluder_samples
from sim.optics import gaussian_kernel
from sim.photometry import check_lamp
from sim.precompute import (
    CAMERA_SIGMA_LIMIT,
    MESH,
    NOTHING,
    SHADOW_MAP_SCALE,
    SIGMA_TOLERANCE,
    TABLE,
    MeshMaps,
    Plan,
    View,
    precompute_view,
)
from sim.scene import ProjectorSpec, Scene
from sim.truth import Truth

__all__ = [
    "Room",
    "NOTHING",
    "TABLE",
    "MESH",
    "SIGMA_TOLERANCE",
    "CAMERA_SIGMA_LIMIT",
    "SHADOW_MAP_SCALE",
    "CACHE_BUDGET_BYTES",
]

#: Field-cache budget: above this many bytes of cached fields, fields are recomputed per capture.
CACHE_BUDGET_BYTES = 1_500_000_000


class Room:
    """The virtual room around a :class:`~sim.scene.Scene`.

    Parameters
    ----------
    scene : Scene
    seed : int
        Seed of the sensor noise (the sequence of captures is reproducible).
    noise : bool
        Default for :meth:`capture` (shot + read noise); quantisation always applies.
    upsample : int, optional
        Field samples per projector pixel and axis (the square footprint); by
        default chosen per projector and camera so the footprint is resolved:
        about the projector pixel's size in camera pixels, 1 to 4.
    clock : callable
        Monotonic seconds, for hand paths (injectable for tests).
    """

    def __init__(self, scene: Scene, *, seed: int = 0, noise: bool = True, upsample: int | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        self.scene = scene
        self.noise = noise
        self._upsample = upsample
        self._clock = clock
        self._rng = np.random.default_rng(seed)
        self._lock = threading.RLock()
        self._frames: dict[str, np.ndarray | None] = {p.slot: None for p in scene.projectors}
        self._frame_version: dict[str, int] = {p.slot: 0 for p in scene.projectors}
        self._active: list[str] = list(scene.slots)
        self._occluders: list = []
        self._path: HandPath | None = None
        self._path_t0 = 0.0
        self._occ_version = 0
        self._views: dict[int, View] = {}
        self._dynamic: dict[int, DynamicState] = {}
        self._fields: dict[tuple, tuple[int, dict[int, np.ndarray]]] = {}
        self._spec = {p.slot: p for p in scene.projectors}
        self._lamp: dict[str, np.ndarray] = {p.slot: np.ones(3) for p in scene.projectors}
        self.truth = Truth(self)
        self._mesh_maps: MeshMaps | None = MeshMaps.render(scene) if scene.mesh is not None else None

    # ------------------------------------------------------------ public state

    @property
    def slots(self) -> list[str]:
        """The rig's projectors (powered by default), e.g. ``["r0c0", ..., "r4c4"]``."""
        return list(self.scene.slots)

    @property
    def all_slots(self) -> list[str]:
        """Every projector in the room, including extra units such as ``p1``."""
        return list(self.scene.all_slots)

    @property
    def active(self) -> list[str]:
        """The powered projectors (no lock: the list is replaced, never changed in place)."""
        return list(self._active)

    def projector(self, slot: str) -> ProjectorSpec:
        """The specification of projector ``slot`` (raises :class:`UnknownSlotError`)."""
        try:
            return self._spec[slot]
        except (KeyError, TypeError):
            raise UnknownSlotError(self._unknown(slot)) from None

    def _unknown(self, slot) -> str:
        slots = self.all_slots
        if len(slots) > 8:
            listed = f"{slots[0]} ... {slots[-1]}" if slots[-1].startswith("r") else f"{slots[0]} ... {slots[-2]}, {slots[-1]}"
        else:
            listed = ", ".join(slots)
        return f"no projector {slot!r} in this room; its slots are {listed}"

    def projector_size(self, slot: str) -> tuple[int, int]:
        """(width, height) of the frames ``slot`` takes."""
        return self.projector(slot).size

    def camera_size(self, camera: int = 0) -> tuple[int, int]:
        """(width, height) of the captures of ``camera``."""
        return self.scene.camera(camera).size

    def set_frame(self, slot: str, frame: np.ndarray | None) -> None:
        """Show ``frame`` on projector ``slot``.

        Parameters
        ----------
        frame : (h, w, 3) uint8 or (h, w) uint8, or None
            Input values exactly as the node outputs them; ``None`` switches
            the projector's light off (no black level either).

        Raises
        ------
        UnknownSlotError, FrameError
        """
        spec = self.projector(slot)
        if frame is not None:
            arr = np.asarray(frame)
            w, h = spec.size
            if arr.dtype != np.uint8:
                raise FrameError(f"frame for {slot} must be uint8 input values, got {arr.dtype}")
            if arr.ndim == 2:
                arr = arr[:, :, None]
            if arr.ndim != 3 or arr.shape[:2] != (h, w) or arr.shape[2] not in (1, 3, 4):
                raise FrameError(f"frame for {slot} must be {w}x{h} (shape ({h}, {w}, 3)), got shape {tuple(np.shape(frame))}")
            if arr.shape[2] == 1:
                arr = np.repeat(arr, 3, axis=2)
            frame = np.ascontiguousarray(arr[:, :, :3])
        with self._lock:
            self._frames[slot] = frame
            self._frame_version[slot] += 1

    def frame(self, slot: str) -> np.ndarray | None:
        """The frame ``slot`` shows (or None)."""
        self.projector(slot)
        with self._lock:
            return self._frames[slot]

    def set_lamp(self, slot: str, gain) -> np.ndarray:
        """Dim or kill the lamp of projector ``slot`` while it keeps showing its frames.

        Parameters
        ----------
        gain : float or (3,) floats in 0..1
            The lamp's output now relative to new, per channel: 1 as new, 0.5 half, 0 dead.
            It scales everything the projector emits, its black level too.

        Returns
        -------
        (3,) float64: the lamp now.

        Raises
        ------
        UnknownSlotError, ValueError (nothing changes)
        """
        self.projector(slot)
        lamp = check_lamp(gain)
        with self._lock:
            self._lamp[slot] = lamp
        return lamp.copy()

    def lamp(self, slot: str) -> np.ndarray:
        """(3,) float64: the lamp of ``slot`` (1 = as new, 0 = dead)."""
        self.projector(slot)
        with self._lock:
            return self._lamp[slot].copy()

    def emission_gains(self, slot: str) -> np.ndarray | None:
        """(3,) float32 per-channel gains of what ``slot`` emits (white point x lamp); None when all are 1."""
        spec = self.projector(slot)
        with self._lock:
            lamp = self._lamp[slot]
        if spec.white is None and np.all(lamp == 1.0):
            return None
        return (spec.white_gains * lamp).astype(np.float32)

    def set_active(self, slots: Iterable[str]) -> None:
        """Power exactly ``slots`` (e.g. ``SUBSETS["P9D"]``); the others emit nothing."""
        slots = list(slots)
        for s in slots:
            self.projector(s)
        with self._lock:
            wanted = set(slots)
            self._active = [s for s in self.all_slots if s in wanted]

    def set_occluders(self, occluders: Iterable | HandPath | None) -> None:
        """Place occluders: a list of :class:`~sim.hand.Hand`, boxes, ...; ``[]`` or None for none.

        A :class:`~sim.hand.HandPath` moves a hand: each capture places
        it at the time elapsed since this call (see :meth:`capture`'s ``time``).
        """
        if isinstance(occluders, HandPath):
            with self._lock:
                self._path = occluders
                self._path_t0 = self._clock()
                self._occluders = []
                self._occ_version += 1
            return
        occ = list(occluders or [])
        for o in occ:
            if not hasattr(o, "primitives"):
                raise TypeError(f"not an occluder: {o!r}")
        with self._lock:
            self._path = None
            self._occluders = occ
            self._occ_version += 1

    def occluders(self, *, time: float | None = None) -> list:
        """The occluders in place (a path evaluated at ``time`` s after it was set, default now)."""
        with self._lock:
            if self._path is not None:
                t = self._clock() - self._path_t0 if time is None else time
                return [self._path.hand_at(t)]
            return list(self._occluders)

    def prepare(self, camera: int = 0) -> None:
        """Do the per-camera precomputation now (otherwise the first capture does it)."""
        self.view(camera)

    # ------------------------------------------------------------ precomputed state (for sim.truth)

    @property
    def lock(self) -> threading.RLock:
        """The room's re-entrant lock: hold it (``with room.lock:``) so several reads see one state.

        Every method of the room takes it; captures run under it.
        """
        return self._lock

    def view(self, camera: int = 0) -> View:
        """The static precomputation of ``camera`` (:class:`sim.precompute.View`, with a plan per projector).

        Computed on first use, then kept; read-only for callers.
        """
        with self._lock:
            view = self._views.get(camera)
            if view is None:
                view = precompute_view(self.scene, camera, upsample=self._upsample, mesh_maps=self._mesh_maps)
                self._views[camera] = view
            return view

    def dynamic_state(self, view: View, *, time: float | None = None) -> DynamicState:
        """What the current occluders hide in ``view`` (:class:`sim.occlusion.DynamicState`).

        Parameters
        ----------
        view : View
            From :meth:`view`.
        time : float, optional
            For a hand path: seconds since :meth:`set_occluders` (default: the clock).

        The state is cached per camera until the occluders (or the hand's place) change.
        """
        with self._lock:
            occluders = self.occluders(time=time)
            if self._path is not None:
                hand = occluders[0]
                key = (self._occ_version, hand.position, hand.height)
            else:
                key = (self._occ_version,)
            dyn = self._dynamic.get(view.camera)
            if dyn is not None and dyn.key == key:
                return dyn
            dyn = occlude(view, flatten(occluders), key, self.scene.camera(view.camera).pinhole, {slot: spec.pinhole for slot, spec in self._spec.items()})
            self._dynamic[view.camera] = dyn
            return dyn

    def occluder_samples(self, view: View, dyn: DynamicState, slot: str) -> OccluderSamples:
        """How ``slot`` lights the occluder surface the camera of ``view`` sees (:class:`sim.occlusion.OccluderSamples`).

        ``dyn`` comes from :meth:`dynamic_state`; the samples are computed once per occluder state.
        """
        with self._lock:
            return occluder_samples(
                view, dyn, self.projector(slot), self.scene.camera(view.camera).pinhole,
                hand_albedo=self.scene.hand_albedo, mesh_maps=self._mesh_maps,
            )

    # ------------------------------------------------------------ capture

    def capture(self, camera: int = 0, *, noise: bool | None = None, exposure: float | None = None, time: float | None = None) -> np.ndarray:
        """What ``camera`` records now.

        Parameters
        ----------
        noise : bool, optional
            Shot and read noise (default: the room's setting).
        exposure : float, optional
            Relative exposure (default: the camera's; 1.0 = powered projectors
            at full white reach 0.8 on the camera's axis).
        time : float, optional
            For a hand path: seconds since :meth:`set_occluders` (default: the clock).

        Returns
        -------
        (H, W, 3) float32 in [0, 1], quantised to the sensor's bit depth.
        """
        with self._lock:
            signal = self.render_linear(camera, exposure=exposure, time=time)
            cam = self.scene.camera(camera)
            return cam.sensor.expose(signal, rng=self._rng, noise=self.noise if noise is None else noise)

    def render_linear(self, camera: int = 0, *, exposure: float | None = None, time: float | None = None) -> np.ndarray:
        """The linear sensor signal (fraction of full scale) before noise, clipping and quantisation.

        Returns
        -------
        (H, W, 3) float32: ``sum_i transport_i @ luminance_i``, with ``luminance_i`` what projector
        i emits, its response times its :meth:`emission_gains` (see :meth:`sim.truth.Truth.transport`).
        """
        with self._lock:
            self.scene.camera(camera)
            view = self.view(camera)
            dyn = self.dynamic_state(view, time=time)
            acc = np.zeros((*view.shape, 3), np.float32)
            hand_acc = np.zeros((len(dyn.hand_index), 3), np.float32)
            for slot in self._active:
                if self._frames[slot] is None:
                    continue
                plan = view.plans[slot]
                self._accumulate(view, dyn, slot, plan, self._field(slot, plan), acc, hand_acc)
            return self._finish(camera, view, dyn, acc, hand_acc, exposure)

    def render_projector(self, slot: str, luminance: np.ndarray, camera: int = 0, *, exposure: float | None = None, time: float | None = None) -> np.ndarray:
        """The linear sensor signal of ``slot`` alone emitting ``luminance`` (its response's output).

        What :meth:`render_linear` gives with only ``slot`` powered and a frame whose response is
        ``luminance``, whatever the room shows now; the lamp, white point, profile and the current
        occluders apply, as in a capture. ``slot`` need not be powered.

        Parameters
        ----------
        luminance : (h, w, 3) float32
            Relative luminance per projector pixel, before the white point and the lamp.

        Returns
        -------
        (H, W, 3) float32
        """
        spec = self.projector(slot)
        w, h = spec.size
        lum = np.asarray(luminance, np.float32)
        if lum.shape != (h, w, 3):
            raise FrameError(f"luminance for {slot} must be shape ({h}, {w}, 3), got {lum.shape}")
        with self._lock:
            view = self.view(camera)
            dyn = self.dynamic_state(view, time=time)
            acc = np.zeros((*view.shape, 3), np.float32)
            hand_acc = np.zeros((len(dyn.hand_index), 3), np.float32)
            plan = view.plans[slot]
            gains = self.emission_gains(slot)
            if gains is not None:
                lum = lum * gains
            self._accumulate(view, dyn, slot, plan, self._fields_of(lum, plan), acc, hand_acc)
            return self._finish(camera, view, dyn, acc, hand_acc, exposure)

    def _accumulate(self, view: View, dyn: DynamicState, slot: str, plan: Plan, fields: dict[int, np.ndarray], acc: np.ndarray, hand_acc: np.ndarray) -> None:
        """Add ``slot``'s light (its blurred fields) to the ROI accumulator and the occluders' samples."""
        sample = view.scratch
        blocked = dyn.blocked.get(slot)
        for level, coef in plan.coef.items():
            cv2.remap(fields[level], plan.mapx, plan.mapy, cv2.INTER_LINEAR, dst=sample, borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))
            if blocked is not None and len(blocked):
                sample.reshape(-1, 3)[blocked] = 0.0
            if coef.ndim == 3:
                cv2.accumulateProduct(sample, coef, acc)
            else:
                np.multiply(sample, coef[:, :, None], out=sample)
                acc += sample
        if len(dyn.hand_index):
            hs = self.occluder_samples(view, dyn, slot)
            for level, coef in hs.coef.items():
                hand = cv2.remap(fields[level], hs.mapx, hs.mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))
                hand_acc += hand[0] * coef[:, None]

    def _finish(self, camera: int, view: View, dyn: DynamicState, acc: np.ndarray, hand_acc: np.ndarray, exposure: float | None) -> np.ndarray:
        """The full camera image of an accumulated ROI: occluder pixels, then the camera's gain and exposure."""
        cam = self.scene.camera(camera)
        W, H = cam.size
        x0, y0, x1, y1 = view.roi
        if len(dyn.hand_roi):
            acc.reshape(-1, 3)[dyn.hand_roi] = 0.0
        out = np.zeros((H, W, 3), np.float32)
        out[y0:y1, x0:x1] = acc
        if len(dyn.hand_index):
            out.reshape(-1, 3)[dyn.hand_index] = hand_acc
        out *= np.float32(cam.gain * (cam.exposure if exposure is None else exposure))
        return out

    # ------------------------------------------------------------ fields

    def _field(self, slot: str, plan: Plan) -> dict[int, np.ndarray]:
        """Blurred light fields (level -> (Hf, Wf, 3) float32) of ``slot``'s current frame."""
        ckey = (slot, plan.upsample, plan.pad, plan.sigmas)
        gains = self.emission_gains(slot)
        version = self._frame_version[slot] if gains is None else (self._frame_version[slot], gains.tobytes())
        cached = self._fields.get(ckey)
        if cached is not None and cached[0] == version:
            return cached[1]
        spec = self._spec[slot]
        frame = self._frames[slot]
        table = spec.response.table_u8()
        if gains is not None:
            table = table * gains  # white point x lamp, per channel: (256, 3) float32
        fields = self._fields_of(cv2.LUT(frame, table.reshape(1, 256, 3)), plan)
        self._fields.pop(ckey, None)
        total = sum(f.nbytes for _, fs in self._fields.values() for f in fs.values())
        if total + sum(f.nbytes for f in fields.values()) <= CACHE_BUDGET_BYTES:
            self._fields[ckey] = (version, fields)
        return fields

    def _fields_of(self, lum: np.ndarray, plan: Plan) -> dict[int, np.ndarray]:
        """Blurred light fields (level -> (Hf, Wf, 3) float32) of emitted luminance ``lum`` (h, w, 3) float32."""
        h, w = lum.shape[:2]
        s, pad = plan.upsample, plan.pad
        base = np.zeros((h * s + 2 * pad, w * s + 2 * pad, 3), np.float32)
        if s > 1:
            cv2.resize(lum, (w * s, h * s), dst=base[pad:-pad, pad:-pad], interpolation=cv2.INTER_NEAREST_EXACT)
        else:
            base[pad:-pad, pad:-pad] = lum
        fields = {}
        for level, sigma in enumerate(plan.sigmas):
            if sigma <= 0:
                fields[level] = base
            else:
                k = gaussian_kernel(sigma * s).astype(np.float32)
                fields[level] = cv2.sepFilter2D(base, cv2.CV_32F, k, k, borderType=cv2.BORDER_CONSTANT)
        return fields
