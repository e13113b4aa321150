"""The light transport and the solve's weights in texture space (a mesh rig), from the texel maps of
:mod:`imaging.compensation.texture_space`.

On a table one homography places every content pixel in the camera; on a mesh each texel has its
own camera position (:class:`~imaging.compensation.texture_space.TexelMap`), or none when the
camera does not see it. Here:

* the window structure of ``L`` (:func:`texel_windows`): the planar layout of
  :mod:`imaging.compensation.transport` (a ``(2R+1)^2`` window per content pixel, row-major
  offsets), centred on each seen texel's rounded camera position; texels the camera does not
  see get no window (an empty column);
* dot-grid separation (:class:`TexelGrid`, :func:`dot_conflicts`, :func:`schedule_dots`): a uv
  layout does not keep texels evenly spaced in the camera (the surface turns away from it, chart
  seams put texels far apart in the texture side by side on the object), so the grid's spacing
  may differ along u and v, and the dots of a grid pattern whose windows would overlap in the
  camera (found by a k-d tree; in any of them when several cameras measure together, where a pair
  counts only when one of the two has a window in that camera) move to extra patterns, greedily,
  each to the first pattern where no dot near it in the camera is lit (:class:`TexelSchedule`):
  every seen texel is measured, in a number of patterns set by the geometry, not by the projectors;
* texels too large for their window (:func:`texel_extent`: where the uv map stretches a texel over
  more camera pixels than the window holds) are left out too: their light would be cut;
* the recovery from the captures (:func:`texel_transport_from_captures`);
* the PSF radius's scales (:func:`view_scales`) and the solve's row weights
  (:func:`row_weights`): a camera pixel's squared residual weighs ``cos(theta)``, how squarely
  the camera sees the surface there, normalised to a median of 1; pixels off the mesh, seen at
  grazing angles (``cos < min_cos``), within the window radius of a silhouette or of a seen
  texel missing from ``L``, or over a texel missing from ``L`` weigh 0. The weight is per
  camera pixel, as the captured quality is scored: a texel the camera magnifies counts with all
  its pixels, since the blur's error inside it is what the camera (and a viewer near it) sees;
* quality over a mask (:func:`masked_quality`): PSNR and SSIM over the visible surface only.
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np
import scipy.sparse as sp
from scipy import ndimage
from scipy.spatial import cKDTree
from skimage.metrics import structural_similarity

from imaging.channel_mean import channel_mean
from imaging.compensation.errors import CompensationError
from imaging.compensation.psf_tails import smooth_tails
from imaging.compensation.texture_space import DeviceView, texels_per_pixel
from imaging.compensation.transport import assemble_transport

__all__ = ["TexelGrid", "TexelSchedule", "texel_windows", "dot_conflicts", "schedule_dots",
           "texel_transport_from_captures", "view_scales", "row_weights", "masked_quality", "ring_energy",
           "measured_texels", "texel_extent"]

class TexelGrid:
    """Shifted dot grids in texture space with spacings ``sx`` (along x, u) and ``sy`` (along y, v).

    Pattern ``k = ty * sx + tx`` (``0 <= k < sx * sy``) lights every texel ``(x, y)`` with
    ``x % sx == tx`` and ``y % sy == ty``; together the patterns light every texel once. The
    interface of :class:`imaging.compensation.transport.DotGrid` (``sx == sy`` is that grid).
    """

    def __init__(self, width: int, height: int, sx: int, sy: int) -> None:
        if width < 1 or height < 1 or sx < 1 or sy < 1:
            raise ValueError(f"need a positive size and spacings, got {width}x{height}, {sx}x{sy}")
        self.width, self.height, self.sx, self.sy = int(width), int(height), int(sx), int(sy)

    @property
    def shape(self) -> tuple[int, int]:
        return self.height, self.width

    @property
    def spacing(self) -> list[int]:
        """``[sx, sy]``."""
        return [self.sx, self.sy]

    def __len__(self) -> int:
        return self.sx * self.sy

    def dots(self, k: int) -> np.ndarray:
        """Texel indices ``(D,) int64`` (``y * W + x``) lit by pattern ``k``."""
        if not 0 <= k < len(self):
            raise IndexError(f"pattern {k} out of range 0..{len(self) - 1}")
        xs = np.arange(k % self.sx, self.width, self.sx, dtype=np.int64)
        ys = np.arange(k // self.sx, self.height, self.sy, dtype=np.int64)
        return (ys[:, None] * self.width + xs[None, :]).ravel()

    def pattern(self, k: int, *, value: float = 1.0, dtype=np.float32) -> np.ndarray:
        """Pattern ``k`` as an ``(H, W)`` image of ``dtype``."""
        img = np.zeros(self.width * self.height, dtype=dtype)
        img[self.dots(k)] = value
        return img.reshape(self.height, self.width)


class TexelSchedule:
    """Dot patterns over the texels of a ``width`` x ``height`` texture: texel ``i`` is lit by pattern
    ``colour[i]`` alone (-1: never lit, no column in ``L``). The interface of :class:`TexelGrid`;
    ``spacing`` is the grid it started from (:func:`schedule_dots`)."""

    def __init__(self, width: int, height: int, colour: np.ndarray, spacing: Sequence[int]) -> None:
        c = np.asarray(colour, np.int32)
        if c.shape != (int(width) * int(height),) or (c.size and c.min() < -1):
            raise ValueError(f"colour must be ({int(width) * int(height)},) ints >= -1, got {c.shape}")
        self.width, self.height, self.colour = int(width), int(height), c
        self.spacing = [int(v) for v in spacing]
        self._order = np.argsort(c, kind="stable")
        self._starts = np.searchsorted(c[self._order], np.arange(len(self) + 1))

    @property
    def shape(self) -> tuple[int, int]:
        return self.height, self.width

    def __len__(self) -> int:
        return int(self.colour.max()) + 1 if self.colour.size else 0

    @property
    def lit(self) -> np.ndarray:
        """(n,) bool: texels some pattern lights."""
        return self.colour >= 0

    def dots(self, k: int) -> np.ndarray:
        """Texel indices ``(D,) int64`` lit by pattern ``k``."""
        if not 0 <= k < len(self):
            raise IndexError(f"pattern {k} out of range 0..{len(self) - 1}")
        return self._order[self._starts[k]:self._starts[k + 1]].astype(np.int64)

    def pattern(self, k: int, *, value: float = 1.0, dtype=np.float32) -> np.ndarray:
        """Pattern ``k`` as an ``(H, W)`` image of ``dtype``."""
        img = np.zeros(self.width * self.height, dtype=dtype)
        img[self.dots(k)] = value
        return img.reshape(self.height, self.width)


def _crowding_graph(bases: np.ndarray, windows: np.ndarray, presents: np.ndarray, reach: int) -> sp.csr_matrix:
    """Which texels may not share a pattern: ``(n, n)`` symmetric CSR int32, entry ``(i, j)`` the number of
    cameras where both dots' light reaches it (``presents``; only texels with a window somewhere are lit), they
    lie within Chebyshev distance ``reach`` and one of them has a window (``windows`` (K, n)). Two dots of which
    a camera measures neither may overlap in it (at a grazing angle they do): none of their light is recorded
    there, so they need not be apart."""
    n = bases.shape[1]
    lit = windows.any(axis=0)
    rows, cols = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for base, reaches, win in zip(bases, presents, windows):
        ids = np.flatnonzero(reaches & lit)
        if len(ids) < 2:
            continue
        pairs = cKDTree(base[ids].astype(np.float64)).query_pairs(r=reach, p=np.inf, output_type="ndarray")
        pairs = ids[pairs]
        pairs = pairs[win[pairs[:, 0]] | win[pairs[:, 1]]]
        rows += [pairs[:, 0], pairs[:, 1]]
        cols += [pairs[:, 1], pairs[:, 0]]
    r, c = np.concatenate(rows), np.concatenate(cols)
    return sp.csr_matrix((np.ones(len(r), np.int32), (r, c)), shape=(n, n))      # duplicates summed


def _greedy_colours(grid: TexelGrid, lit: np.ndarray, graph: sp.csr_matrix, *, crowded_first: bool = False
                    ) -> np.ndarray:
    """``grid``'s pattern per ``lit`` texel, the dots that crowd another of their pattern (``graph``,
    :func:`_crowding_graph`) moved to the first pattern none of their neighbours has: ``(n,) int32``, -1 never
    lit. The moved dots are coloured in texel order, or with ``crowded_first`` those crowded most first
    (neighbours counted in every camera where they crowd; the largest-first heuristic: fewer patterns where
    several cameras' constraints pile up)."""
    n = len(lit)
    idx = np.arange(n)
    colour = np.full(n, -1, np.int32)
    colour[lit] = ((idx[lit] // grid.width) % grid.sy) * grid.sx + (idx[lit] % grid.width) % grid.sx
    coo = graph.tocoo()
    same = colour[coo.row] == colour[coo.col]
    crowded = np.zeros(n, bool)
    crowded[coo.row[same]] = True
    pending = np.flatnonzero(crowded)
    if not len(pending):
        return colour
    preferred = colour[pending].copy()
    colour[pending] = -2
    if crowded_first:
        order = np.argsort(-np.asarray(graph[pending].sum(axis=1)).ravel(), kind="stable")
    else:
        order = range(len(pending))
    indptr, indices = graph.indptr, graph.indices
    for i in order:
        t, want = pending[i], int(preferred[i])
        used = set(colour[indices[indptr[t]:indptr[t + 1]]].tolist())
        if want in used:
            want = 0
            while want in used:
                want += 1
        colour[t] = want
    return colour


def schedule_dots(base: np.ndarray, seen: np.ndarray, content_shape: Sequence[int], radius: int, *,
                  spacing: int | Sequence[int] | None = None, guard: int = 1, limit: int = 32,
                  present: np.ndarray | None = None) -> TexelSchedule:
    """Dot patterns that measure every seen texel with its ``(2R+1)^2`` window alone (:class:`TexelSchedule`).

    Starting from a grid (``spacing``: ``s`` or ``(sx, sy)``; by default each ``sx`` x ``sy`` near the median
    camera spacing of neighbouring texels, the one with the fewest patterns in the end), the
    dots whose windows would come within ``guard`` px of another dot's of the same pattern move
    greedily to extra patterns (seams, oblique views). Every pattern lights only seen texels.
    With several cameras (``base`` (K, n, 2), ``seen`` (K, n)) one schedule serves them all: every
    camera captures every pattern, and a dot's window stays clear in each camera that sees it,
    also of the dots lit for another camera whose light reaches it (``present`` (K, n): the texels
    whose light reaches each camera, seen or at a grazing angle; default ``seen``; ``base`` must
    hold their positions); two dots of which a camera has no window may crowd in it (their light
    lands on no window: :func:`_crowding_graph`). The grids tried are those near each camera's
    spacing, each coloured in texel order and crowded dots first (:func:`_greedy_colours`).

    Parameters
    ----------
    base : (n, 2) or (K, n, 2) int
        Rounded camera position of each texel (:func:`texel_windows`), per camera.
    seen : (n,) or (K, n) bool
    content_shape : (H, W)

    Raises
    ------
    CompensationError
        When the camera sees no texel.
    """
    h, w = int(content_shape[0]), int(content_shape[1])
    seens = np.asarray(seen, bool)
    bases = np.asarray(base)
    if seens.ndim == 1:
        seens, bases = seens[None], bases[None]
    presents = seens if present is None else np.asarray(present, bool).reshape(seens.shape) | seens
    if bases.shape != (len(seens), h * w, 2) or seens.shape != (len(bases), h * w):
        raise ValueError(f"base must be ([K,] {h * w}, 2) and seen ([K,] {h * w},), got {np.shape(base)}, "
                         f"{np.shape(seen)}")
    if not seens.any():
        raise CompensationError("the camera sees no texel of the mesh: check the camera's pose (calibration)")
    if guard < 0:
        raise ValueError(f"guard must be >= 0, got {guard}")
    reach = 2 * int(radius) + guard
    if spacing is not None:
        sx, sy = (spacing, spacing) if np.isscalar(spacing) else spacing
        candidates = [(int(sx), int(sy))]
    else:
        found = set()
        for b, s in zip(bases, seens):
            if not s.any():
                continue
            pos = b.reshape(h, w, 2).astype(np.float64)
            ok = s.reshape(h, w)
            steps = []
            for axis in (1, 0):                                  # along x (u), then along y (v)
                a = [slice(None)] * 2
                c = [slice(None)] * 2
                a[axis], c[axis] = slice(1, None), slice(None, -1)
                both = ok[tuple(a)] & ok[tuple(c)]
                d = np.abs(pos[tuple(a)] - pos[tuple(c)]).max(axis=2)[both]
                steps.append(float(np.median(d)) if d.size else 1.0)
            s0 = [min(limit, max(1, math.ceil((reach + 1) / max(st, 0.5)))) for st in steps]
            found |= {(min(limit, max(1, s0[0] + dx)), min(limit, max(1, s0[1] + dy)))
                      for dx in (-1, 0, 1) for dy in (-1, 0, 1)}
        candidates = sorted(found)
    graph = _crowding_graph(bases, seens, presents, reach)
    lit = seens.any(axis=0)
    best: TexelSchedule | None = None
    for sx, sy in candidates:
        for crowded_first in (False, True):
            colour = _greedy_colours(TexelGrid(w, h, sx, sy), lit, graph, crowded_first=crowded_first)
            sched = TexelSchedule(w, h, colour, (sx, sy))
            if best is None or len(sched) < len(best):
                best = sched
    return best


def texel_windows(position: np.ndarray, seen: np.ndarray, camera_shape: Sequence[int],
                  radius: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The window structure of a mesh rig's ``L`` in one camera.

    Parameters
    ----------
    position : (n, 2) float
        Camera position ``(X, Y)`` of each texel (NaN allowed where not ``seen``).
    seen : (n,) bool
        Texels that get a window.
    camera_shape : (Hc, Wc)
    radius : int

    Returns
    -------
    base : (n, 2) int64
        Rounded camera position of each texel (0 where not seen).
    rows : (n, K) int32
        Camera pixel of each window entry, ``K = (2R+1)^2`` row-major over ``(dy, dx)``.
    valid : (n, K) bool
        Entries inside the image, of seen texels.
    """
    hc, wc = int(camera_shape[0]), int(camera_shape[1])
    pos = np.asarray(position, np.float64)
    seen = np.asarray(seen, bool)
    if pos.ndim != 2 or pos.shape[1] != 2 or seen.shape != (len(pos),):
        raise ValueError(f"position must be (n, 2) and seen (n,), got {pos.shape}, {seen.shape}")
    if radius < 0:
        raise ValueError(f"radius must be >= 0, got {radius}")
    b = np.where(seen[:, None], np.nan_to_num(np.rint(pos)), 0).astype(np.int64)
    offs = np.arange(-radius, radius + 1, dtype=np.int64)
    dy = np.repeat(offs, 2 * radius + 1)
    dx = np.tile(offs, 2 * radius + 1)
    X = b[:, :1] + dx[None, :]
    Y = b[:, 1:] + dy[None, :]
    valid = seen[:, None] & (X >= 0) & (X < wc) & (Y >= 0) & (Y < hc)
    rows = (np.clip(Y, 0, hc - 1) * wc + np.clip(X, 0, wc - 1)).astype(np.int32)
    return b, rows, valid


def dot_conflicts(grid: TexelGrid, base: np.ndarray, seen: np.ndarray, radius: int, *, guard: int = 0) -> np.ndarray:
    """Seen texels whose window would share camera pixels (plus ``guard``) with another dot of their pattern.

    ``base``: rounded camera positions (:func:`texel_windows`). Returns ``(n,) bool``.
    """
    out = np.zeros(len(base), bool)
    reach = 2 * radius + guard            # Chebyshev distance below 2R+1+guard: the windows touch
    for k in range(len(grid)):
        dots = grid.dots(k)
        dots = dots[seen[dots]]
        if len(dots) < 2:
            continue
        pairs = cKDTree(base[dots].astype(np.float64)).query_pairs(r=reach, p=np.inf, output_type="ndarray")
        if len(pairs):
            out[dots[pairs.ravel()]] = True
    return out


def texel_transport_from_captures(captures: Iterable[np.ndarray], black: np.ndarray, *, grid: TexelGrid,
                                  rows: np.ndarray, valid: np.ndarray, dot_value: float = 1.0, core: int | None = None,
                                  radius: int | None = None) -> sp.csr_matrix:
    """A mesh rig's ``L`` in one camera from dot-grid captures: ``(Hc*Wc, W*H) float32`` CSR.

    As :func:`imaging.compensation.transport.transport_from_captures` (the channel mean of
    ``capture - black`` inside each dot's window, negatives clipped, divided by ``dot_value``),
    with the window structure of :func:`texel_windows` (texels left out: ``valid`` all False). With
    ``core`` below the windows' ``radius``, the entries beyond it are first averaged over neighbouring texels
    (:func:`~imaging.compensation.psf_tails.smooth_tails`, within each camera of a stacked image).

    Parameters
    ----------
    captures : iterable of (Hc, Wc, C) float32, one per pattern of ``grid`` in order
    black : (Hc, Wc, C) float32
    rows, valid : (W*H, K)
    """
    b = channel_mean(black)
    camera_shape = b.shape
    if rows.shape != valid.shape or rows.shape[0] != grid.width * grid.height:
        raise ValueError(f"rows {rows.shape} and valid {valid.shape} must be ({grid.width * grid.height}, K)")
    if dot_value <= 0:
        raise ValueError(f"dot_value must be positive, got {dot_value}")
    values = np.zeros(rows.shape, np.float32)
    count = 0
    for k, capture in enumerate(captures):
        if k >= len(grid):
            raise ValueError(f"got more than the {len(grid)} captures the dot grid needs")
        img = channel_mean(capture)
        if img.shape != camera_shape:
            raise ValueError(f"capture {k} has shape {img.shape}, the black capture {camera_shape}")
        diff = (img - b).reshape(-1)
        dots = grid.dots(k)
        values[dots] = diff[rows[dots]]
        count += 1
    if count != len(grid):
        raise ValueError(f"the dot grid needs {len(grid)} captures, got {count}")
    if dot_value != 1.0:
        values /= np.float32(dot_value)
    if core is not None:
        if radius is None:
            raise ValueError("averaging the tails beyond the core needs the windows' radius")
        smooth_tails(values, rows, valid, camera_width=camera_shape[1], radius=radius, core=core)
    np.maximum(values, 0, out=values)
    values[~valid] = 0
    return assemble_transport(values, rows, valid, camera_shape)


def view_scales(camera: DeviceView, projectors: Sequence[DeviceView]) -> tuple[float, float]:
    """Median scales on the surface: ``c`` camera px per texel and ``p`` camera px per projector px
    (for :func:`imaging.compensation.geometry.psf_radius_at_scales`)."""
    a_cam = texels_per_pixel(camera)
    a_cam = a_cam[camera.on_mesh & np.isfinite(a_cam) & (a_cam > 0)]
    if a_cam.size == 0:
        raise CompensationError("the camera sees none of the mesh: check the camera's pose (calibration)")
    c = float(1.0 / np.sqrt(np.median(a_cam)))
    ratios = []
    for v in projectors:
        a = texels_per_pixel(v)
        a = a[v.on_mesh & np.isfinite(a) & (a > 0)]
        if a.size:
            ratios.append(c * float(np.sqrt(np.median(a))))     # texel px per projector px, times c
    return c, float(np.median(ratios)) if ratios else c


def row_weights(view: DeviceView, measured: np.ndarray, content_size: tuple[int, int], *, radius: int,
                min_cos: float = 0.25, unmeasured_at: np.ndarray | None = None, normalise: bool = True) -> np.ndarray:
    """The weight of each camera pixel's squared residual in the solve: ``(Hc, Wc) float32`` (see the module
    docstring), 0 outside the visible surface the solve uses; ``normalise=False``: ``cos``, not divided by
    its median (cameras combined share one divisor).

    ``measured``: (W*H,) bool texels with a column in ``L``. A pixel counts when it sees the mesh
    at ``cos >= min_cos`` more than ``radius`` px from the outline of that region (light from the
    texels beyond it, unmeasured, reaches that far), its nearest texel is measured, and no texel
    of ``unmeasured_at`` ((m, 2) camera positions of texels the camera sees but ``L`` lacks) lies
    within ``radius`` px (Chebyshev), and the texture area it covers is defined (none across a uv seam).
    """
    cw, ch = content_size
    good = view.on_mesh & (view.cos >= min_cos)
    good = ndimage.binary_erosion(good, structure=np.ones((3, 3), bool), iterations=radius, border_value=0)
    x, y = np.rint(np.nan_to_num(view.x, nan=-10.0)), np.rint(np.nan_to_num(view.y, nan=-10.0))
    inside = (x >= 0) & (x < cw) & (y >= 0) & (y < ch)
    m = np.asarray(measured, bool).reshape(ch, cw)
    good &= inside & m[np.clip(y, 0, ch - 1).astype(np.int64), np.clip(x, 0, cw - 1).astype(np.int64)]
    if unmeasured_at is not None and len(unmeasured_at):
        hc, wc = view.shape
        pts = np.rint(np.asarray(unmeasured_at, np.float64))
        pts = pts[np.isfinite(pts).all(axis=1)].astype(np.int64)
        pts = pts[(pts[:, 0] >= 0) & (pts[:, 0] < wc) & (pts[:, 1] >= 0) & (pts[:, 1] < hc)]
        near = np.zeros(view.shape, bool)
        near[pts[:, 1], pts[:, 0]] = True
        good &= ~ndimage.binary_dilation(near, structure=np.ones((2 * radius + 1, 2 * radius + 1), bool))
    area = texels_per_pixel(view)
    good &= np.isfinite(area) & (area > 0)
    w = np.zeros(view.shape, np.float32)
    if not good.any():
        raise CompensationError("no camera pixel sees the measured surface well: check the camera's pose and the "
                                "light-transport measurement")
    raw = view.cos[good].astype(np.float32)
    w[good] = raw / np.float32(np.median(raw)) if normalise else raw
    return w


def masked_quality(target: np.ndarray, captured: np.ndarray, mask: np.ndarray) -> dict[str, float]:
    """PSNR and SSIM (data range 1) of ``captured`` against ``target`` over the pixels of ``mask`` only.

    ``target``, ``captured``: ``(H, W, C)`` float; ``captured`` is clipped to [0, 1]. Outside
    the mask the captured image is replaced by the target, so SSIM's 7x7 windows that straddle
    the mask's edge compare only what lies inside it; SSIM is the mean of its map over the mask.
    Returns ``{"psnr", "ssim", "pixels"}``.
    """
    t = np.asarray(target, np.float64)
    c = np.clip(np.asarray(captured, np.float64), 0.0, 1.0)
    m = np.asarray(mask, bool)
    if t.shape != c.shape or t.shape[:2] != m.shape:
        raise ValueError(f"target {t.shape}, captured {c.shape} and mask {m.shape} must match")
    if not m.any():
        raise ValueError("the mask is empty")
    c = np.where(m[:, :, None] if c.ndim == 3 else m, c, t)
    mse = float(np.mean((t[m] - c[m]) ** 2))
    psnr = float("inf") if mse == 0 else float(10 * np.log10(1.0 / mse))
    _, smap = structural_similarity(t, c, data_range=1.0, channel_axis=2 if t.ndim == 3 else None, full=True)
    if smap.ndim == 3:
        smap = smap.mean(axis=2)
    return {"psnr": round(psnr, 3), "ssim": round(float(smap[m].mean()), 4), "pixels": int(m.sum())}


def ring_energy(L: sp.spmatrix, base: np.ndarray, camera_width: int, radius: int) -> float:
    """Share of ``L``'s squared entries on the outer ring of their windows (centred on ``base``, (n, 2)):
    :func:`imaging.compensation.geometry.edge_energy` for windows placed per texel."""
    csc = sp.csc_matrix(L)
    cols = np.repeat(np.arange(csc.shape[1]), np.diff(csc.indptr))
    rows = csc.indices.astype(np.int64)
    dx = rows % int(camera_width) - base[cols, 0]
    dy = rows // int(camera_width) - base[cols, 1]
    ring = (np.abs(dx) == radius) | (np.abs(dy) == radius)
    v = csc.data.astype(np.float64) ** 2
    total = float(v.sum())
    return float(v[ring].sum()) / total if total > 0 else 0.0


def measured_texels(L: sp.spmatrix) -> np.ndarray:
    """``(n_content,) bool``: texels with a window in ``L`` (a non-empty column)."""
    return np.diff(sp.csc_matrix(L).indptr) > 0


def texel_extent(position: np.ndarray, content_shape: Sequence[int]) -> np.ndarray:
    """How far a texel's light reaches in the camera: ``(n,) float64``, the largest Chebyshev camera distance
    (px) from its centre to its 8 neighbours' (a node's bilinear lookup spreads a texel over its
    neighbours' span). NaN where the texel has no position; neighbours without one are skipped.
    A uv map that stretches texels on the surface (a cylindrical map near its poles) makes it large.
    """
    h, w = int(content_shape[0]), int(content_shape[1])
    pos = np.asarray(position, np.float64).reshape(h, w, 2)
    pad = np.full((h + 2, w + 2, 2), np.nan)
    pad[1:-1, 1:-1] = pos
    out = np.full((h, w), -np.inf)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dx == dy == 0:
                continue
            d = np.abs(pad[1 + dy:h + 1 + dy, 1 + dx:w + 1 + dx] - pos).max(axis=2)
            out = np.fmax(out, d)
    out[~np.isfinite(pos).all(axis=2)] = np.nan
    out[np.isneginf(out)] = 0.0
    return out.reshape(-1)
