"""Synthetic light transport: a physically plausible stand-in for a projector rig.

Used by tests and ``shadowless bench compensation`` (the virtual room computes its own
ground truth; nothing here reads it). Each projector of a 5x5 ceiling array lights a content
pixel with a square footprint (the projector pixel) on the camera, which is

* offset by a sub-pixel, spatially varying misalignment (residual calibration error plus a
  keystone-like quadratic term),
* scaled and slightly rotated (pixel pitch and orientation differ between units),
* blurred by a defocus Gaussian whose width grows away from the projector's focus point,
* weighted by the unit's brightness and a vignetting fall-off around its nadir.

The footprint is integrated exactly over each camera pixel (box convolved with a Gaussian
has a closed form; rotation is handled by splitting the square into ``M x M`` sub-squares),
then truncated to the shared ``(2R+1)^2`` window structure of
:func:`~imaging.compensation.transport.transport_windows`. The rig's transport is
``L = sum_i L_i``; ``L`` and every ``L_i`` have the same structure, so the per-projector
baseline and the summed method solve problems of identical cost per iteration.
"""
from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.special import ndtr

from imaging.calibration.planar import apply_homography
from imaging.compensation.transport import DotGrid, assemble_transport, transport_windows

__all__ = [
    "ProjectorOptics",
    "SyntheticRig",
    "synthetic_rig",
    "synthetic_transport",
    "simulate_captures",
    "slot_names",
]

_CHUNK = 1 << 18  # content pixels per vectorised block (bounds temporary memory)


@dataclass(frozen=True)
class ProjectorOptics:
    """One projector's optics as seen by the camera (all lengths in camera pixels).

    Normalised content coordinates ``u, v`` run from -1 (left/top) to +1 (right/bottom).
    """

    slot: str
    position: tuple[float, float]  #: nadir of the unit in normalised content coordinates
    gain: float  #: relative peak brightness (about 1 +- 10 %)
    offset: tuple[float, float]  #: misalignment at the centre (x, y)
    offset_gradient: tuple[tuple[float, float], tuple[float, float]]  #: d offset / d (u, v), rows x and y
    keystone: tuple[float, float]  #: quadratic misalignment coefficient (x: u*v, y: u*u)
    scale: float  #: footprint side relative to the content pixel pitch
    scale_gradient: tuple[float, float]  #: relative change of the side per unit (u, v)
    rotation: float  #: footprint rotation, radians
    sigma: float  #: defocus Gaussian at the focus point
    sigma_growth: float  #: defocus growth per squared normalised distance from the nadir
    vignette: float  #: relative brightness loss at normalised distance 2 from the nadir


@dataclass(frozen=True)
class SyntheticRig:
    """A synthetic rig: geometry shared by all projectors plus each one's optics."""

    content_shape: tuple[int, int]
    camera_shape: tuple[int, int]
    homography: np.ndarray  #: (3, 3) float64 content -> camera
    radius: int
    projectors: tuple[ProjectorOptics, ...]

    @property
    def n_content(self) -> int:
        return self.content_shape[0] * self.content_shape[1]

    @property
    def n_camera(self) -> int:
        return self.camera_shape[0] * self.camera_shape[1]


def slot_names(n: int, *, grid: tuple[int, int] = (5, 5)) -> list[str]:
    """The ``n`` slots of a ``rows x cols`` array nearest its centre (1: r2c2, 9: the 3x3 core)."""
    rows, cols = grid
    if not 1 <= n <= rows * cols:
        raise ValueError(f"between 1 and {rows * cols} projectors, got {n}")
    cr, cc = (rows - 1) / 2, (cols - 1) / 2
    slots = sorted(
        ((r, c) for r in range(rows) for c in range(cols)),
        key=lambda rc: (max(abs(rc[0] - cr), abs(rc[1] - cc)), (rc[0] - cr) ** 2 + (rc[1] - cc) ** 2, rc),
    )
    return [f"r{r}c{c}" for r, c in slots[:n]]


