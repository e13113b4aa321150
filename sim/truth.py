"""Ground truth of a room: poses, homographies, correspondences, light transport, light drop.

For tests and benchmarks only: the coordinator never reads these, it has to
measure them through captures. ``room.truth`` is a :class:`Truth`.

:class:`Truth` reads the room only through the public methods listed in
:class:`RoomState` (which :class:`sim.room.Room` implements); this module does
not import :mod:`sim.room`.
"""
from __future__ import annotations

from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import scipy.sparse

from protos.spaces import content_to_table
from sim.geometry import plane_homography
from sim.occlusion import DynamicState, OccluderSamples
from sim.optics import Sensor, remap_fractions, sample_weights_1d
from sim.photometry import Profile
from sim.precompute import NOTHING, View
from sim.scene import ProjectorSpec, Scene


class RoomState(Protocol):
    """What :class:`Truth` reads of a room; :class:`sim.room.Room` provides it."""

    scene: Scene

    @property
    def active(self) -> list[str]:
        """The powered projectors."""

    @property
    def lock(self) -> AbstractContextManager:
        """Held while reading several pieces of state that must agree."""

    def projector(self, slot: str) -> ProjectorSpec:
        """The specification of projector ``slot``."""

    def view(self, camera: int = 0) -> View:
        """The static precomputation of ``camera``."""

    def dynamic_state(self, view: View, *, time: float | None = None) -> DynamicState:
        """What the current occluders hide in ``view``."""

    def occluder_samples(self, view: View, dyn: DynamicState, slot: str) -> OccluderSamples:
        """How ``slot`` lights the occluder surface the camera of ``view`` sees."""

    def lamp(self, slot: str) -> np.ndarray:
        """(3,) the lamp of ``slot`` now (1 = as new, 0 = dead)."""

    def render_projector(self, slot: str, luminance: np.ndarray, camera: int = 0) -> np.ndarray:
        """(H, W, 3) the linear signal of ``slot`` alone emitting ``luminance`` (h, w, 3)."""


@dataclass(frozen=True, eq=False)
class ProjectorTruth:
    """A projector's true optics at the room's resolution (``native_*``: at native resolution).

    ``P = K [R | t]`` maps world mm to projector pixels; the response maps an
    input value v in [0, 1] to ``black + (1 - black) v**gamma`` (per channel),
    times ``peak`` (the unit's brightness), ``white`` (its per-channel gains, the
    white point), ``lamp`` (the lamp now, per channel: 1 as new, 0 dead) and the
    profile at the pixel (``profile``: hot spot and vignetting,
    :class:`sim.photometry.Profile`, the identity when even). See :mod:`sim.photometry`.
    """

    slot: str
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    P: np.ndarray
    size: tuple[int, int]
    native_K: np.ndarray
    native_size: tuple[int, int]
    center: np.ndarray
    gamma: np.ndarray
    black: np.ndarray
    peak: float
    aperture: float
    focus: float
    falloff: float
    powered: bool
    white: np.ndarray = None       # (3,) float64
    lamp: np.ndarray = None        # (3,) float64
    profile: Profile = Profile()

    @property
    def hotspot(self) -> float:
        return self.profile.hotspot

    @property
    def hotspot_width(self) -> float:
        return self.profile.hotspot_width

    @property
    def hotspot_center(self) -> tuple[float, float]:
        return self.profile.hotspot_center

    @property
    def vignetting(self) -> float:
        return self.profile.vignetting


@dataclass(frozen=True, eq=False)
class CameraTruth:
    """A camera's true optics at the room's resolution, and its sensor."""

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    P: np.ndarray
    size: tuple[int, int]
    center: np.ndarray
    gain: float
    exposure: float
    sensor: Sensor


@dataclass(frozen=True, eq=False)
class SurfaceTruth:
    """What each camera pixel sees of the static room (no occluders).

    Attributes
    ----------
    points : (H, W, 3) float32   world mm (nan where nothing)
    normals : (H, W, 3) float32
    uv : (H, W, 2) float32       content uv of the table or mesh (nan where nothing)
    kind : (H, W) uint8          0 nothing, 1 table, 2 mesh
    """

    points: np.ndarray
    normals: np.ndarray
    uv: np.ndarray
    kind: np.ndarray


