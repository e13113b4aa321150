"""The constant-capture calibration mode: every projector shows its patterns at
the same time, multiplexed so that each projector's contribution can be told apart.

Why not interleave markers in projector space? In a synthetic-aperture rig
every projector covers the whole table, but from a different place: the same
normalised projector position lands up to hundreds of millimetres apart on the
table for a corner and a centre unit (keystone). Before calibration nobody
knows where a projector's pixels land, so any dense pattern overlaps every
other projector's. Two stages avoid that:

**Stage 1 - coded dots (coarse).** Every projector shows a few small square
dots at random, well-spread places (one per cell of a jittered grid over its
image). Each dot carries a ``bits``-long code naming its projector and its
index: capture ``2k`` shows the dots whose code has bit ``k`` set, capture
``2k + 1`` the others, so every dot is lit in exactly one capture of each pair
and decodes against itself (no threshold). Dots of different projectors that
happen to land on each other are caught: such a blob is lit in both captures
of some pair. With the codes shared out between the projectors
(``dots per projector = 2**bits / N``, capped), the number of captures is
``2 bits`` whatever N is (``bits`` grows as log2 N beyond ~50 projectors).
A robust homography through a projector's decoded dots gives its coarse pose
(typically sub-pixel already). Projectors left with too few dots (rare bad
luck with overlaps) get a retry round of their own.

**Stage 2 - interleaved lattice (refine).** With every projector's coarse
table -> projector mapping known, sites on a lattice over the table are shared
out between the projectors (site (a, b) belongs to projector
``(a + q b + shift) mod N``, with ``q`` chosen so each projector's sites are
spread evenly) and every projector draws a dot exactly where its coarse pose
puts its sites. Dots of different projectors now land a lattice step apart by
construction, so one capture measures every projector's dots at once; a few
rounds with shifted lattices give each projector ~100+ dots. Each dot's camera
centroid (background-subtracted, iterated, sub-pixel) and its exact projector
centre form a correspondence; a robust homography through them is the
refined camera -> projector mapping.

Captures for the whole rig: 1 dark + ``2 bits`` coded + ``rounds`` lattice
(plus a retry round only when stage 1 fails a projector), independent of N up
to the lattice's capacity: a lattice step is a few dot widths in the camera,
so one round holds a few hundred dots over the table; the job adds rounds
only when a projector would get fewer than ~40 dots (beyond ~35 projectors at
the room's default camera resolution), i.e. about one capture per 9 extra
projectors, against 2 log2(w h) + 2 per projector for the sequential mode. Stage 2 doubles as the alignment check: drawing the
lattice through the rig's *current* poses and measuring where the dots land
gives each projector's residual misalignment (:mod:`imaging.calibration.alignment`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from imaging.calibration.graycode import luminance
from imaging.calibration.planar import apply_homography


def _sizes(sizes: dict[str, tuple[int, int]]) -> dict[str, tuple[int, int]]:
    out = {}
    for slot, (w, h) in sizes.items():
        if int(w) < 8 or int(h) < 8:
            raise ValueError(f"projector {slot} is {w}x{h}; need at least 8x8")
        out[slot] = (int(w), int(h))
    if not out:
        raise ValueError("no projectors to calibrate")
    return out


def draw_dots(size: tuple[int, int], centres: np.ndarray, dot_px: int, *, level: int = 255) -> np.ndarray:
    """A black (h, w) uint8 image with a ``dot_px`` x ``dot_px`` square at each centre.

    Parameters
    ----------
    centres : (M, 2) float64
        Dot centres in projector pixels; with ``dot_px`` odd they must be
        integers, with ``dot_px`` even half-integers (the square covers pixels
        ``centre - (dot_px - 1) / 2 ... centre + (dot_px - 1) / 2``).
    """
    w, h = size
    img = np.zeros((h, w), np.uint8)
    c = np.asarray(centres, np.float64).reshape(-1, 2)
    if len(c) == 0:
        return img
    x0 = np.rint(c[:, 0] - (dot_px - 1) / 2.0).astype(np.int64)
    y0 = np.rint(c[:, 1] - (dot_px - 1) / 2.0).astype(np.int64)
    for dy in range(dot_px):
        for dx in range(dot_px):
            xs, ys = x0 + dx, y0 + dy
            ok = (xs >= 0) & (xs < w) & (ys >= 0) & (ys < h)
            img[ys[ok], xs[ok]] = level
    return img


def snap_centre(xy: np.ndarray, dot_px: int) -> np.ndarray:
    """Nearest valid dot centre: integers for odd ``dot_px``, half-integers for even."""
    xy = np.asarray(xy, np.float64)
    off = 0.5 if dot_px % 2 == 0 else 0.0
    return np.floor(xy - off + 0.5) + off


# ---------------------------------------------------------------------- stage 1: coded dots
@dataclass(frozen=True, eq=False)
class CodedDots:
    """The stage-1 plan.

    Attributes
    ----------
    slots : tuple of str
    sizes : dict slot -> (w, h)
    bits : int
        Code length; the stage takes ``2 * bits`` captures.
    dot_px : int
    centres : dict slot -> (D, 2) float64 projector dot centres
    codes : dict slot -> (D,) int64
    """

    slots: tuple[str, ...]
    sizes: dict[str, tuple[int, int]]
    bits: int
    dot_px: int
    centres: dict[str, np.ndarray]
    codes: dict[str, np.ndarray]

    @property
    def captures(self) -> int:
        return 2 * self.bits

    def frames(self, index: int) -> dict[str, np.ndarray]:
        """Projector images of capture ``index`` (0 .. 2 bits - 1): (h, w) uint8 per slot."""
        if not 0 <= index < self.captures:
            raise ValueError(f"capture index {index} outside 0..{self.captures - 1}")
        k, inverse = divmod(index, 2)
        out = {}
        for s in self.slots:
            on = ((self.codes[s] >> (self.bits - 1 - k)) & 1).astype(bool)
            if inverse:
                on = ~on
            out[s] = draw_dots(self.sizes[s], self.centres[s][on], self.dot_px)
        return out


def plan_coded_dots(sizes: dict[str, tuple[int, int]], *, bits: int | None = None, max_dots: int = 48,
                    min_dots: int = 20, dot_px: int = 1, seed: int = 0) -> CodedDots:
    """Place each projector's coded dots (stage 1).

    Parameters
    ----------
    sizes : dict slot -> (w, h)
    bits : int, optional
        Code length; default ``max(10, ceil(log2(N * min_dots)))``.
    max_dots, min_dots : int
        Dots per projector: ``min(max_dots, 2**bits // N)``, at least ``min_dots``.
    dot_px : int
        Side of a dot in projector pixels.
    seed : int
        Dot positions are a jittered grid, jittered by a generator seeded from
        ``seed`` and the slot's position in ``sizes``.
    """
    sizes = _sizes(sizes)
    slots = tuple(sizes)
    n = len(slots)
    if bits is None:
        bits = max(10, math.ceil(math.log2(n * min_dots)))
    per = min(max_dots, (1 << bits) // n)
    if per < min(min_dots, 4):
        raise ValueError(f"{bits} code bits leave {per} dots for each of {n} projectors; use more bits")
    rng = np.random.default_rng(seed)
    codes_all = rng.permutation(1 << bits)[: per * n].astype(np.int64)   # spread codes over the code space
    centres, codes = {}, {}
    margin = dot_px + 1
    for i, s in enumerate(slots):
        w, h = sizes[s]
        aspect = (w - 2 * margin) / max(h - 2 * margin, 1)
        gx = max(1, round(math.sqrt(per * aspect)))
        gy = max(1, math.ceil(per / gx))
        cells = np.array([(cx, cy) for cy in range(gy) for cx in range(gx)], np.float64)
        cells = cells[np.random.default_rng([seed, i]).permutation(len(cells))[:per]]
        jitter = np.random.default_rng([seed, i, 1]).uniform(0.15, 0.85, (per, 2))
        cw, ch = (w - 2 * margin) / gx, (h - 2 * margin) / gy
        xy = np.column_stack([margin + (cells[:, 0] + jitter[:, 0]) * cw, margin + (cells[:, 1] + jitter[:, 1]) * ch])
        centres[s] = snap_centre(xy, dot_px)
        codes[s] = codes_all[i * per:(i + 1) * per]
    return CodedDots(slots, sizes, bits, dot_px, centres, codes)


@dataclass(frozen=True, eq=False)
class DotMatches:
    """Decoded dots of one projector: camera centroids and the projector centres they belong to."""

    camera: np.ndarray      # (M, 2) float64
    projector: np.ndarray   # (M, 2) float64

    @property
    def count(self) -> int:
        return len(self.camera)


@dataclass(frozen=True, eq=False)
class CodedDecode:
    matches: dict[str, DotMatches]
    blobs: int
    collisions: int
    unknown: int
    noise: float


def _noise_sigma(img: np.ndarray) -> float:
    med = float(np.median(img))
    return float(1.4826 * np.median(np.abs(img - med))) or 1e-6


def _peaks(img: np.ndarray, *, threshold: float, spacing: int) -> np.ndarray:
    """(P, 2) int64 (x, y) local maxima above ``threshold`` at least ``spacing`` apart, away from the border."""
    mx = ndimage.maximum_filter(img, size=2 * spacing + 1, mode="constant", cval=np.inf)
    ys, xs = np.nonzero((img >= mx) & (img > threshold))
    b = spacing + 2
    ok = (xs >= b) & (ys >= b) & (xs < img.shape[1] - b) & (ys < img.shape[0] - b)
    return np.column_stack([xs[ok], ys[ok]]).astype(np.int64)


def _window_offsets(radius: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    r = radius
    dy, dx = np.mgrid[-r - 2: r + 3, -r - 2: r + 3]
    d2 = dx * dx + dy * dy
    inner = d2 <= r * r
    ring = (d2 > (r + 0.5) ** 2) & (d2 <= (r + 2) ** 2)
    return dx[inner], dy[inner], dx[ring], dy[ring]


def centroids(image: np.ndarray, seeds: np.ndarray, *, radius: int, iterations: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel blob centroids near ``seeds``.

    Each blob's background is the median of a ring just outside a disc of
    ``radius`` pixels; the background-subtracted intensities inside the disc
    weigh the pixel centres; the disc is re-centred on the result and the
    step repeated ``iterations`` times.

    Parameters
    ----------
    image : (H, W) float32
    seeds : (P, 2) float64 (x, y) starting points

    Returns
    -------
    xy : (P, 2) float64; NaN where the blob left the image or has no mass
    mass : (P,) float64 background-subtracted sum inside the disc
    """
    img = np.asarray(image, np.float32)
    if img.ndim != 2:
        raise ValueError(f"image must be (H, W), got {img.shape}")
    H, W = img.shape
    xy = np.asarray(seeds, np.float64).reshape(-1, 2).copy()
    mass = np.zeros(len(xy))
    dx, dy, rx, ry = _window_offsets(radius)
    m = radius + 2
    for _ in range(max(1, iterations)):
        fin = np.isfinite(xy).all(axis=1)
        cx = np.rint(np.where(fin[:, None], xy, 0.0)[:, 0]).astype(np.int64)
        cy = np.rint(np.where(fin[:, None], xy, 0.0)[:, 1]).astype(np.int64)
        ok = fin & (cx >= m) & (cy >= m) & (cx < W - m) & (cy < H - m)
        cx, cy = np.where(ok, cx, m), np.where(ok, cy, m)
        vals = img[cy[:, None] + dy[None, :], cx[:, None] + dx[None, :]]
        bg = np.median(img[cy[:, None] + ry[None, :], cx[:, None] + rx[None, :]], axis=1)
        wgt = vals - bg[:, None]
        mass = wgt.sum(axis=1)
        good = ok & (mass > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            nx = cx + (wgt * dx[None, :]).sum(axis=1) / mass
            ny = cy + (wgt * dy[None, :]).sum(axis=1) / mass
        new = np.column_stack([nx, ny])
        new[~good] = np.nan
        # a centroid that jumps out of its disc lost its blob
        jump = np.linalg.norm(new - np.column_stack([cx, cy]), axis=1) > radius
        new[jump] = np.nan
        xy = new
    return xy, mass


def decode_coded_dots(captures: list[np.ndarray], dark: np.ndarray, plan: CodedDots, *, radius: int = 2,
                      min_purity: float = 0.4, threshold_sigma: float = 8.0) -> CodedDecode:
    """Find the coded dots in stage-1 captures and name each one's projector and dot.

    Parameters
    ----------
    captures : list of (H, W) or (H, W, 3) float32
        The ``2 bits`` captures of :meth:`CodedDots.frames`, in order.
    dark : (H, W) or (H, W, 3) float32
        Every projector black.
    radius : int
        Camera-pixel radius of the disc a dot is measured in.
    min_purity : float
        For every bit, ``|on - off| / (on + off)`` must reach this, else the
        blob is two overlapping dots with different codes (rejected).
    threshold_sigma : float
        Blob detection threshold in noise standard deviations.
    """
    if len(captures) != plan.captures:
        raise ValueError(f"expected {plan.captures} captures, got {len(captures)}")
    d = luminance(dark)
    stack = np.stack([luminance(c) - d for c in captures])
    total = stack.reshape(plan.bits, 2, *d.shape).sum(axis=1).mean(axis=0)   # every dot, averaged over the pairs
    smooth = ndimage.gaussian_filter(total, 1.0)
    sigma = _noise_sigma(smooth)
    seeds = _peaks(smooth, threshold=threshold_sigma * sigma, spacing=max(2, radius - 1))
    xy, mass = centroids(total, seeds.astype(np.float64), radius=radius)
    good = np.isfinite(xy).all(axis=1)
    xy, mass = xy[good], mass[good]
    # per-bit on/off sums over the same discs
    dx, dy, rx, ry = _window_offsets(radius)
    cx = np.rint(xy[:, 0]).astype(np.int64)
    cy = np.rint(xy[:, 1]).astype(np.int64)
    code = np.zeros(len(xy), np.int64)
    purity = np.ones(len(xy))
    for k in range(plan.bits):
        sums = []
        for img in (stack[2 * k], stack[2 * k + 1]):
            vals = img[cy[:, None] + dy[None, :], cx[:, None] + dx[None, :]]
            bg = np.median(img[cy[:, None] + ry[None, :], cx[:, None] + rx[None, :]], axis=1)
            sums.append((vals - bg[:, None]).sum(axis=1))
        on, off = sums
        with np.errstate(divide="ignore", invalid="ignore"):
            p = np.abs(on - off) / (np.abs(on) + np.abs(off))
        purity = np.minimum(purity, np.nan_to_num(p, nan=0.0))
        code = (code << 1) | (on > off)
    clean = purity >= min_purity
    lookup = np.full(1 << plan.bits, -1, np.int64)
    base = 0
    for s in plan.slots:
        lookup[plan.codes[s]] = base + np.arange(len(plan.codes[s]))
        base += len(plan.codes[s])
    flat = lookup[code]
    known = clean & (flat >= 0)
    matches = {}
    base = 0
    for s in plan.slots:
        n = len(plan.codes[s])
        sel = known & (flat >= base) & (flat < base + n)
        matches[s] = DotMatches(xy[sel], plan.centres[s][flat[sel] - base])
        base += n
    return CodedDecode(matches, blobs=len(xy), collisions=int((~clean).sum()), unknown=int((clean & (flat < 0)).sum()),
                       noise=sigma)


# ---------------------------------------------------------------------- stage 2: interleaved lattice
def _lattice_multiplier(n: int) -> int:
    """``q`` for which the sites {(a, b): a + q b = i mod n} of one projector are spread most evenly."""
    if n <= 2:
        return 1
    best, best_d = 1, -1.0
    for q in range(1, n):
        if math.gcd(q, n) != 1:
            continue
        d = float(n)
        for b in range(1, n + 1):
            a = (-q * b) % n
            a = a - n if a > n / 2 else a
            d = min(d, math.hypot(a, b))
        if d > best_d:
            best, best_d = q, d
    return best


def local_scale(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Pixels per source unit of ``H`` at ``points`` (N, 2): sqrt of the Jacobian's |determinant|."""
    p = np.asarray(points, np.float64).reshape(-1, 2)
    e = 0.5
    px = apply_homography(H, p + [e, 0]) - apply_homography(H, p - [e, 0])
    py = apply_homography(H, p + [0, e]) - apply_homography(H, p - [0, e])
    det = (px[:, 0] * py[:, 1] - px[:, 1] * py[:, 0]) / (4 * e * e)
    return np.sqrt(np.abs(det))


@dataclass(frozen=True, eq=False)
class LatticeRound:
    """One capture of stage 2: every projector's dots.

    Attributes
    ----------
    centres : dict slot -> (M, 2) float64 projector dot centres
    expected : dict slot -> (M, 2) float64 camera positions where the dots should land
    sites : dict slot -> (M, 2) float64 table mm of the sites
    """

    centres: dict[str, np.ndarray]
    expected: dict[str, np.ndarray]
    sites: dict[str, np.ndarray]


@dataclass(frozen=True, eq=False)
class Lattice:
    """The stage-2 plan (also the alignment check's pattern)."""

    slots: tuple[str, ...]
    sizes: dict[str, tuple[int, int]]
    dot_px: int
    spacing_mm: float
    spacing_px: float
    radius: int
    rounds: list[LatticeRound] = field(default_factory=list)

    def frames(self, index: int) -> dict[str, np.ndarray]:
        r = self.rounds[index]
        return {s: draw_dots(self.sizes[s], r.centres[s], self.dot_px) for s in self.slots}


def plan_lattice(table_to_projector: dict[str, np.ndarray], table_to_camera: np.ndarray, *,
                 sizes: dict[str, tuple[int, int]], camera_size: tuple[int, int], table_mm: tuple[float, float],
                 rounds: int = 4, dot_px: int | None = None, spacing_px: float | None = None,
                 margin_mm: float = 10.0) -> Lattice:
    """Share lattice sites on the table out between the projectors (stage 2).

    Parameters
    ----------
    table_to_projector : dict slot -> (3, 3) float64
        Each projector's (coarse or current) table mm -> projector px mapping.
    table_to_camera : (3, 3) float64
    sizes : dict slot -> (w, h) projector sizes
    camera_size : (w, h)
    table_mm : (W, H) table size; sites stay ``margin_mm`` inside it
    rounds : int
        Captures; round r shifts the lattice by half a step (in x, y or both)
        and rotates the site owners.
    dot_px : int, optional
        Dot side in projector px; default odd and at least 3 camera px wide.
    spacing_px : float, optional
        Lattice step in camera px; default from the dot's size in the camera.

    Returns
    -------
    Lattice
    """
    sizes = _sizes(sizes)
    slots = tuple(s for s in table_to_projector if s in sizes)
    if not slots:
        raise ValueError("no projectors with a table -> projector mapping")
    tw, th = (float(v) for v in table_mm)
    cw, ch = camera_size
    probe = np.array([[x, y] for x in np.linspace(-tw / 2, tw / 2, 5) for y in np.linspace(-th / 2, th / 2, 3)])
    cam_per_mm = local_scale(table_to_camera, probe)
    cam_per_mm = cam_per_mm[np.isfinite(cam_per_mm)]
    if len(cam_per_mm) == 0 or cam_per_mm.min() <= 0:
        raise ValueError("the table -> camera mapping is degenerate")
    proj_per_mm = np.concatenate([local_scale(table_to_projector[s], probe) for s in slots])
    cam_per_proj = float(np.nanmin(cam_per_mm)) / float(np.nanmax(proj_per_mm))
    if dot_px is None:
        dot_px = max(3, int(math.ceil(3.0 / cam_per_proj)))
        dot_px += 1 - dot_px % 2
    dot_cam = dot_px * float(np.nanmax(cam_per_mm)) / float(np.nanmin(proj_per_mm))   # largest dot in camera px
    radius = int(math.ceil(dot_cam / 2 + 2.5))
    if spacing_px is None:
        spacing_px = max(12.0, 2 * radius + 4.0)
    step = spacing_px / float(np.nanmin(cam_per_mm))
    n = len(slots)
    q = _lattice_multiplier(n)
    na = int((tw - 2 * margin_mm) // step) + 1
    nb = int((th - 2 * margin_mm) // step) + 1
    a, b = np.meshgrid(np.arange(na), np.arange(nb), indexing="xy")
    a, b = a.ravel(), b.ravel()
    shifts = [(0.0, 0.0), (0.5, 0.5), (0.5, 0.0), (0.0, 0.5)]
    lattice = Lattice(slots, sizes, dot_px, step, spacing_px, radius)
    edge = radius + 3
    for r in range(rounds):
        sx, sy = shifts[r % 4]
        sites = np.column_stack([-tw / 2 + margin_mm + (a + sx) * step, th / 2 - margin_mm - (b + sy) * step])
        inside = (sites[:, 0] <= tw / 2 - margin_mm) & (sites[:, 1] >= -th / 2 + margin_mm)
        owner = (a + q * b + r * (n // max(rounds, 1) + 1) + (r // 4)) % n
        centres, expected, owned = {}, {}, {}
        for i, s in enumerate(slots):
            sel = inside & (owner == i)
            st = sites[sel]
            w, h = sizes[s]
            c = snap_centre(apply_homography(table_to_projector[s], st), dot_px)
            half = (dot_px - 1) / 2 + 1
            ok = np.isfinite(c).all(axis=1) & (c[:, 0] >= half) & (c[:, 1] >= half) & (c[:, 0] <= w - 1 - half) & (c[:, 1] <= h - 1 - half)
            # where the drawn (snapped) dot lands: back to the table, then into the camera
            landed = apply_homography(np.linalg.inv(table_to_projector[s]), np.where(ok[:, None], c, 0.0))
            e = apply_homography(table_to_camera, landed)
            ok &= np.isfinite(e).all(axis=1) & (e[:, 0] >= edge) & (e[:, 1] >= edge) & (e[:, 0] < cw - edge) & (e[:, 1] < ch - edge)
            centres[s], expected[s], owned[s] = c[ok], e[ok], st[ok]
        lattice.rounds.append(LatticeRound(centres, expected, owned))
    return lattice


def measure_lattice(capture: np.ndarray, dark: np.ndarray, lattice: Lattice, index: int, *,
                    min_snr: float = 8.0) -> dict[str, DotMatches]:
    """Measure where each dot of round ``index`` landed in the camera.

    Each dot is looked for within half a lattice step of where it should
    land: the brightest (smoothed) pixel there seeds :func:`centroids`.

    Returns
    -------
    dict slot -> DotMatches (camera centroid, projector centre) of the dots found
    """
    img = luminance(capture) - luminance(dark)
    smooth = ndimage.gaussian_filter(img, 1.0)
    sigma = _noise_sigma(smooth)
    H, W = img.shape
    rnd = lattice.rounds[index]
    search = max(2, int(lattice.spacing_px / 2 - 1))
    out = {}
    for s in lattice.slots:
        exp = rnd.expected[s]
        if len(exp) == 0:
            out[s] = DotMatches(np.zeros((0, 2)), np.zeros((0, 2)))
            continue
        ex = np.clip(np.rint(exp[:, 0]).astype(np.int64), search, W - search - 1)
        ey = np.clip(np.rint(exp[:, 1]).astype(np.int64), search, H - search - 1)
        oy, ox = np.mgrid[-search: search + 1, -search: search + 1]
        win = smooth[ey[:, None] + oy.ravel()[None, :], ex[:, None] + ox.ravel()[None, :]]
        best = np.argmax(win, axis=1)
        peak = win[np.arange(len(win)), best]
        seeds = np.column_stack([ex + ox.ravel()[best], ey + oy.ravel()[best]]).astype(np.float64)
        xy, mass = centroids(img, seeds, radius=lattice.radius)
        ok = np.isfinite(xy).all(axis=1) & (peak > min_snr * sigma) & (mass > 0)
        out[s] = DotMatches(xy[ok], rnd.centres[s][ok])
    return out
