"""The blend's captures: spatially multiplexed blobs, so that the capture count barely grows with N.

Sites lie on a lattice over the part of the camera image the surface fills (``spacing`` camera
pixels apart). Each site can be lit by the projectors whose frame holds a disc there; in capture
``k`` it is lit by exactly one of them, ``candidates[(k + offset) mod n]``, with an offset that
varies across the lattice (``3 ix + 7 iy``) so that each projector's sites spread over its
footprint in every capture. Every projector draws, in its own pixels, a white disc of ``radius``
camera pixels (through the calibrated camera -> projector mapping and its local scale) at each
site it owns: blobs of different projectors never overlap in the camera, because they sit on
distinct sites. A capture therefore samples every projector at once; the plan takes the fewest
captures that give every projector ``samples`` sites (or every site each of its candidates).

With N projectors all covering a surface of ``M`` sites, each gets ``M / N`` per capture, so the
capture count is about ``N samples / M``: at the room's camera, 1 capture for 1 projector and 4
for 25 (plus one black capture either way).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from imaging.blending.contributions import projector_mapper
from imaging.blending.errors import BlendError

__all__ = ["SamplePlan", "plan_samples", "default_blob", "draw_discs"]


def default_blob(camera_size: tuple[int, int]) -> tuple[float, float]:
    """``(radius, spacing)`` in camera pixels for a camera of ``(W, H)``: discs wide enough that the lens's
    blur leaves their centre at full level, and a lattice whose neighbours' blur does not reach it."""
    W, H = camera_size
    radius = max(4.0, min(W, H) / 80.0)
    return radius, 2.0 * radius + max(4.0, radius * 0.8)


def _local_scale(f, points: np.ndarray, e: float = 1.0) -> np.ndarray:
    """Projector pixels per camera pixel around each point (square root of the Jacobian's determinant of
    ``f``, camera -> projector pixels)."""
    c = f(points)
    dx = f(points + [e, 0.0]) - c
    dy = f(points + [0.0, e]) - c
    det = np.abs(dx[..., 0] * dy[..., 1] - dx[..., 1] * dy[..., 0]) / (e * e)
    return np.sqrt(det)


def draw_discs(size: tuple[int, int], centres: np.ndarray, radii: np.ndarray, *, level: int = 255) -> np.ndarray:
    """``(h, w) uint8``: black with a filled disc of ``radii[k]`` projector pixels at each of ``centres`` ((n, 2))."""
    W, H = size
    out = np.zeros((H, W), np.uint8)
    for (cx, cy), r in zip(np.asarray(centres, np.float64), np.asarray(radii, np.float64)):
        x0, x1 = max(int(math.floor(cx - r)), 0), min(int(math.ceil(cx + r)), W - 1)
        y0, y1 = max(int(math.floor(cy - r)), 0), min(int(math.ceil(cy + r)), H - 1)
        if x1 < x0 or y1 < y0:
            continue
        ys, xs = np.mgrid[y0:y1 + 1, x0:x1 + 1]
        inside = (xs - cx) ** 2 + (ys - cy) ** 2 <= r * r
        out[y0:y1 + 1, x0:x1 + 1][inside] = level
    return out


@dataclass(frozen=True, eq=False)
class SamplePlan:
    """Which projector lights which site in which capture.

    Attributes
    ----------
    sites : (M, 2) float64
        Site centres, camera pixels.
    radius : float
        Disc radius in camera pixels.
    owner : (K, M) int32
        ``owner[k, j]``: index into ``slots`` of the projector that lights site ``j`` in capture ``k``, -1 none.
    slots : list of str
    projector_xy : dict slot -> (M, 2) float64
        Each site in the slot's projector pixels.
    projector_radius : dict slot -> (M,) float64
        The disc's radius there, in the slot's projector pixels.
    projector_size : dict slot -> (W, H)
    candidates : (M,) int
        How many projectors can light each site.
    """

    sites: np.ndarray
    radius: float
    owner: np.ndarray
    slots: list[str]
    projector_xy: dict[str, np.ndarray]
    projector_radius: dict[str, np.ndarray]
    projector_size: dict[str, tuple[int, int]]
    candidates: np.ndarray

    @property
    def captures(self) -> int:
        """Blob captures (the black one not counted)."""
        return int(self.owner.shape[0])

    def counts(self) -> dict[str, int]:
        """Samples each projector gets over the plan."""
        return {s: int((self.owner == i).sum()) for i, s in enumerate(self.slots)}

    def frames(self, k: int) -> dict[str, np.ndarray]:
        """Capture ``k``'s frame for every projector: ``(h, w) uint8`` in its pixels (black where it owns no site)."""
        out = {}
        for i, s in enumerate(self.slots):
            j = np.flatnonzero(self.owner[k] == i)
            out[s] = draw_discs(self.projector_size[s], self.projector_xy[s][j], self.projector_radius[s][j])
        return out


