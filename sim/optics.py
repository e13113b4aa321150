"""Optics of the room: projector response, pixel footprint and defocus, irradiance, camera sensor.

Everything here is linear in the luminance a projector emits, so light
transport measured through the room is a real measurement.

How a projector's frame reaches a camera pixel
----------------------------------------------
1. **Response**: input value ``v`` (uint8 / 255) emits relative luminance
   ``r(v) = black + (1 - black) v**gamma`` per channel (:class:`Response`).
2. **Footprint**: each projector pixel lights a square on the surface. The
   frame is replicated ``upsample`` times per axis (nearest), so a projector
   pixel becomes an ``s x s`` block of the *field* grid.
3. **Blur**: the field is filtered with a normalised Gaussian whose sigma (in
   projector pixels) adds the defocus of the lens (:func:`defocus_sigma`) and
   the size of the camera pixel's footprint (:func:`camera_footprint_sigma`) in
   quadrature. Spatially varying blur is a per-pixel blend of two levels of a
   fixed ladder (:data:`SIGMA_LEVELS`), weighted so the blend has the wanted
   variance (:func:`blend_levels`).
4. **Sampling**: the blurred field is read with bilinear interpolation at the
   camera pixel's sub-pixel projector coordinate (``cv2.remap``;
   :func:`sample_weights_1d` and :func:`remap_fractions` give the identical linear weights).
5. **Irradiance**: multiplied by :func:`irradiance_factor` (distance,
   incidence, lens fall-off) and the projector's peak output.

Every kernel integrates to one, so blur and footprint move light around but
never create or destroy it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

#: Blur ladder in projector pixels; a pixel's sigma is a blend of two neighbours.
SIGMA_LEVELS: tuple[float, ...] = (0.0, 0.2, 0.35, 0.5, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0, 5.6, 8.0, 11.0, 16.0)

#: Sub-pixel steps of OpenCV's fixed-point remap (``cv2.INTER_TAB_SIZE``), used before OpenCV 5.
REMAP_STEPS = 32

#: Reference distance (mm) of :func:`irradiance_factor`: 1.0 = on-axis, fronto-parallel, 1 m away.
REFERENCE_DISTANCE_MM = 1000.0


# ---------------------------------------------------------------- projector response


@dataclass(frozen=True, eq=False)
class Response:
    """Per-channel luminance response ``r(v) = black + (1 - black) * v**gamma``.

    Attributes
    ----------
    gamma : (3,) float64
        Exponent per channel (about 2.2).
    black : (3,) float64
        Relative luminance emitted for input 0 (about 0.002-0.01).
    """

    gamma: np.ndarray
    black: np.ndarray

    def __post_init__(self) -> None:
        g = np.broadcast_to(np.asarray(self.gamma, np.float64), (3,)).copy()
        b = np.broadcast_to(np.asarray(self.black, np.float64), (3,)).copy()
        if np.any(g <= 0) or np.any((b < 0) | (b >= 1)):
            raise ValueError(f"need gamma > 0 and 0 <= black < 1, got gamma={g}, black={b}")
        object.__setattr__(self, "gamma", g)
        object.__setattr__(self, "black", b)

    def luminance(self, values: np.ndarray) -> np.ndarray:
        """Relative luminance for input values in [0, 1], shape ``(..., 3)`` float64."""
        v = np.clip(np.asarray(values, np.float64), 0.0, 1.0)
        return self.black + (1.0 - self.black) * v**self.gamma

    def inverse(self, luminance: np.ndarray) -> np.ndarray:
        """Input values in [0, 1] that emit ``luminance`` ``(..., 3)`` (clipped to the range)."""
        lum = np.asarray(luminance, np.float64)
        x = np.clip((lum - self.black) / (1.0 - self.black), 0.0, 1.0)
        return x ** (1.0 / self.gamma)

    def table_u8(self) -> np.ndarray:
        """(256, 3) float32: luminance of every uint8 input value per channel."""
        return self.luminance((np.arange(256, dtype=np.float64) / 255.0)[:, None]).astype(np.float32)


def random_response(rng: np.random.Generator, *, gamma: float = 2.2, spread: float = 0.1, black=(0.002, 0.01)) -> Response:
    """A unit's response: gamma within ``gamma * (1 +- spread)`` (channels within +-2 %) and black level in ``black``."""
    unit_gamma = gamma * (1.0 + rng.uniform(-spread, spread))
    channels = unit_gamma * (1.0 + rng.uniform(-0.02, 0.02, size=3))
    unit_black = rng.uniform(*black)
    return Response(channels, unit_black * (1.0 + rng.uniform(-0.1, 0.1, size=3)))


