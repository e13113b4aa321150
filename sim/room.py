"""The Room: what the camera sees when the projectors show their frames.

For every camera the room precomputes, once, what each camera pixel looks at
(the table, the mesh), and for every projector where that surface point falls
in the projector's image (sub-pixel), how much light reaches it (distance,
incidence, lens fall-off, mesh self-occlusion) and how blurred it is
(defocus + the camera pixel's footprint). A capture is then, per powered
projector: response(frame) -> footprint/blur-filtered light field (cached
while the frame is unchanged) -> ``cv2.remap`` at the camera pixels ->
x irradiance x visibility; summed; then exposure, sensor noise and
quantisation (:class:`sim.optics.Sensor`).

Occluders (hands, boxes) only change visibility. Per projector, the camera
pixels whose line of sight to it crosses an occluder are found with exact ray
tests, culled through a tile index of the projector image; camera pixels that
see the occluder itself are rendered with the occluder's surface and albedo
(lit, and shadowed, by the same projectors).

Blur: a projector whose blur varies by less than :data:`SIGMA_TOLERANCE`
projector pixels over the surface the camera sees uses one blur (the RMS);
otherwise each pixel blends two levels of :data:`sim.optics.SIGMA_LEVELS`.

Everything before the sensor is linear in the emitted luminance of the
frames, and :meth:`sim.truth.Truth.transport` returns exactly the matrix the
capture applies.

Example::

    room = Room(reference_scene())
    for slot in room.slots:
        w, h = room.projector_size(slot)
        room.set_frame(slot, np.full((h, w, 3), 255, np.uint8))
    room.set_occluders([Hand(position=(0, 0), height=200)])
    image = room.capture()          # (H, W, 3) float32
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Iterable

import cv2
import numpy as np

from sim.errors import FrameError, UnknownSlotError
from sim.geometry import Pinhole, intersect_plane_z
from sim.occluders import HandPath, Primitive, flatten
from sim.optics import (
    REFERENCE_DISTANCE_MM,
    SIGMA_LEVELS,
    blend_levels,
    field_padding,
    gaussian_kernel,
)
from sim.scene import ProjectorSpec, Scene


#: Kinds of surface a camera pixel sees.
NOTHING, TABLE, MESH = 0, 1, 2

#: Below this spread (projector px) of a projector's blur over the view, one blur level is used.
SIGMA_TOLERANCE = 0.1

#: Largest camera-footprint sigma (projector px) — a grazing camera pixel is not blurred further.
CAMERA_SIGMA_LIMIT = 2.0

#: Shadow-map texels per projector pixel and axis (mesh self-occlusion).
SHADOW_MAP_SCALE = 2

#: Offset (mm) along the normal before testing an occluder point's own shadows.
_SELF_OFFSET = 0.5

#: Field-cache budget: above this many bytes of cached fields, fields are recomputed per capture.
CACHE_BUDGET_BYTES = 1_500_000_000

#: Views with more ROI pixels than this keep single-channel coefficients (memory over speed).
_COEF3_LIMIT = 700_000


@dataclass(eq=False)
class _Plan:
    """How one projector lights the static surface seen by one camera."""

    upsample: int
    pad: int
    sigmas: tuple[float, ...]  # blur of each level, projector px
    mapx: np.ndarray  # (hr, wr) float32 field coordinates (-10: unlit)
    mapy: np.ndarray
    weight: np.ndarray  # (hr, wr) float32 albedo * peak * irradiance * static visibility
    lo: np.ndarray  # (hr, wr) int8 level
    alpha: np.ndarray  # (hr, wr) float32 blend towards level lo + 1
    coef: dict[int, np.ndarray]  # level -> (hr, wr, 3) or (hr, wr) float32
    lit: np.ndarray  # (n,) int64 flat ROI indices with weight > 0 or light spill
    order: np.ndarray  # (n,) int32 positions into ``lit``, sorted by tile
    starts: np.ndarray  # (ntiles + 1,) int64
    tiles: tuple[int, int, float, int]  # tiles across, down, origin (px), tile size (px)
    uv: np.ndarray  # (n, 2) float32 projector coordinates of ``lit``
    tile_dirs: np.ndarray  # (nty, ntx, 3) unit world directions through tile centres
    tile_ang: float  # bound on a tile's angular radius, rad

    def coef_2d(self, level: int) -> np.ndarray:
        c = self.coef[level]
        return c[:, :, 0] if c.ndim == 3 else c


@dataclass(eq=False)
class _View:
    """What one camera sees of the static room (ROI-shaped arrays)."""

    camera: int
    roi: tuple[int, int, int, int]
    kind: np.ndarray  # (hr, wr) uint8
    points: np.ndarray  # (hr, wr, 3) float64
    normals: np.ndarray  # (hr, wr, 3) float64
    albedo: np.ndarray  # (hr, wr) float32
    content_uv: np.ndarray  # (hr, wr, 2) float32
    distance: np.ndarray  # (hr, wr) float64 from the camera centre (inf: nothing)
    cam_area: np.ndarray  # (hr, wr) float64 camera pixel footprint, mm^2
    plans: dict[str, _Plan] = field(default_factory=dict)
    surf: np.ndarray = field(default=None)  # (n,) flat ROI indices that see a surface
    scratch: np.ndarray = field(default=None)  # (hr, wr, 3) float32 work buffer of captures

    def __post_init__(self) -> None:
        self.surf = np.flatnonzero(self.kind.reshape(-1) != NOTHING)
        # Surface-only copies, contiguous, for the per-projector precomputation.
        flat_p = self.points.reshape(-1, 3)
        flat_n = self.normals.reshape(-1, 3)
        self.s_points = tuple(np.ascontiguousarray(flat_p[self.surf, k]) for k in range(3))
        self.s_normals = tuple(np.ascontiguousarray(flat_n[self.surf, k]) for k in range(3))
        self.s_albedo = self.albedo.reshape(-1)[self.surf]
        self.s_cam_area = self.cam_area.reshape(-1)[self.surf]
        self.scratch = np.empty((*self.kind.shape, 3), np.float32)

    @property
    def shape(self) -> tuple[int, int]:
        return self.kind.shape


@dataclass(eq=False)
class _Samples:
    """Sampling of one projector at a flat list of points (camera pixels that see an occluder)."""

    mapx: np.ndarray  # (1, n) float32
    mapy: np.ndarray
    weight: np.ndarray  # (n,) float32
    lo: np.ndarray  # (n,) int8
    alpha: np.ndarray  # (n,) float32
    coef: dict[int, np.ndarray]  # level -> (n,) float32


@dataclass(eq=False)
class _Dynamic:
    """Occluder state for one view."""

    key: object
    primitives: list[Primitive]
    blocked: dict[str, np.ndarray]  # slot -> flat ROI indices whose sight line is blocked
    hand_index: np.ndarray  # (m,) flat image indices of pixels that see an occluder
    hand_roi: np.ndarray  # flat ROI indices among them
    hand_points: np.ndarray  # (m, 3)
    hand_normals: np.ndarray  # (m, 3)
    samples: dict[str, _Samples] = field(default_factory=dict)


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
        from sim.truth import Truth

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
        self._views: dict[int, _View] = {}
        self._dynamic: dict[int, _Dynamic] = {}
        self._fields: dict[tuple, tuple[int, dict[int, np.ndarray]]] = {}
        self._shadow_maps: dict[str, tuple[Pinhole, np.ndarray]] = {}
        self._mesh_gbuffers: dict[int, tuple] = {}
        self._spec = {p.slot: p for p in scene.projectors}
        self.truth = Truth(self)
        if scene.mesh is not None:
            self._build_mesh_maps()

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

    def set_active(self, slots: Iterable[str]) -> None:
        """Power exactly ``slots`` (e.g. ``SUBSETS["P9D"]``); the others emit nothing."""
        slots = list(slots)
        for s in slots:
            self.projector(s)
        with self._lock:
            wanted = set(slots)
            self._active = [s for s in self.all_slots if s in wanted]

    def set_occluders(self, occluders: Iterable | HandPath | None) -> None:
        """Place occluders: a list of :class:`~sim.occluders.Hand`, boxes, ...; ``[]`` or None for none.

        A :class:`~sim.occluders.HandPath` moves a hand: each capture places
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
        with self._lock:
            self._view(camera)

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
        (H, W, 3) float32: ``sum_i transport_i @ luminance_i`` (see :meth:`sim.truth.Truth.transport`).
        """
        with self._lock:
            cam = self.scene.camera(camera)
            view = self._view(camera)
            dyn = self._dynamic_state(view, time=time)
            x0, y0, x1, y1 = view.roi
            W, H = cam.size
            acc = np.zeros((*view.shape, 3), np.float32)
            sample = view.scratch
            hand_acc = np.zeros((len(dyn.hand_index), 3), np.float32)
            for slot in self._active:
                if self._frames[slot] is None:
                    continue
                plan = view.plans[slot]
                fields = self._field(slot, plan)
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
                    hs = self._samples(view, dyn, slot)
                    for level, coef in hs.coef.items():
                        hand = cv2.remap(fields[level], hs.mapx, hs.mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))
                        hand_acc += hand[0] * coef[:, None]
            if len(dyn.hand_roi):
                acc.reshape(-1, 3)[dyn.hand_roi] = 0.0
            out = np.zeros((H, W, 3), np.float32)
            out[y0:y1, x0:x1] = acc
            if len(dyn.hand_index):
                out.reshape(-1, 3)[dyn.hand_index] = hand_acc
            out *= np.float32(cam.gain * (cam.exposure if exposure is None else exposure))
            return out

    # ------------------------------------------------------------ fields

    def _field(self, slot: str, plan: _Plan) -> dict[int, np.ndarray]:
        """Blurred light fields (level -> (Hf, Wf, 3) float32) of ``slot``'s current frame."""
        ckey = (slot, plan.upsample, plan.pad, plan.sigmas)
        version = self._frame_version[slot]
        cached = self._fields.get(ckey)
        if cached is not None and cached[0] == version:
            return cached[1]
        spec = self._spec[slot]
        frame = self._frames[slot]
        lum = cv2.LUT(frame, spec.response.table_u8().reshape(1, 256, 3))
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
        self._fields.pop(ckey, None)
        total = sum(f.nbytes for _, fs in self._fields.values() for f in fs.values())
        if total + sum(f.nbytes for f in fields.values()) <= CACHE_BUDGET_BYTES:
            self._fields[ckey] = (version, fields)
        return fields

    # ------------------------------------------------------------ static precomputation

    def _build_mesh_maps(self) -> None:
        from sim.raster import MeshRaster

        with MeshRaster(self.scene.mesh) as raster:
            for p in self.scene.projectors:
                w, h = p.pinhole.size
                device = p.pinhole.scaled((w * SHADOW_MAP_SCALE, h * SHADOW_MAP_SCALE))
                self._shadow_maps[p.slot] = (device, raster.depth_map(device))
            for i, c in enumerate(self.scene.cameras):
                self._mesh_gbuffers[i] = raster.gbuffer(c.pinhole)

    def _mesh_shadowed(self, slot: str, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """(n,) bool: the mesh hides ``points`` from projector ``slot`` (shadow-map test)."""
        if slot not in self._shadow_maps or len(points) == 0:
            return np.zeros(len(points), bool)
        device, depth = self._shadow_maps[slot]
        pix, z = device.project(points)
        h, w = depth.shape
        inside = (pix[:, 0] >= 0) & (pix[:, 0] <= w - 1) & (pix[:, 1] >= 0) & (pix[:, 1] <= h - 1) & (z > 0)
        x2 = np.clip(np.floor(np.nan_to_num(pix[:, 0])).astype(np.int64), 0, w - 2)
        y2 = np.clip(np.floor(np.nan_to_num(pix[:, 1])).astype(np.int64), 0, h - 2)
        # Occluded only if all four texels around the point are nearer: no acne, slight leaks at silhouettes.
        dmax = np.maximum.reduce([depth[y2, x2], depth[y2, x2 + 1], depth[y2 + 1, x2], depth[y2 + 1, x2 + 1]])
        # Slope-scaled bias: one texel spans z / f mm; a tilted surface changes depth by tan(theta) per mm.
        to_dev = device.center - points
        dist = np.linalg.norm(to_dev, axis=1)
        cos_t = np.clip(np.einsum("ij,ij->i", normals, to_dev) / dist, 0.05, 1.0)
        tan_t = np.sqrt(1.0 - cos_t**2) / cos_t
        bias = np.minimum(1.0 + 2.0 * (z / device.K[0, 0]) * tan_t, 25.0)
        return inside & (z > dmax + bias)

    def _view(self, camera: int) -> _View:
        view = self._views.get(camera)
        if view is None:
            view = self._build_view(camera)
            for p in self.scene.projectors:
                view.plans[p.slot] = self._build_plan(view, p)
            self._views[camera] = view
        return view

    def _build_view(self, camera: int) -> _View:
        scene = self.scene
        cam = scene.camera(camera).pinhole
        W, H = cam.size
        rays = cam.rays(cam.pixel_grid())
        kind = np.zeros((H, W), np.uint8)
        points = np.zeros((H, W, 3))
        normals = np.zeros((H, W, 3))
        albedo = np.zeros((H, W), np.float32)
        content = np.full((H, W, 2), np.nan, np.float32)
        dist = np.full((H, W), np.inf)
        if scene.table is not None:
            tw, th = scene.table.size
            pts, s = intersect_plane_z(np.broadcast_to(cam.center, rays.shape), rays, z=0.0)
            on = np.isfinite(s) & (np.abs(pts[..., 0]) <= tw / 2) & (np.abs(pts[..., 1]) <= th / 2)
            kind[on] = TABLE
            points[on] = pts[on]
            normals[on] = (0.0, 0.0, 1.0)
            albedo[on] = scene.table.albedo
            content[on, 0] = (pts[on, 0] + tw / 2) / tw
            content[on, 1] = (th / 2 - pts[on, 1]) / th
            dist[on] = s[on]
        if scene.mesh is not None:
            mpos, mnrm, muv, mhit = self._mesh_gbuffers[camera]
            md = np.linalg.norm(mpos.astype(np.float64) - cam.center, axis=-1)
            front = mhit & (md < dist)
            kind[front] = MESH
            points[front] = mpos[front]
            n = mnrm[front].astype(np.float64)
            normals[front] = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
            albedo[front] = scene.mesh_albedo
            content[front] = muv[front]
            dist[front] = md[front]
        ys, xs = np.nonzero(kind)
        roi = (0, 0, 1, 1) if len(ys) == 0 else (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
        x0, y0, x1, y1 = roi
        sl = (slice(y0, y1), slice(x0, x1))
        pts, nrm = points[sl].copy(), normals[sl].copy()
        cam_area = np.full(pts.shape[:2], np.inf)
        surf = kind[sl] != NOTHING
        cam_area[surf] = _footprint_area(cam, pts[surf], nrm[surf])
        return _View(camera, roi, kind[sl].copy(), pts, nrm, albedo[sl].copy(), content[sl].copy(), dist[sl].copy(), cam_area)

    def _build_plan(self, view: _View, spec: ProjectorSpec) -> _Plan:
        dev = spec.pinhole
        w, h = dev.size
        surf = view.surf
        pts = view.s_points
        nrm = view.s_normals
        g = _geometry(dev, pts, nrm, falloff=spec.falloff)
        proj_area = g["area"]
        cam_area = view.s_cam_area
        ok = np.isfinite(proj_area) & np.isfinite(cam_area)
        if self._upsample is not None:
            s = int(self._upsample)
        elif ok.any():
            some = np.flatnonzero(ok)[:: max(1, int(ok.sum()) // 20000)]  # a sample is plenty for a median
            s = int(np.clip(round(float(np.median(np.sqrt(proj_area[some] / cam_area[some])))), 1, 4))
        else:
            s = 1
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(ok, cam_area / proj_area, 0.0)
        sigma_cam = np.minimum(np.sqrt(np.maximum(ratio, 0.0) / 12.0), CAMERA_SIGMA_LIMIT)
        d = g["distance"]
        with np.errstate(divide="ignore", invalid="ignore"):
            sigma_def = np.where(d > 0, spec.aperture * dev.K[0, 0] * np.abs(d - spec.focus) / (4.0 * spec.focus * d), 0.0)
        sigma = np.sqrt(sigma_def**2 + sigma_cam**2)
        u, v, depth, e = g["u"], g["v"], g["depth"], g["irradiance"]
        margin = 3.0 * float(np.max(sigma, initial=0.0)) + 1.0
        lit = (depth > 0) & (e > 0) & (u > -0.5 - margin) & (u < w - 0.5 + margin) & (v > -0.5 - margin) & (v < h - 0.5 + margin)
        if self.scene.mesh is not None and lit.any():
            idx = np.flatnonzero(lit)
            sub_p = np.column_stack([a[idx] for a in pts])
            sub_n = np.column_stack([a[idx] for a in nrm])
            lit[idx[self._mesh_shadowed(spec.slot, sub_p, sub_n)]] = False
        # Blur levels: one if the blur hardly varies, else a blend of two ladder levels per pixel.
        sl = sigma[lit]
        if len(sl) == 0 or float(sl.max() - sl.min()) <= SIGMA_TOLERANCE:
            rms = float(np.sqrt(np.mean(sl**2))) if len(sl) else 0.0
            sigmas: tuple[float, ...] = (rms,)
            lo = np.zeros(len(surf), np.int32)
            alpha = np.zeros(len(surf), np.float32)
        else:
            glo, galpha = blend_levels(sigma)
            first = int(glo[lit].min())
            last = int(np.max(np.where(galpha > 0, glo + 1, glo)[lit]))
            sigmas = tuple(SIGMA_LEVELS[first : last + 1])
            lo = glo - first
            alpha = galpha
        pad = field_padding(max(sigmas), s)
        shape = view.shape
        n_roi = shape[0] * shape[1]

        def roi_map(values, fill, dtype):
            out = np.full(n_roi, fill, dtype)
            out[surf] = values
            return out.reshape(shape)

        fx = np.where(lit, s * (u + 0.5) - 0.5 + pad, -10.0)
        fy = np.where(lit, s * (v + 0.5) - 0.5 + pad, -10.0)
        mapx = roi_map(fx, -10.0, np.float32)
        mapy = roi_map(fy, -10.0, np.float32)
        weight = roi_map(np.where(lit, view.s_albedo * spec.peak * e, 0.0), 0.0, np.float32)
        lo_map = roi_map(lo, 0, np.int8)
        alpha_map = roi_map(np.where(lit, alpha, 0.0), 0.0, np.float32)
        coef = _blend_coefficients(weight, lo_map, alpha_map, len(sigmas), three=n_roi <= _COEF3_LIMIT)
        lit_roi = surf[lit]
        uv = np.empty((len(lit_roi), 2), np.float32)
        uv[:, 0] = u[lit]
        uv[:, 1] = v[lit]
        order, starts, tiles, tile_dirs, tile_ang = _tile_index(uv, dev)
        return _Plan(s, pad, sigmas, mapx, mapy, weight, lo_map, alpha_map, coef, lit_roi, order, starts, tiles, uv, tile_dirs, tile_ang)

    # ------------------------------------------------------------ occluders

    def _dynamic_state(self, view: _View, *, time: float | None = None) -> _Dynamic:
        occluders = self.occluders(time=time)
        if self._path is not None:
            hand = occluders[0]
            key = (self._occ_version, hand.position, hand.height)
        else:
            key = (self._occ_version,)
        dyn = self._dynamic.get(view.camera)
        if dyn is not None and dyn.key == key:
            return dyn
        dyn = self._occlude(view, flatten(occluders), key)
        self._dynamic[view.camera] = dyn
        return dyn

    def _occlude(self, view: _View, prims: list[Primitive], key) -> _Dynamic:
        cam = self.scene.camera(view.camera).pinhole
        W, H = cam.size
        x0, y0, x1, y1 = view.roi
        wr = x1 - x0
        empty = np.zeros(0, np.int64)
        if not prims:
            return _Dynamic(key, prims, {}, empty, empty, np.zeros((0, 3)), np.zeros((0, 3)))
        # 1. Camera pixels that see an occluder: rays over the projected boxes of the primitives.
        mask = np.zeros((H, W), bool)
        boxes = [_projected_bboxes(cam, prim.cull_spheres()) for prim in prims]
        for prim_boxes in boxes:
            for bb in prim_boxes:
                if bb is None:
                    mask[:] = True
                    continue
                bx0, by0, bx1, by1 = _pixel_box(bb, W, H)
                mask[by0:by1, bx0:bx1] = True
        idx = np.flatnonzero(mask)
        xs, ys = idx % W, idx // W
        dirs = cam.rays(np.column_stack([xs, ys]).astype(np.float64))
        best = np.full(len(idx), np.inf)
        for prim, prim_boxes in zip(prims, boxes):
            sel = np.flatnonzero(_in_boxes(xs, ys, prim_boxes))
            if len(sel) == 0:
                continue
            d = dirs[sel]
            t_in, t_out = prim.interval_from(cam.center, d[:, 0], d[:, 1], d[:, 2])
            ok = (t_in > 0) & (t_in <= t_out) & (t_in < best[sel])
            best[sel[ok]] = t_in[ok]
        static = np.full(len(idx), np.inf)
        in_roi = (xs >= x0) & (xs < x1) & (ys >= y0) & (ys < y1)
        static[in_roi] = view.distance[ys[in_roi] - y0, xs[in_roi] - x0]
        seen = np.isfinite(best) & (best < static)
        hand_index = idx[seen]
        hit_dirs = dirs[seen]
        hand_points = cam.center + best[seen, None] * hit_dirs
        hand_normals = np.zeros_like(hand_points)
        bestn = np.full(len(hand_points), np.inf)
        for prim in prims:  # normals from the full test on the few hit pixels
            t_in, _, n = prim.interval(np.broadcast_to(cam.center, hit_dirs.shape).copy(), hit_dirs)
            better = (t_in > 0) & (t_in < bestn)
            bestn = np.where(better, t_in, bestn)
            hand_normals = np.where(better[:, None], n, hand_normals)
        r = in_roi[seen]
        hand_roi = (ys[seen][r] - y0) * wr + (xs[seen][r] - x0)
        # 2. Per projector: static surface points whose line of sight to it crosses an occluder.
        flat_points = view.points.reshape(-1, 3)
        n_roi = view.shape[0] * view.shape[1]
        blocked: dict[str, np.ndarray] = {}
        for slot, plan in view.plans.items():
            dev = self._spec[slot].pinhole
            hit_mask = np.zeros(n_roi, bool)
            for prim in prims:
                cand = _cone_candidates(plan, dev, prim.cull_spheres())
                if len(cand) == 0:
                    continue
                roi_idx = plan.lit[cand]
                vec = flat_points[roi_idx] - dev.center
                dist = np.sqrt(np.einsum("ij,ij->i", vec, vec))
                vec /= dist[:, None]
                t_in, t_out = prim.interval_from(dev.center, vec[:, 0], vec[:, 1], vec[:, 2])
                hit_mask[roi_idx[(t_in < dist - 1e-6) & (t_out > 1e-6)]] = True
            blocked[slot] = np.flatnonzero(hit_mask)
        return _Dynamic(key, prims, blocked, hand_index, hand_roi, hand_points, hand_normals)

    def _samples(self, view: _View, dyn: _Dynamic, slot: str) -> _Samples:
        """How ``slot`` lights the occluder surface the camera sees (computed once per occluder state)."""
        hs = dyn.samples.get(slot)
        if hs is not None:
            return hs
        spec = self._spec[slot]
        dev = spec.pinhole
        plan = view.plans[slot]
        cam = self.scene.camera(view.camera).pinhole
        pts, nrm = dyn.hand_points, dyn.hand_normals
        g = _geometry(dev, pts, nrm, falloff=spec.falloff)
        u, v, depth, e = g["u"], g["v"], g["depth"], g["irradiance"]
        w, h = dev.size
        lit = (depth > 0) & (e > 0) & (u > -0.5) & (u < w - 0.5) & (v > -0.5) & (v < h - 0.5)
        if lit.any():
            idx = np.flatnonzero(lit)
            start = pts[idx] + _SELF_OFFSET * nrm[idx]
            vec = start - dev.center
            dist = np.linalg.norm(vec, axis=1)
            vec /= dist[:, None]
            blocked = np.zeros(len(idx), bool)
            for prim in dyn.primitives:
                # Only points whose projector pixel lies in the primitive's projected boxes can be hidden by it.
                sel = np.flatnonzero(_in_boxes(u[idx], v[idx], _projected_bboxes(dev, prim.cull_spheres())))
                if len(sel) == 0:
                    continue
                d = vec[sel]
                t_in, t_out = prim.interval_from(dev.center, d[:, 0], d[:, 1], d[:, 2])
                blocked[sel] |= (t_in < dist[sel] - 1e-6) & (t_out > 1e-6)
            lit[idx[blocked]] = False
        if self.scene.mesh is not None and lit.any():
            idx = np.flatnonzero(lit)
            lit[idx[self._mesh_shadowed(slot, pts[idx], nrm[idx])]] = False
        # Blur as in the static plan (the field is shared): clamp into its levels.
        cam_area = _footprint_area(cam, pts, nrm)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(np.isfinite(cam_area) & np.isfinite(g["area"]), cam_area / g["area"], 0.0)
        d = g["distance"]
        sigma = np.sqrt((spec.aperture * dev.K[0, 0] * np.abs(d - spec.focus) / (4.0 * spec.focus * np.maximum(d, 1e-9))) ** 2 + np.minimum(ratio / 12.0, CAMERA_SIGMA_LIMIT**2))
        if len(plan.sigmas) == 1:
            lo = np.zeros(len(pts), np.int32)
            alpha = np.zeros(len(pts), np.float32)
        else:
            lo, alpha = blend_levels(sigma, plan.sigmas)
        s, pad = plan.upsample, plan.pad
        mapx = np.where(lit, s * (u + 0.5) - 0.5 + pad, -10.0).astype(np.float32)[None, :]
        mapy = np.where(lit, s * (v + 0.5) - 0.5 + pad, -10.0).astype(np.float32)[None, :]
        weight = np.where(lit, self.scene.hand_albedo * spec.peak * e, 0.0).astype(np.float32)
        lo8 = lo.astype(np.int8)
        alpha = np.where(lit, alpha, 0.0).astype(np.float32)
        coef = {L: c[0] for L, c in _blend_coefficients(weight[None, :], lo8[None, :], alpha[None, :], len(plan.sigmas), three=False).items()}
        hs = _Samples(mapx, mapy, weight, lo8, alpha, coef)
        dyn.samples[slot] = hs
        return hs


# ---------------------------------------------------------------- helpers


def _soa(a) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, y, z) component arrays of (n, 3) points or of a tuple of three arrays."""
    if isinstance(a, tuple):
        return a
    return a[:, 0], a[:, 1], a[:, 2]


def _affine_row(row: np.ndarray, X: np.ndarray, Y: np.ndarray, Z: np.ndarray) -> np.ndarray:
    out = row[0] * X
    out += row[1] * Y
    out += row[2] * Z
    out += row[3]
    return out


def _geometry(dev: Pinhole, pts, nrm, *, falloff: float) -> dict[str, np.ndarray]:
    """Per-point projection and photometry of one device, component-wise and in place for speed.

    ``pts``, ``nrm``: (n, 3) arrays or (x, y, z) tuples of (n,) arrays.
    Returns u, v (pixels), depth (mm along the axis), distance (mm), irradiance
    (:func:`sim.optics.irradiance_factor`) and area (:func:`sim.geometry.pixel_footprint_area`).
    """
    P = dev._P
    X, Y, Z = _soa(pts)
    NX, NY, NZ = _soa(nrm)
    hz = _affine_row(P[2], X, Y, Z)
    c = dev.center
    vx = c[0] - X
    vy = c[1] - Y
    vz = c[2] - Z
    d2 = vx * vx
    d2 += vy * vy
    d2 += vz * vz
    d = np.sqrt(d2)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = _affine_row(P[0], X, Y, Z)
        u /= hz
        v = _affine_row(P[1], X, Y, Z)
        v /= hz
        cos_t = NX * vx
        cos_t += NY * vy
        cos_t += NZ * vz
        cos_t /= d
        cos_a = hz / d  # depth / distance (K's last row is (0, 0, 1))
        valid = (cos_t > 0) & (cos_a > 1e-6)
        k = falloff - 3.0
        if k == -2.0:
            e = 1.0 / (cos_a * cos_a)
        elif k == -3.0:
            e = 1.0 / (cos_a * cos_a * cos_a)
        else:
            e = np.power(cos_a, k)
        e *= cos_t
        e *= REFERENCE_DISTANCE_MM * REFERENCE_DISTANCE_MM
        e /= d2
        e[~valid] = 0.0
        area = cos_a * cos_a * cos_a
        area *= d2
        area /= dev.K[0, 0] * dev.K[1, 1]
        area /= cos_t
        area[~valid] = np.inf
    return {"u": u, "v": v, "depth": hz, "distance": d, "irradiance": e, "area": area}


def _footprint_area(dev: Pinhole, pts: np.ndarray, nrm: np.ndarray) -> np.ndarray:
    return _geometry(dev, pts, nrm, falloff=0.0)["area"]


def _blend_coefficients(weight: np.ndarray, lo: np.ndarray, alpha: np.ndarray, n_levels: int, *, three: bool) -> dict[int, np.ndarray]:
    """level -> weight x blend coefficient; levels that carry nothing are left out."""
    coef = {}
    for L in range(n_levels):
        if n_levels == 1:
            c = weight.astype(np.float32)
        else:
            c = (weight * (np.where(lo == L, 1.0 - alpha, 0.0) + np.where(lo + 1 == L, alpha, 0.0))).astype(np.float32)
        if not np.any(c):
            continue
        coef[L] = np.repeat(c[..., None], 3, axis=-1) if three else c
    return coef


def _tile_size(width: int) -> int:
    return max(4, width // 80)


def _tile_index(uv: np.ndarray, dev: Pinhole) -> tuple[np.ndarray, np.ndarray, tuple[int, int, float, int], np.ndarray, float]:
    """Sort lit points by the projector tile they fall in.

    Returns positions into ``uv`` sorted by tile, each tile's start, the grid
    (tiles across, down, origin px, tile px), the unit world direction through
    every tile centre (nty, ntx, 3) and a bound on a tile's angular radius.
    Points outside the grid are clipped into its border tiles.
    """
    w, h = dev.size
    T = _tile_size(w)
    origin = -4.0 * T
    ntx = int(math.ceil((w - origin + 4 * T) / T))
    nty = int(math.ceil((h - origin + 4 * T) / T))
    # Truncation equals floor for the non-negative values that survive the clamp below.
    tx = ((uv[:, 0] - origin) * (1.0 / T)).astype(np.int32)
    ty = ((uv[:, 1] - origin) * (1.0 / T)).astype(np.int32)
    np.clip(tx, 0, ntx - 1, out=tx)
    np.clip(ty, 0, nty - 1, out=ty)
    tid = ty * ntx + tx
    # A stable sort of small integers is a radix sort in numpy: linear time.
    order = np.argsort(tid.astype(np.uint16) if ntx * nty < 65536 else tid, kind="stable").astype(np.int32)
    starts = np.searchsorted(tid[order], np.arange(ntx * nty + 1))
    cx = origin + (np.arange(ntx) + 0.5) * T
    cy = origin + (np.arange(nty) + 0.5) * T
    dirs = dev.rays(np.stack(np.meshgrid(cx, cy), axis=-1))
    # A tile reaches T * sqrt(2) / 2 px from its centre; one pixel subtends at most 1 / f radians.
    ang = T * math.sqrt(2.0) / 2.0 / min(dev.K[0, 0], dev.K[1, 1])
    return order, starts, (ntx, nty, origin, T), dirs, ang


def _cone_candidates(plan: _Plan, dev: Pinhole, spheres) -> np.ndarray:
    """Positions into ``plan.lit`` whose line of sight to ``dev`` may cross one of ``spheres``.

    A tile is kept when the cone of directions through it meets the cone
    that a sphere subtends from the projector's centre.
    """
    ntx, nty, origin, T = plan.tiles
    marked = np.zeros((nty, ntx), bool)
    c0 = dev._center
    for (center, radius), bb in zip(spheres, _projected_bboxes(dev, spheres)):
        q = np.asarray(center, np.float64) - c0
        D = math.sqrt(float(q @ q))
        if D <= radius * 1.001 or bb is None:
            return plan.order.astype(np.int64)
        u0, v0, u1, v1 = bb
        tx0 = min(max(int((u0 - origin) // T) - 1, 0), ntx - 1)
        tx1 = min(max(int((u1 - origin) // T) + 1, 0), ntx - 1)
        ty0 = min(max(int((v0 - origin) // T) - 1, 0), nty - 1)
        ty1 = min(max(int((v1 - origin) // T) + 1, 0), nty - 1)
        sub = plan.tile_dirs[ty0 : ty1 + 1, tx0 : tx1 + 1]
        limit = math.cos(min(math.pi, math.asin(min(1.0, radius / D)) + plan.tile_ang))
        near = (sub @ (q / D)) >= limit
        # Border tiles also hold the points clipped into them from outside the grid.
        if tx0 == 0:
            near[:, 0] = True
        if ty0 == 0:
            near[0, :] = True
        if tx1 == ntx - 1:
            near[:, -1] = True
        if ty1 == nty - 1:
            near[-1, :] = True
        marked[ty0 : ty1 + 1, tx0 : tx1 + 1] |= near
    tiles = np.flatnonzero(marked)
    first = plan.starts[tiles]
    counts = plan.starts[tiles + 1] - first
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    offsets = np.repeat(first - (np.cumsum(counts) - counts), counts) + np.arange(total)
    return plan.order[offsets].astype(np.int64)


def _pixel_box(bb, W: int, H: int) -> tuple[int, int, int, int]:
    """Integer pixel range (x0, y0, x1, y1), clipped to the image, covering a float box."""
    x0 = int(np.clip(math.floor(bb[0]), 0, W))
    y0 = int(np.clip(math.floor(bb[1]), 0, H))
    x1 = int(np.clip(math.ceil(bb[2]) + 1, 0, W))
    y1 = int(np.clip(math.ceil(bb[3]) + 1, 0, H))
    return x0, y0, max(x0, x1), max(y0, y1)


def _in_boxes(x: np.ndarray, y: np.ndarray, boxes) -> np.ndarray:
    """Whether points (pixel coordinates) fall in any of ``boxes`` (None: a box covering everything)."""
    out = np.zeros(np.shape(x), bool)
    for bb in boxes:
        if bb is None:
            return np.ones(np.shape(x), bool)
        out |= (x >= bb[0] - 1) & (x <= bb[2] + 1) & (y >= bb[1] - 1) & (y <= bb[3] + 1)
    return out


_CUBE = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float64)


def _projected_bboxes(device: Pinhole, spheres) -> list:
    """:func:`_projected_bbox` of many spheres at once."""
    centers = np.array([c for c, _ in spheres], np.float64)
    radii = np.array([r for _, r in spheres], np.float64)
    corners = centers[:, None, :] + radii[:, None, None] * _CUBE  # (S, 8, 3)
    pix, z = device.project(corners)
    lo = pix.min(axis=1)
    hi = pix.max(axis=1)
    behind = np.any(z <= 1.0, axis=1)
    return [None if behind[k] else (float(lo[k, 0]), float(lo[k, 1]), float(hi[k, 0]), float(hi[k, 1])) for k in range(len(spheres))]


def _projected_bbox(device: Pinhole, center: np.ndarray, radius: float):
    """Pixel box (u0, v0, u1, v1) holding a sphere's image, or None if the sphere reaches behind the device."""
    corners = center + radius * np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float64)
    pix, z = device.project(corners)
    if np.any(z <= 1.0):
        return None
    u0, v0 = pix.min(axis=0)
    u1, v1 = pix.max(axis=0)
    return (float(u0), float(v0), float(u1), float(v1))