def plan_samples(camera_size: tuple[int, int], camera_to_projector: Mapping[str, np.ndarray],
                 projector_size: Mapping[str, tuple[int, int]], *, surface: np.ndarray | None = None,
                 radius: float | None = None, spacing: float | None = None, samples: int = 48,
                 max_captures: int = 64) -> SamplePlan:
    """The multiplexed blob plan (see the module docstring).

    Parameters
    ----------
    camera_size : (W, H)
    camera_to_projector : slot -> (3, 3) float64 homography (full-camera pixels -> projector pixels), or
        (h, w, 2) projector coordinates on a grid over the camera image (a mesh rig)
    projector_size : slot -> (W, H)
    surface : (h, w) bool, optional
        Where the surface is, on any grid over the camera image (default: everywhere).
    radius, spacing : camera pixels (default: :func:`default_blob`)
    samples : int
        Sites each projector should get.
    max_captures : int
    """
    W, H = (int(v) for v in camera_size)
    slots = list(camera_to_projector)
    if not slots:
        raise BlendError("no projector to sample")
    r0, sp0 = default_blob((W, H))
    radius = float(r0 if radius is None else radius)
    spacing = float(sp0 if spacing is None else spacing)
    if not (1.0 <= radius <= min(W, H) / 4):
        raise BlendError(f"blob radius must be 1..{min(W, H) / 4:g} camera pixels, got {radius:g}")
    if spacing < 2 * radius + 2:
        raise BlendError(f"blob spacing {spacing:g} px must be at least 2 x radius + 2 = {2 * radius + 2:g} px "
                         "so that blobs never touch")
    nx = max(int((W - 2 * radius) // spacing), 1)
    ny = max(int((H - 2 * radius) // spacing), 1)
    x0 = (W - 1 - (nx - 1) * spacing) / 2
    y0 = (H - 1 - (ny - 1) * spacing) / 2
    iy, ix = np.mgrid[0:ny, 0:nx]
    sites = np.stack([x0 + ix * spacing, y0 + iy * spacing], axis=-1).reshape(-1, 2)
    ix, iy = ix.reshape(-1), iy.reshape(-1)
    if surface is not None:
        surf = np.asarray(surface, bool)
        sh, sw = surf.shape
        ok = np.ones(len(sites), bool)
        for ox, oy in ((0, 0), (radius + 1, 0), (-radius - 1, 0), (0, radius + 1), (0, -radius - 1)):
            gx = np.clip(((sites[:, 0] + ox + 0.5) * sw / W).astype(np.int64), 0, sw - 1)
            gy = np.clip(((sites[:, 1] + oy + 0.5) * sh / H).astype(np.int64), 0, sh - 1)
            ok &= surf[gy, gx]
        sites, ix, iy = sites[ok], ix[ok], iy[ok]
    pxy, prad, fits = {}, {}, []
    for s in slots:
        f = projector_mapper(camera_to_projector[s], (W, H))
        pw, ph = (int(v) for v in projector_size[s])
        u = f(sites[:, None, :])[:, 0]
        rad = radius * _local_scale(f, sites[:, None, :])[:, 0]
        inside = np.isfinite(u).all(axis=1) & (u[:, 0] - rad >= 0.5) & (u[:, 0] + rad <= pw - 1.5) \
            & (u[:, 1] - rad >= 0.5) & (u[:, 1] + rad <= ph - 1.5) & np.isfinite(rad)
        pxy[s], prad[s] = u, rad
        fits.append(inside)
    fit = np.stack(fits, axis=1)  # (M, N)
    keep = fit.any(axis=1)
    sites, ix, iy, fit = sites[keep], ix[keep], iy[keep], fit[keep]
    for s in slots:
        pxy[s], prad[s] = pxy[s][keep], prad[s][keep]
    if not len(sites):
        raise BlendError("no blob site lies inside a projector's frame on the surface the camera sees: "
                         "check the calibration and the camera's view")
    cand = [np.flatnonzero(row) for row in fit]
    n = np.array([len(cj) for cj in cand])
    offset = 3 * ix + 7 * iy
    most = int(n.max())
    owner_rows = []
    counts = np.zeros(len(slots), np.int64)
    reachable = fit.sum(axis=0)
    for k in range(min(most, max_captures)):
        row = np.array([cj[(k + o) % len(cj)] for cj, o in zip(cand, offset)], np.int32)
        owner_rows.append(row)
        counts += np.bincount(row, minlength=len(slots))
        if np.all(counts >= np.minimum(samples, reachable)):
            break
    return SamplePlan(sites=sites, radius=radius, owner=np.stack(owner_rows), slots=slots, projector_xy=pxy,
                      projector_radius=prad, projector_size={s: tuple(int(v) for v in projector_size[s]) for s in slots},
                      candidates=n.astype(np.int32))