def apply_response(frame: np.ndarray, response: Response) -> np.ndarray:
    """Emitted relative luminance of a frame.

    Parameters
    ----------
    frame : (h, w, 3) uint8
        Input values, as the node outputs them.

    Returns
    -------
    (h, w, 3) float32
    """
    if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
        raise ValueError(f"frame must be (h, w, 3) uint8, got {frame.shape} {frame.dtype}")
    return cv2.LUT(frame, response.table_u8().reshape(1, 256, 3))


# ---------------------------------------------------------------- blur and footprint


def defocus_sigma(distance: np.ndarray, *, focus: float, aperture: float, focal_px: float) -> np.ndarray:
    """Gaussian sigma (projector pixels) of a thin lens's defocus at ``distance``.

    The cone of light from one pixel converges at the focus distance; at
    ``distance`` its diameter on the surface is ``aperture * |d - focus| / focus``
    mm, i.e. ``aperture * focal_px * |d - focus| / (focus * d)`` pixels; a disc
    of diameter D has a per-axis standard deviation of D / 4.

    Parameters
    ----------
    distance : (...,) float64
        Distance from the lens along the ray, mm.
    focus, aperture : float
        Focus distance and aperture diameter, mm.
    focal_px : float
        Focal length in pixels (at the projector's current resolution).
    """
    d = np.asarray(distance, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = aperture * focal_px * np.abs(d - focus) / (4.0 * focus * d)
    return np.where(d > 0, s, 0.0)


def camera_footprint_sigma(camera_area: np.ndarray, projector_area: np.ndarray, *, limit: float = 4.0) -> np.ndarray:
    """Sigma (projector pixels) that stands for a camera pixel integrating over its footprint.

    A square pixel of side ``a`` has a per-axis variance ``a**2 / 12``; the
    camera pixel's side in projector pixels is ``sqrt(camera_area / projector_area)``.

    Parameters
    ----------
    camera_area, projector_area : (...,) float64
        Footprint areas (mm^2) of one camera pixel and one projector pixel at the point.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.asarray(camera_area, np.float64) / np.asarray(projector_area, np.float64)
    ratio = np.where(np.isfinite(ratio) & (ratio > 0), ratio, 0.0)
    return np.minimum(np.sqrt(ratio / 12.0), limit)


def blend_levels(sigma: np.ndarray, levels: tuple[float, ...] = SIGMA_LEVELS) -> tuple[np.ndarray, np.ndarray]:
    """Bracket each sigma between two ladder levels.

    The blend ``(1 - alpha) * G(levels[lo]) + alpha * G(levels[lo + 1])`` has
    exactly the variance ``sigma**2`` (both kernels are centred and integrate to one).

    Returns
    -------
    lo : (...,) int32
    alpha : (...,) float32 in [0, 1]
    """
    s = np.clip(np.asarray(sigma, np.float64), levels[0], levels[-1])
    lv = np.asarray(levels, np.float64)
    lo = np.clip(np.searchsorted(lv, s, side="right") - 1, 0, len(lv) - 2)
    a2, b2 = lv[lo] ** 2, lv[lo + 1] ** 2
    alpha = (s * s - a2) / (b2 - a2)
    return lo.astype(np.int32), np.clip(alpha, 0.0, 1.0).astype(np.float32)


def gaussian_kernel(sigma: float) -> np.ndarray:
    """Normalised 1D Gaussian taps ``(2r + 1,)`` float64, r = ceil(3.5 sigma); ``[1.0]`` for sigma 0."""
    if sigma < 0:
        raise ValueError("sigma must be >= 0")
    if sigma == 0:
        return np.ones(1)
    r = max(1, math.ceil(3.5 * sigma))
    x = np.arange(-r, r + 1, dtype=np.float64)
    g = np.exp(-0.5 * (x / sigma) ** 2)
    return g / g.sum()


def field_padding(max_sigma_px: float, upsample: int) -> int:
    """Border (field pixels) around an upsampled frame so blurred light is never cut off."""
    return (len(gaussian_kernel(max_sigma_px * upsample)) // 2) + 2


def light_field(luminance: np.ndarray, *, upsample: int, pad: int, sigmas: list[float]) -> list[np.ndarray]:
    """Footprint- and blur-filtered light fields of one frame, one per sigma.

    Parameters
    ----------
    luminance : (h, w, 3) float32
        Emitted relative luminance per projector pixel.
    upsample : int
        Field samples per projector pixel and axis (square footprint).
    pad : int
        Zero border in field pixels (see :func:`field_padding`).
    sigmas : list of float
        Blur levels in projector pixels.

    Returns
    -------
    list of (s h + 2 pad, s w + 2 pad, 3) float32
        Field sample ``k`` (per axis) sits at projector coordinate ``(k - pad + 0.5) / s - 0.5``.
    """
    if luminance.ndim != 3 or luminance.shape[2] != 3:
        raise ValueError(f"luminance must be (h, w, 3), got {luminance.shape}")
    img = np.ascontiguousarray(luminance, dtype=np.float32)
    if upsample > 1:
        h, w = img.shape[:2]
        img = cv2.resize(img, (w * upsample, h * upsample), interpolation=cv2.INTER_NEAREST_EXACT)
    img = cv2.copyMakeBorder(img, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=(0.0, 0.0, 0.0))
    out = []
    for sigma in sigmas:
        if sigma <= 0:
            out.append(img)
            continue
        k = gaussian_kernel(sigma * upsample).astype(np.float32)
        out.append(cv2.sepFilter2D(img, cv2.CV_32F, k, k, borderType=cv2.BORDER_CONSTANT))
    return out


def field_coordinates(u: np.ndarray, *, upsample: int, pad: int) -> np.ndarray:
    """Field-grid coordinate of projector coordinate ``u`` (any shape, float64): ``s (u + 0.5) - 0.5 + pad``."""
    return upsample * (np.asarray(u, np.float64) + 0.5) - 0.5 + pad


def sample_weights_1d(sigma_px: float, *, upsample: int) -> tuple[int, np.ndarray]:
    """Exact 1D weights of footprint + blur + bilinear sampling, per projector pixel.

    A sample at field position ``k = pad + s q + rho + f`` (integer ``q``,
    residue ``0 <= rho < s``, fraction ``0 <= f < 1``) reads the field at
    ``pad + s q + rho`` with weight ``1 - f`` and at the next sample with
    weight ``f``; it receives from projector pixel ``q + dj`` the weight
    ``(1 - f) * table[rho, 0, dj - dj_min] + f * table[rho, 1, dj - dj_min]``.

    Returns
    -------
    dj_min : int
    table : (s, 2, n) float64
        Each ``table[rho, t]`` sums to one (light is conserved).
    """
    s = int(upsample)
    g = gaussian_kernel(sigma_px * s)
    r = len(g) // 2
    dj_min = math.floor(-r / s)
    dj_max = math.floor((s + r) / s)
    table = np.zeros((s, 2, dj_max - dj_min + 1))
    for rho in range(s):
        for t in (0, 1):
            for m in range(-r, r + 1):
                k = rho + t - m  # field index relative to pad + s q
                table[rho, t, math.floor(k / s) - dj_min] += g[m + r]
    return dj_min, table


def remap_fractions(coords: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Integer sample and interpolation fraction ``cv2.remap`` uses for float32 map values.

    OpenCV 5 interpolates float maps exactly; older versions round to 1/32
    (``cv2.INTER_TAB_SIZE``). Which one applies is probed once.

    Returns
    -------
    base : int64 array, fraction : float64 array in [0, 1)
    """
    x = np.asarray(coords, np.float32).astype(np.float64)
    if not _REMAP_EXACT:
        x = np.round(x * REMAP_STEPS) / REMAP_STEPS
    base = np.floor(x)
    return base.astype(np.int64), x - base


def _probe_remap_exact() -> bool:
    img = np.array([[0.0, 1.0], [0.0, 1.0]], np.float32)
    m = np.full((1, 1), 0.3, np.float32)
    out = cv2.remap(img, m, np.zeros_like(m), cv2.INTER_LINEAR)
    return abs(float(out[0, 0]) - 0.3) < 1e-6


_REMAP_EXACT = _probe_remap_exact()


# ---------------------------------------------------------------- irradiance


def irradiance_factor(center: np.ndarray, axis: np.ndarray, points: np.ndarray, normals: np.ndarray, *, falloff: float = 1.0) -> np.ndarray:
    """Irradiance at surface points from a uniform full frame of unit flux per pixel.

    A projector's pixels carry equal flux and each spans the solid angle
    ``cos^3(a) / f^2``; a surface at distance ``d`` tilted by ``theta`` from the
    ray receives ``cos(theta) / (cos^3(a) d^2)``, times a lens fall-off
    ``cos(a)**falloff``. Normalised to 1 on the axis of a fronto-parallel
    surface :data:`REFERENCE_DISTANCE_MM` away.

    Parameters
    ----------
    center, axis : (3,) float64
        Projector optical centre (mm) and unit viewing direction.
    points, normals : (..., 3) float64

    Returns
    -------
    (...,) float64, zero for surfaces facing away or behind the projector.
    """
    v = np.asarray(center, np.float64) - np.asarray(points, np.float64)
    d = np.linalg.norm(v, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        cos_t = np.einsum("...i,...i->...", np.asarray(normals, np.float64), v) / d
        cos_a = -(v @ np.asarray(axis, np.float64)) / d
        e = cos_t * cos_a ** (falloff - 3.0) * (REFERENCE_DISTANCE_MM / d) ** 2
    return np.where((cos_t > 0) & (cos_a > 1e-6) & np.isfinite(e), e, 0.0)


# ---------------------------------------------------------------- camera sensor


@dataclass(frozen=True)
class Sensor:
    """A camera sensor: linear up to saturation, shot and read noise, quantisation.

    Attributes
    ----------
    full_well : float
        Electrons at full scale (shot noise: a signal ``x`` of full scale
        collects ``x * full_well`` electrons, Poisson distributed).
    read_noise : float
        Read noise in electrons (Gaussian).
    bits : int
        Output quantisation (12 by default); 0 keeps float values.
    gamma : float
        Output response ``value ** (1 / gamma)``; 1.0 (linear) by default.
    """

    full_well: float = 10000.0
    read_noise: float = 2.5
    bits: int = 12
    gamma: float = 1.0

    def expose(self, signal: np.ndarray, *, rng: np.random.Generator | None, noise: bool = True) -> np.ndarray:
        """Sensor output for a linear signal (fraction of full scale).

        Parameters
        ----------
        signal : (H, W, 3) float32
        rng : numpy Generator (required when ``noise``)

        Returns
        -------
        (H, W, 3) float32 in [0, 1].
        """
        x = np.asarray(signal, np.float32)
        if noise:
            if rng is None:
                raise ValueError("noise needs a random generator")
            e = np.maximum(x, 0.0) * np.float32(self.full_well)
            std = np.sqrt(e + np.float32(self.read_noise**2))
            e = e + std * rng.standard_normal(x.shape, dtype=np.float32)
            x = e / np.float32(self.full_well)
        x = np.clip(x, 0.0, 1.0)
        if self.gamma != 1.0:
            x = x ** np.float32(1.0 / self.gamma)
        if self.bits:
            q = np.float32(2**self.bits - 1)
            x = np.rint(x * q) / q
        return x.astype(np.float32, copy=False)