def _optics(slot: str, grid: tuple[int, int], seed: int) -> ProjectorOptics:
    r, c = (int(v) for v in slot[1:].split("c"))
    rng = np.random.default_rng([seed, r, c])
    rows, cols = grid
    pos = (
        (2 * c / (cols - 1) - 1) if cols > 1 else 0.0,
        (2 * r / (rows - 1) - 1) if rows > 1 else 0.0,
    )
    u = lambda lo, hi: float(rng.uniform(lo, hi))  # noqa: E731
    return ProjectorOptics(
        slot=slot,
        position=pos,
        gain=u(0.9, 1.1),
        offset=(u(-0.45, 0.45), u(-0.45, 0.45)),
        offset_gradient=((u(-0.15, 0.15), u(-0.15, 0.15)), (u(-0.15, 0.15), u(-0.15, 0.15))),
        keystone=(0.04 * pos[1] + u(-0.02, 0.02), 0.04 * pos[0] + u(-0.02, 0.02)),
        scale=u(1.0, 1.3),
        scale_gradient=(0.04 * pos[0] + u(-0.01, 0.01), 0.04 * pos[1] + u(-0.01, 0.01)),
        rotation=math.radians(u(-2.0, 2.0)),
        sigma=u(0.35, 0.5),
        sigma_growth=u(0.04, 0.08),
        vignette=u(0.04, 0.08),
    )


def synthetic_rig(
    n_projectors: int = 25,
    *,
    content_shape: Sequence[int],
    camera_shape: Sequence[int] | None = None,
    homography: np.ndarray | None = None,
    radius: int = 2,
    seed: int = 0,
    grid: tuple[int, int] = (5, 5),
) -> SyntheticRig:
    """Draw a rig of ``n_projectors`` units (the ones nearest the centre of ``grid``).

    A slot's optics depend only on ``(seed, slot)``, so the 1-, 9- and 25-projector rigs of one
    seed share their units. ``camera_shape`` defaults to ``content_shape`` and ``homography``
    (content -> camera, (3, 3) float64) to the identity.
    """
    content_shape = (int(content_shape[0]), int(content_shape[1]))
    camera_shape = content_shape if camera_shape is None else (int(camera_shape[0]), int(camera_shape[1]))
    h = np.eye(3) if homography is None else np.asarray(homography, dtype=np.float64)
    if h.shape != (3, 3):
        raise ValueError(f"homography must be (3, 3), got {h.shape}")
    if radius < 1:
        raise ValueError(f"radius must be >= 1, got {radius}")
    slots = slot_names(n_projectors, grid=grid)
    return SyntheticRig(content_shape, camera_shape, h, radius, tuple(_optics(s, grid, seed) for s in slots))


# Psi(t) = t*Phi(t) + phi(t), tabulated for fast, accurate (< 1e-6) linear interpolation.
_PSI_LIMIT = 8.0
_PSI_STEPS = 256  # samples per unit
_PSI_T = np.arange(-_PSI_LIMIT * _PSI_STEPS, _PSI_LIMIT * _PSI_STEPS + 2) / _PSI_STEPS
_PSI = (_PSI_T * ndtr(_PSI_T) + np.exp(-0.5 * _PSI_T**2) / math.sqrt(2 * math.pi)).astype(np.float32)
_PSI_SLOPE = np.append(np.diff(_PSI), np.float32(1.0 / _PSI_STEPS)).astype(np.float32)