class Truth:
    """Ground-truth queries on a :class:`~sim.room.Room` (always its current state).

    Parameters
    ----------
    room : RoomState
        The room (a :class:`sim.room.Room`).
    """

    def __init__(self, room: RoomState) -> None:
        self._room = room

    # ------------------------------------------------------------ optics

    def projector(self, slot: str) -> ProjectorTruth:
        p = self._room.projector(slot)
        d = p.pinhole
        return ProjectorTruth(
            slot, d.K.copy(), d.R.copy(), d.t.copy(), d.P, d.size, p.native.K.copy(), p.native.size, d.center,
            p.response.gamma.copy(), p.response.black.copy(), p.peak, p.aperture, p.focus, p.falloff, p.powered,
            p.white_gains, self._room.lamp(slot), p.profile if p.profile is not None else Profile(),
        )

    def camera(self, camera: int = 0) -> CameraTruth:
        c = self._room.scene.camera(camera)
        d = c.pinhole
        return CameraTruth(d.K.copy(), d.R.copy(), d.t.copy(), d.P, d.size, d.center, c.gain, c.exposure, c.sensor)

    def table_to_camera_homography(self, camera: int = 0) -> np.ndarray:
        """(3, 3) float64: table mm (x, y) -> camera pixels."""
        d = self._room.scene.camera(camera).pinhole
        return plane_homography(d.K, d.R, d.t)

    def table_to_projector_homography(self, slot: str) -> np.ndarray:
        """(3, 3) float64: table mm (x, y) -> projector pixels (at the room's resolution)."""
        d = self._room.projector(slot).pinhole
        return plane_homography(d.K, d.R, d.t)

    def content_to_table_homography(self, content_size: tuple[int, int]) -> np.ndarray:
        """(3, 3) float64: content pixels -> table mm for a content image covering the table.

        Content x runs along world +x, content y along world -y (the table seen
        from above), pixel centres at integers: ``x_mm = W_mm (x + 0.5) / w - W_mm / 2``
        (the shared convention, :func:`protos.spaces.content_to_table`).
        """
        table = self._room.scene.table
        if table is None:
            raise ValueError("this room has no table")
        return content_to_table(content_size, table.size)

    def content_to_projector_homography(self, slot: str, content_size: tuple[int, int]) -> np.ndarray:
        """(3, 3) float64: the planar pose of ``slot`` for content covering the table."""
        H = self.table_to_projector_homography(slot) @ self.content_to_table_homography(content_size)
        return H / H[2, 2]

    # ------------------------------------------------------------ per-pixel truth

    def _view(self, camera: int) -> View:
        return self._room.view(camera)

    def _full(self, camera: int, roi_array: np.ndarray, fill) -> np.ndarray:
        W, H = self._room.scene.camera(camera).size
        x0, y0, x1, y1 = self._view(camera).roi
        out = np.full((H, W, *roi_array.shape[2:]), fill, dtype=roi_array.dtype)
        out[y0:y1, x0:x1] = roi_array
        return out

    def surface(self, camera: int = 0) -> SurfaceTruth:
        """Static surface seen by each camera pixel."""
        with self._room.lock:
            v = self._view(camera)
            none = v.kind == NOTHING
            pts = v.points.astype(np.float32)
            pts[none] = np.nan
            nrm = v.normals.astype(np.float32)
            nrm[none] = np.nan
            return SurfaceTruth(self._full(camera, pts, np.nan), self._full(camera, nrm, np.nan), self._full(camera, v.content_uv, np.nan), self._full(camera, v.kind, 0))

    def projector_coordinates(self, slot: str, camera: int = 0) -> np.ndarray:
        """Sub-pixel projector coordinates of each camera pixel's surface point.

        Returns
        -------
        (H, W, 2) float32; nan where the projector does not light the point
        (outside its image, facing away, or hidden by the mesh). Occluders are
        ignored here; see :meth:`shadow_mask`.
        """
        with self._room.lock:
            w, h = self._room.projector(slot).size
            view = self._view(camera)
            plan = view.plans[slot]
            uv = np.full((view.shape[0] * view.shape[1], 2), np.nan, np.float32)
            inside = (plan.uv[:, 0] >= -0.5) & (plan.uv[:, 0] <= w - 0.5) & (plan.uv[:, 1] >= -0.5) & (plan.uv[:, 1] <= h - 0.5)
            uv[plan.lit[inside]] = plan.uv[inside]
            return self._full(camera, uv.reshape(*view.shape, 2), np.nan)

    def irradiance(self, slot: str, camera: int = 0, *, occluders: bool = True) -> np.ndarray:
        """Albedo x peak x irradiance x profile (hot spot, vignetting) of ``slot`` at full white at each
        camera pixel's surface point; the white point and the lamp are not in it (see :meth:`contribution`).

        Returns
        -------
        (H, W) float32, in the units of :meth:`transport` before the camera gain.
        """
        with self._room.lock:
            view = self._view(camera)
            w = view.plans[slot].weight.copy()
            if occluders:
                dyn = self._room.dynamic_state(view)
                b = dyn.blocked.get(slot)
                if b is not None and len(b):
                    w.reshape(-1)[b] = 0.0
            return self._full(camera, w, np.float32(0.0))

    def shadow_mask(self, slot: str, camera: int = 0) -> np.ndarray:
        """(H, W) bool: occluders block ``slot``'s light at the pixel's surface point."""
        with self._room.lock:
            view = self._view(camera)
            dyn = self._room.dynamic_state(view)
            m = np.zeros(view.shape, bool)
            b = dyn.blocked.get(slot)
            if b is not None and len(b):
                m.reshape(-1)[b] = True
            m &= view.plans[slot].weight > 0
            return self._full(camera, m, False)

    def occluder_mask(self, camera: int = 0) -> np.ndarray:
        """(H, W) bool: the camera sees an occluder (hand) at the pixel."""
        with self._room.lock:
            view = self._view(camera)
            dyn = self._room.dynamic_state(view)
            W, H = self._room.scene.camera(camera).size
            m = np.zeros(H * W, bool)
            m[dyn.hand_index] = True
            return m.reshape(H, W)

    def light_drop(self, camera: int = 0) -> np.ndarray:
        """Fraction of the light lost to occluders at each camera pixel's surface point.

        ``1 - sum_i E_i v_i / sum_i E_i`` over the powered projectors, with
        ``E_i`` the full-white irradiance of projector i at the point (peak,
        distance, incidence, lens fall-off, mesh self-occlusion) and ``v_i``
        whether its line of sight is free of occluders. The surface point is
        the static one behind the pixel, also where the camera sees the hand.
        Pixels that see nothing (or no powered projector) have 0.

        Returns
        -------
        (H, W) float32 in [0, 1]
        """
        with self._room.lock:
            view = self._view(camera)
            dyn = self._room.dynamic_state(view)
            total = np.zeros(view.shape, np.float64)
            kept = np.zeros(view.shape, np.float64)
            for slot in self._room.active:
                w = view.plans[slot].weight.astype(np.float64)
                total += w
                b = dyn.blocked.get(slot)
                if b is not None and len(b):
                    w = w.copy()
                    w.reshape(-1)[b] = 0.0
                kept += w
            with np.errstate(divide="ignore", invalid="ignore"):
                drop = np.where(total > 0, 1.0 - kept / total, 0.0)
            return self._full(camera, np.clip(drop, 0.0, 1.0).astype(np.float32), np.float32(0.0))

    def contribution(self, slot: str, camera: int = 0) -> np.ndarray:
        """The camera signal ``slot`` alone adds at full white, above its black.

        What :meth:`sim.room.Room.render_linear` gives with only ``slot`` powered showing input
        255, minus the same with input 0: ``(1 - black)`` per channel through the projector's
        white point, lamp, profile, irradiance and blur, with the current occluders, the camera's
        gain and exposure (the units of ``render_linear``). Whether ``slot`` is powered now does
        not matter. Zero outside its footprint.

        Returns
        -------
        (H, W, 3) float32
        """
        room = self._room
        spec = room.projector(slot)
        w, h = spec.size
        lum = np.broadcast_to((1.0 - spec.response.black).astype(np.float32), (h, w, 3))
        return room.render_projector(slot, np.ascontiguousarray(lum), camera)

    def illumination_count(self, camera: int = 0, *, occluders: bool = False) -> np.ndarray:
        """(H, W) int32: how many powered projectors light each pixel's surface point (the paper's heat map).

        A projector counts where the point is inside its image, faces it and
        is not hidden by the mesh (and, with ``occluders``, not shadowed).
        """
        with self._room.lock:
            view = self._view(camera)
            count = np.zeros(view.shape, np.int32)
            dyn = self._room.dynamic_state(view) if occluders else None
            for slot in self._room.active:
                lit = np.isfinite(self.projector_coordinates(slot, camera)[..., 0])
                x0, y0, x1, y1 = view.roi
                m = lit[y0:y1, x0:x1].copy()
                if dyn is not None:
                    b = dyn.blocked.get(slot)
                    if b is not None and len(b):
                        m.reshape(-1)[b] = False
                count += m
            return self._full(camera, count, np.int32(0))

    # ------------------------------------------------------------ light transport

    def transport(self, slot: str, camera: int = 0) -> scipy.sparse.csr_matrix:
        """Light transport from ``slot``'s pixels to the camera's, as the capture applies it.

        Entry ``[y * W + x, v * w + u]`` is the camera's linear signal at pixel
        (x, y) (fraction of full scale, before noise and quantisation) per unit
        of relative luminance emitted by projector pixel (u, v); channels do
        not mix, so the same matrix serves R, G and B. With ``lum_i`` the
        emitted luminance of every powered projector (``response(frame)`` times the
        per-channel white point and lamp, :meth:`sim.room.Room.emission_gains`; the
        hot spot and vignetting are in the matrix),
        ``Room.render_linear()[..., c].ravel() == sum_i transport_i @ lum_i[..., c].ravel()``.
        Current occluders and the exposure are included.

        Returns
        -------
        scipy.sparse.csr_matrix (H*W, w*h) float32
        """
        room = self._room
        with room.lock:
            spec = room.projector(slot)
            cam = room.scene.camera(camera)
            W, H = cam.size
            w, h = spec.size
            view = self._view(camera)
            dyn = room.dynamic_state(view)
            plan = view.plans[slot]
            x0, y0, x1, y1 = view.roi
            wr = x1 - x0
            rows_all, cols_all, vals_all = [], [], []
            local = np.arange(view.shape[0] * view.shape[1])
            cam_index = (y0 + local // wr) * W + (x0 + local % wr)
            blocked = dyn.blocked.get(slot)
            for level in plan.coef:
                c = plan.coef_2d(level).reshape(-1).copy()
                if blocked is not None and len(blocked):
                    c[blocked] = 0.0
                if len(dyn.hand_roi):
                    c[dyn.hand_roi] = 0.0
                r, cidx, v = _entries(plan.mapx.reshape(-1), plan.mapy.reshape(-1), c, plan.sigmas[level], plan.upsample, plan.pad, (w, h))
                rows_all.append(cam_index[r])
                cols_all.append(cidx)
                vals_all.append(v)
            if len(dyn.hand_index):
                hs = room.occluder_samples(view, dyn, slot)
                for level, c in hs.coef.items():
                    r, cidx, v = _entries(hs.mapx.reshape(-1), hs.mapy.reshape(-1), c, plan.sigmas[level], plan.upsample, plan.pad, (w, h))
                    rows_all.append(dyn.hand_index[r])
                    cols_all.append(cidx)
                    vals_all.append(v)
            scale = cam.gain * cam.exposure
            rows = np.concatenate(rows_all) if rows_all else np.zeros(0, np.int64)
            cols = np.concatenate(cols_all) if cols_all else np.zeros(0, np.int64)
            vals = (np.concatenate(vals_all) if vals_all else np.zeros(0)) * scale
            m = scipy.sparse.coo_matrix((vals.astype(np.float32), (rows, cols)), shape=(H * W, w * h))
            return m.tocsr()


def _entries(mapx: np.ndarray, mapy: np.ndarray, coef: np.ndarray, sigma: float, upsample: int, pad: int, size: tuple[int, int]):
    """Sparse entries (row, column, value) of one blur level's sampling, as ``cv2.remap`` reads the field."""
    nz = np.flatnonzero(coef)
    if len(nz) == 0:
        return nz, nz, np.zeros(0)
    s = upsample
    ix, fx = remap_fractions(mapx[nz])
    iy, fy = remap_fractions(mapy[nz])
    qx, rx = np.divmod(ix - pad, s)
    qy, ry = np.divmod(iy - pad, s)
    dj_min, table = sample_weights_1d(sigma, upsample=s)
    wx = (1.0 - fx)[:, None] * table[rx, 0] + fx[:, None] * table[rx, 1]  # (n, nd)
    wy = (1.0 - fy)[:, None] * table[ry, 0] + fy[:, None] * table[ry, 1]
    c = coef[nz].astype(np.float64)
    w, h = size
    rows, cols, vals = [], [], []
    nd = table.shape[2]
    for b in range(nd):
        col_y = qy + dj_min + b
        oky = (col_y >= 0) & (col_y < h) & (wy[:, b] != 0)
        if not oky.any():
            continue
        for a in range(nd):
            col_x = qx + dj_min + a
            ok = oky & (col_x >= 0) & (col_x < w) & (wx[:, a] != 0)
            if not ok.any():
                continue
            rows.append(nz[ok])
            cols.append(col_y[ok] * w + col_x[ok])
            vals.append(c[ok] * wx[ok, a] * wy[ok, b])
    if not rows:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    return np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