def _smooth_antiderivative(z: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """F(z) = sigma * Psi(z / sigma) = z*Phi(z/sigma) + sigma*phi(z/sigma), float32.

    The second antiderivative of the N(0, sigma^2) density: ``F(z) -> 0`` for ``z -> -inf``
    and ``F(z) -> z`` for ``z -> +inf``.
    """
    t = z / sigma
    u = t * np.float32(_PSI_STEPS)
    u += np.float32(_PSI_LIMIT * _PSI_STEPS)
    np.clip(u, 0, 2 * _PSI_LIMIT * _PSI_STEPS, out=u)
    i = u.astype(np.int32)
    u -= i
    out = _PSI[i]
    u *= _PSI_SLOPE[i]
    out += u
    np.copyto(out, t, where=t > _PSI_LIMIT)
    out *= sigma
    return out


def _box_weights(edges0: np.ndarray, centre: np.ndarray, half: np.ndarray, sigma: np.ndarray, k: int) -> np.ndarray:
    """Fraction of a box (half-width ``half``) convolved with N(0, sigma^2) in each of ``k`` unit pixels.

    ``edges0``: (n,) left edge of the first pixel; returns (n, k) float32.
    """
    e = edges0[:, None] + np.arange(k + 1, dtype=np.float32)[None, :] - centre[:, None]
    s = sigma[:, None]
    hh = half[:, None]
    g = _smooth_antiderivative(e + hh, s) - _smooth_antiderivative(e - hh, s)
    w = np.diff(g, axis=1) / (2 * hh)
    np.maximum(w, 0, out=w)
    return w


def _projector_block(
    rig: SyntheticRig, optics: ProjectorOptics, start: int, stop: int, samples: int
) -> np.ndarray:
    """Window values (n, K) float32 of one projector for content pixels ``start..stop-1``."""
    hgt, wid = rig.content_shape
    R = rig.radius
    k = 2 * R + 1
    idx = np.arange(start, stop, dtype=np.int64)
    x = (idx % wid).astype(np.float64)
    y = (idx // wid).astype(np.float64)
    centres = apply_homography(rig.homography, np.stack([x, y], axis=1))
    cx, cy = centres[:, 0], centres[:, 1]
    hm = rig.homography
    wgt = hm[2, 0] * x + hm[2, 1] * y + hm[2, 2]
    pitch = np.sqrt(np.abs(np.linalg.det(hm)) / wgt**3)  # sqrt(|det J|) of the homography
    bx, by = np.rint(cx), np.rint(cy)
    u = (x - (wid - 1) / 2) / max((wid - 1) / 2, 1)
    v = (y - (hgt - 1) / 2) / max((hgt - 1) / 2, 1)
    o = optics
    (gxu, gxv), (gyu, gyv) = o.offset_gradient
    mx = cx + o.offset[0] + gxu * u + gxv * v + o.keystone[0] * u * v
    my = cy + o.offset[1] + gyu * u + gyv * v + o.keystone[1] * u * u
    side = pitch * o.scale * (1 + o.scale_gradient[0] * u + o.scale_gradient[1] * v)
    d2 = (u - o.position[0]) ** 2 + (v - o.position[1]) ** 2
    sigma = (o.sigma * pitch * (1 + o.sigma_growth * d2)).astype(np.float32)
    bright = o.gain * (1 - o.vignette * d2 / 4) * pitch**2
    f32 = np.float32
    ex0 = (bx - R - 0.5).astype(f32)
    ey0 = (by - R - 0.5).astype(f32)
    half = (side / (2 * samples)).astype(f32)
    ca, sa = math.cos(o.rotation), math.sin(o.rotation)
    out = np.zeros((idx.size, k, k), dtype=f32)
    subs = (np.arange(samples) + 0.5) / samples - 0.5
    for p in subs:
        for q in subs:
            # sub-square centre: the footprint's (p, q) cell rotated about its centre
            sx = (mx + side * (ca * p - sa * q)).astype(f32)
            sy = (my + side * (sa * p + ca * q)).astype(f32)
            wx = _box_weights(ex0, sx, half, sigma, k)
            wy = _box_weights(ey0, sy, half, sigma, k)
            out += wy[:, :, None] * wx[:, None, :]
    out *= (bright / samples**2).astype(f32)[:, None, None]
    return out.reshape(idx.size, k * k)


def synthetic_transport(
    rig: SyntheticRig,
    *,
    projectors: Sequence[int] | None = None,
    scale: float = 1.0,
    per_projector: bool = False,
    footprint_samples: int = 2,
    workers: int = 1,
) -> sp.csr_matrix | list[sp.csr_matrix]:
    """The rig's light transport, ``(n_camera, n_content)`` CSR float32.

    Parameters
    ----------
    rig : SyntheticRig
    projectors : sequence of int, optional
        Indices into ``rig.projectors`` (default: all).
    scale : float
        Uniform factor applied to every ``L_i`` (e.g. ``1/N`` to match one projector's brightness).
    per_projector : bool
        Return the list ``[L_i]`` instead of ``L = sum L_i``.
    footprint_samples : int
        ``M``: the square footprint is split into ``M x M`` sub-squares to model rotation
        (1 ignores rotation, 4x faster).
    workers : int
        Threads used for the vectorised PSF evaluation (numpy releases the GIL).
    """
    if footprint_samples < 1:
        raise ValueError(f"footprint_samples must be >= 1, got {footprint_samples}")
    chosen = list(range(len(rig.projectors))) if projectors is None else [int(i) for i in projectors]
    if not chosen:
        raise ValueError("no projectors chosen")
    n = rig.n_content
    _, rows, valid = transport_windows(rig.homography, rig.content_shape, rig.camera_shape, rig.radius)
    kk = rows.shape[1]
    blocks = [(a, min(a + _CHUNK, n)) for a in range(0, n, _CHUNK)]
    results: list[sp.csr_matrix] = []
    total = None if per_projector else np.zeros((n, kk), dtype=np.float32)
    executor = ThreadPoolExecutor(max_workers=workers) if workers > 1 else None
    try:
        for i in chosen:
            optics = rig.projectors[i]
            values = total if total is not None else np.zeros((n, kk), dtype=np.float32)

            def work(ab: tuple[int, int], optics: ProjectorOptics = optics, values: np.ndarray = values) -> None:
                a, b = ab
                block = _projector_block(rig, optics, a, b, footprint_samples)
                if scale != 1.0:
                    block *= np.float32(scale)
                values[a:b] += block

            if executor is None:
                for ab in blocks:
                    work(ab)
            else:
                list(executor.map(work, blocks))
            if per_projector:
                results.append(assemble_transport(values, rows, valid, rig.camera_shape))
    finally:
        if executor is not None:
            executor.shutdown(wait=True)
    if per_projector:
        return results
    return assemble_transport(total, rows, valid, rig.camera_shape)


def simulate_captures(
    L: sp.spmatrix,
    grid: DotGrid,
    camera_shape: Sequence[int],
    *,
    black: float | np.ndarray = 0.0,
    read_noise: float = 0.0,
    shot_noise: float = 0.0,
    dot_value: float = 1.0,
    rng: np.random.Generator | None = None,
) -> Iterator[np.ndarray]:
    """A synthetic camera: yields ``(Hc, Wc) float32`` captures of ``grid``'s patterns through ``L``.

    capture = L @ pattern + black + noise, with Gaussian noise of variance
    ``read_noise**2 + shot_noise**2 * signal`` (signal = L @ pattern + black).
    """
    hc, wc = int(camera_shape[0]), int(camera_shape[1])
    if L.shape != (hc * wc, grid.width * grid.height):
        raise ValueError(f"L has shape {L.shape}, expected {(hc * wc, grid.width * grid.height)}")
    rng = np.random.default_rng(0) if rng is None else rng
    L = sp.csr_matrix(L)
    for k in range(len(grid)):
        img = (L @ grid.pattern(k, value=dot_value).reshape(-1)).reshape(hc, wc)
        yield camera_noise(img + np.asarray(black, dtype=np.float32), read_noise=read_noise, shot_noise=shot_noise, rng=rng)


def camera_noise(
    signal: np.ndarray, *, read_noise: float = 0.0, shot_noise: float = 0.0, rng: np.random.Generator
) -> np.ndarray:
    """Add Gaussian read + shot noise to a linear ``signal`` image; returns float32 of the same shape."""
    signal = np.asarray(signal, dtype=np.float32)
    if read_noise == 0 and shot_noise == 0:
        return signal.copy()
    std = np.sqrt(read_noise**2 + shot_noise**2 * np.maximum(signal, 0))
    return (signal + std * rng.standard_normal(signal.shape, dtype=np.float32)).astype(np.float32)


_MOSAIC_SOURCES = ("astronaut", "coffee", "rocket", "chelsea", "text", "immunohistochemistry", "brick",
                   "camera", "page", "hubble_deep_field", "coins", "grass", "colorwheel", "clock")


def sample_image(height: int, width: int, *, channels: int = 3, seed: int = 0) -> np.ndarray:
    """A sharp test picture: scikit-image's sample photos tiled at native resolution (no upsampling).

    Returns ``(H, W, 3)`` or ``(H, W)`` float32 sRGB-encoded values in [0, 1] (``channels`` 3 or
    1; grey is the Rec. 709 luma). Tiles are cropped at random (``seed``) so every size gets
    full-resolution detail: edges, text, texture and smooth areas.
    """
    import skimage.data  # lazy: scikit-image's sample data is heavy and only test pictures need it

    if channels not in (1, 3):
        raise ValueError(f"channels must be 1 or 3, got {channels}")
    if height < 1 or width < 1:
        raise ValueError(f"size must be positive, got {width}x{height}")
    rng = np.random.default_rng(seed)
    canvas = np.zeros((height, width, 3), dtype=np.float32)
    tile = 320
    k = 0
    for y0 in range(0, height, tile):
        for x0 in range(0, width, tile):
            name = _MOSAIC_SOURCES[k % len(_MOSAIC_SOURCES)]
            k += 1
            src = np.asarray(getattr(skimage.data, name)())
            if src.ndim == 2:
                src = np.repeat(src[:, :, None], 3, axis=2)
            src = src[:, :, :3].astype(np.float32) / (255.0 if src.dtype == np.uint8 else 1.0)
            th, tw = min(tile, height - y0), min(tile, width - x0)
            if src.shape[0] < th or src.shape[1] < tw:
                reps = (-(-th // src.shape[0]), -(-tw // src.shape[1]), 1)
                src = np.tile(src, reps)
            sy = int(rng.integers(0, src.shape[0] - th + 1))
            sx = int(rng.integers(0, src.shape[1] - tw + 1))
            canvas[y0 : y0 + th, x0 : x0 + tw] = src[sy : sy + th, sx : sx + tw]
    if channels == 1:
        return (canvas @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)).astype(np.float32)
    return canvas
