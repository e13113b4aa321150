"""Luminance response of each projector, its inverse lookup table, and brightness matching.

A projector given input value ``v`` in [0, 1] (the uint8 it outputs / 255) emits
``r(v) = black + peak * rho(v)``, where ``rho`` is its *normalised response*: monotone,
``rho(0) = 0``, ``rho(1) = 1`` (for a gamma display ``rho(v) = v**gamma``, whatever the black
level). Light transport is measured above black (the black capture is subtracted), so a node
that shows linear content ``y`` in [0, 1] must output ``v = rho^-1(y)``; then every
projector's light above black is ``peak * y``: linear, and the rig's sum is linear too.

Procedure (the coordinator drives the captures; these functions are the numerics):

1. :func:`grey_levels` -- the input values to show, one projector at a time;
2. :func:`response_mask` + :func:`capture_means` -- reduce each capture to a mean;
3. :func:`fit_response` -- a monotone curve per channel (isotonic regression + PCHIP);
4. :func:`inverse_lut` -- the ``(C, E)`` float32 table the node's shader applies (what a node
   then outputs is :func:`protos.spaces.lut_lookup`);
5. :func:`verify_linearity` -- show linear levels through the LUTs, check the straight line;
6. :func:`brightness_scale` -- one uniform gain so the rig matches a reference brightness.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PchipInterpolator

from imaging.compensation.errors import CompensationError

__all__ = [
    "FittedResponse",
    "Linearity",
    "BrightnessMatch",
    "grey_levels",
    "response_mask",
    "capture_means",
    "fit_response",
    "inverse_lut",
    "verify_linearity",
    "brightness_scale",
]


@dataclass(frozen=True)
class FittedResponse:
    """A fitted projector response.

    Attributes
    ----------
    levels : (K,) float64
        Input values of the samples, strictly increasing, ``levels[0] == 0``, ``levels[-1] == 1``.
    curve : (C, K) float64
        Normalised response at ``levels``: non-decreasing, 0 at input 0 and 1 at input 1.
    black : (C,) float64
        Measured luminance at input 0 (camera units; includes ambient light).
    peak : (C,) float64
        Luminance span ``r(1) - r(0)`` (camera units).
    gamma : (C,) float64
        Exponent of the power law ``v**gamma`` closest to ``curve`` (a summary for reports).
    """

    levels: np.ndarray
    curve: np.ndarray
    black: np.ndarray
    peak: np.ndarray
    gamma: np.ndarray

    @property
    def channels(self) -> int:
        return int(self.curve.shape[0])

    def normalised(self, v: np.ndarray | float) -> np.ndarray:
        """``rho(v)`` for inputs ``v`` in [0, 1]: shape ``(C, *v.shape)`` float64 (monotone PCHIP)."""
        v = np.clip(np.asarray(v, dtype=np.float64), 0.0, 1.0)
        out = PchipInterpolator(self.levels, self.curve, axis=1, extrapolate=False)(v)
        return np.clip(out, 0.0, 1.0)

    def luminance(self, v: np.ndarray | float) -> np.ndarray:
        """Absolute ``r(v) = black + peak * rho(v)``: shape ``(C, *v.shape)`` float64."""
        rho = self.normalised(v)
        shape = (-1,) + (1,) * (rho.ndim - 1)
        return self.black.reshape(shape) + self.peak.reshape(shape) * rho


@dataclass(frozen=True)
class Linearity:
    """Straight-line fit of measured luminance against requested linear levels, per channel.

    ``max_error`` and ``rms_error`` are residuals relative to the fitted full-scale span
    (``slope``); ``linear`` says whether ``max_error <= tolerance``.
    """

    slope: np.ndarray
    intercept: np.ndarray
    max_error: float
    rms_error: float
    tolerance: float

    @property
    def linear(self) -> bool:
        return self.max_error <= self.tolerance


@dataclass(frozen=True)
class BrightnessMatch:
    """Uniform gain that makes the rig's white match a reference white.

    ``gain`` multiplies the linear content on every node (before its LUT). ``headroom`` is
    rig white / reference white: how much brighter than the reference the rig could go (a
    value below 1 means the reference cannot be reached; ``gain`` is then above 1 and
    ``reachable`` is False). ``channel_headroom`` is the same ratio per channel.
    """

    gain: float
    headroom: float
    channel_headroom: np.ndarray
    rig_peak: np.ndarray
    reference_peak: np.ndarray

    @property
    def reachable(self) -> bool:
        return self.gain <= 1.0 + 1e-12


def grey_levels(count: int = 33, *, bits: int = 8) -> np.ndarray:
    """``count`` input values from 0 to 1 on the ``bits``-bit grid a node can output: (count,) float64."""
    if count < 3:
        raise ValueError(f"need at least 3 grey levels, got {count}")
    top = (1 << bits) - 1
    codes = np.unique(np.rint(np.linspace(0, top, count)).astype(np.int64))
    return codes / top


def response_mask(white: np.ndarray, black: np.ndarray, *, fraction: float = 0.5) -> np.ndarray:
    """Camera pixels a projector lights well: ``(H, W) bool``.

    A pixel is in when its white-minus-black difference (channel mean) exceeds ``fraction`` of
    the 99th percentile of that difference; edges of the lit area are excluded.
    """
    w = np.asarray(white, dtype=np.float32)
    b = np.asarray(black, dtype=np.float32)
    if w.shape != b.shape or w.ndim not in (2, 3):
        raise ValueError(f"white {w.shape} and black {b.shape} must be equal (H, W) or (H, W, C) images")
    d = w - b
    if d.ndim == 3:
        d = d.mean(axis=2)
    top = float(np.percentile(d, 99))
    if top <= 0:
        raise CompensationError("the projector adds no light to the camera image; check that it is on and in view")
    return d > fraction * top


def capture_means(captures: Sequence[np.ndarray], *, mask: np.ndarray | None = None) -> np.ndarray:
    """Mean of each capture inside ``mask``: ``(K, C) float64`` (C = 1 for grey captures).

    ``captures``: K linear camera images, (H, W) or (H, W, C), one per grey level.
    """
    rows = []
    for k, cap in enumerate(captures):
        a = np.asarray(cap, dtype=np.float64)
        if a.ndim == 2:
            a = a[:, :, None]
        if a.ndim != 3:
            raise ValueError(f"capture {k} must be (H, W) or (H, W, C), got {np.asarray(cap).shape}")
        if mask is not None:
            m = np.asarray(mask, dtype=bool)
            if m.shape != a.shape[:2]:
                raise ValueError(f"mask {m.shape} does not match capture {a.shape[:2]}")
            if not m.any():
                raise CompensationError("the response mask is empty; the projector lights no camera pixel")
            a = a[m]
        rows.append(a.reshape(-1, a.shape[-1]).mean(axis=0))
    if not rows:
        raise ValueError("no captures")
    out = np.stack(rows)
    if len({r.shape for r in rows}) != 1:
        raise ValueError("captures differ in channel count")
    return out


def _isotonic(y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted least-squares non-decreasing fit (pool adjacent violators), (K,) float64."""
    vals: list[float] = []
    wts: list[float] = []
    lens: list[int] = []
    for yi, wi in zip(y.tolist(), w.tolist()):
        vals.append(yi)
        wts.append(wi)
        lens.append(1)
        while len(vals) > 1 and vals[-2] > vals[-1]:
            wt = wts[-2] + wts[-1]
            v = (vals[-2] * wts[-2] + vals[-1] * wts[-1]) / wt
            n = lens[-2] + lens[-1]
            del vals[-1], wts[-1], lens[-1]
            vals[-1], wts[-1], lens[-1] = v, wt, n
    return np.repeat(np.asarray(vals), lens)


def fit_response(
    levels: np.ndarray | Sequence[float],
    measured: np.ndarray,
    *,
    channels: int | None = None,
) -> FittedResponse:
    """Fit a monotone response curve per channel from grey-level measurements.

    Parameters
    ----------
    levels : (K,) float
        Input values shown, in [0, 1]; must include 0 and 1; repeats are averaged.
    measured : (K,) or (K, C) float
        Camera luminance for each level (e.g. from :func:`capture_means`).
    channels : int, optional
        Number of channels of the result. A single measured channel is replicated to
        ``channels``; otherwise it must match ``C``.

    Returns
    -------
    FittedResponse
        Samples are averaged per level, normalised between the black and white levels, made
        non-decreasing by isotonic regression and interpolated by a monotone PCHIP.

    Raises
    ------
    ValueError
        On bad shapes or levels without 0 and 1.
    CompensationError
        If a channel's white is not brighter than its black (no light measured).
    """
    lv = np.asarray(levels, dtype=np.float64).reshape(-1)
    m = np.asarray(measured, dtype=np.float64)
    if m.ndim == 1:
        m = m[:, None]
    if m.ndim != 2 or m.shape[0] != lv.size:
        raise ValueError(f"measured must be (K,) or (K, C) with K = {lv.size} levels, got {np.asarray(measured).shape}")
    if not (np.all(np.isfinite(lv)) and np.all(np.isfinite(m))):
        raise ValueError("levels and measurements must be finite")
    if lv.min() < 0 or lv.max() > 1:
        raise ValueError("levels must lie in [0, 1]")
    uniq, inv, counts = np.unique(lv, return_inverse=True, return_counts=True)
    if uniq.size < 3 or uniq[0] != 0.0 or uniq[-1] != 1.0:
        raise ValueError("need at least 3 distinct levels including 0 and 1")
    sums = np.zeros((uniq.size, m.shape[1]))
    np.add.at(sums, inv, m)
    mean = sums / counts[:, None]
    c = m.shape[1]
    if channels is not None:
        if c == 1 and channels > 1:
            mean = np.repeat(mean, channels, axis=1)
            c = channels
        elif c != channels:
            raise ValueError(f"measured has {c} channels, expected {channels}")
    black = mean[0].copy()
    peak = mean[-1] - black
    if np.any(peak <= 0):
        bad = [int(i) for i in np.flatnonzero(peak <= 0)]
        raise CompensationError(
            f"channel(s) {bad}: white is not brighter than black; check that the projector is on and in the camera view"
        )
    rho = (mean - black) / peak
    curve = np.empty((c, uniq.size))
    for ch in range(c):
        iso = np.clip(_isotonic(rho[:, ch], counts.astype(np.float64)), 0.0, 1.0)
        iso[0], iso[-1] = 0.0, 1.0
        curve[ch] = np.maximum.accumulate(iso)
    sel = (uniq >= 0.1) & (uniq < 1.0)
    gamma = np.full(c, np.nan)
    for ch in range(c):
        ok = sel & (curve[ch] > 1e-6)
        if ok.sum() >= 1:
            lx, ly = np.log(uniq[ok]), np.log(curve[ch, ok])
            gamma[ch] = float(np.dot(lx, ly) / np.dot(lx, lx))
    return FittedResponse(levels=uniq, curve=curve, black=black, peak=peak, gamma=gamma)


def inverse_lut(response: FittedResponse, entries: int = 1024) -> np.ndarray:
    """The inverse-response lookup table a node applies: ``(C, E) float32``.

    Entry ``k`` of channel ``c`` is the input value in [0, 1] whose normalised light equals
    ``k / (E - 1)`` (linear luminance relative to that projector's maximum above black);
    nodes interpolate linearly between entries. ``LUT[:, 0] == 0`` and ``LUT[:, -1] == 1``.
    """
    if entries < 2:
        raise ValueError(f"a LUT needs at least 2 entries, got {entries}")
    v = np.linspace(0.0, 1.0, max(8 * entries, 8193))
    rho = response.normalised(v)
    y = np.linspace(0.0, 1.0, entries)
    lut = np.empty((response.channels, entries), dtype=np.float32)
    for ch in range(response.channels):
        r = np.maximum.accumulate(rho[ch])
        # a tiny ramp makes flat stretches (isotonic ties) strictly increasing, so the
        # inverse picks the lowest input that reaches each level
        r = (r + 1e-9 * v) / (1.0 + 1e-9)
        lut[ch] = np.interp(y, r, v)
    lut[:, 0] = 0.0
    lut[:, -1] = 1.0
    return lut


def verify_linearity(
    levels: np.ndarray | Sequence[float], measured: np.ndarray, *, tolerance: float = 0.01
) -> Linearity:
    """Check that the rig's light after the LUTs is a straight line of the requested level.

    Parameters
    ----------
    levels : (K,) float
        Linear levels requested (each node applied its LUT).
    measured : (K,) or (K, C) float
        Captured luminance for each level.
    tolerance : float
        Allowed maximum residual, as a fraction of full scale.
    """
    lv = np.asarray(levels, dtype=np.float64).reshape(-1)
    m = np.asarray(measured, dtype=np.float64)
    if m.ndim == 1:
        m = m[:, None]
    if m.ndim != 2 or m.shape[0] != lv.size or lv.size < 3:
        raise ValueError(f"measured must be (K,) or (K, C) with K = {lv.size} >= 3 levels")
    design = np.stack([np.ones_like(lv), lv], axis=1)
    coef, *_ = np.linalg.lstsq(design, m, rcond=None)
    intercept, slope = coef[0], coef[1]
    if np.any(slope <= 0):
        raise CompensationError("the rig's light does not grow with the requested level; check LUTs and gains")
    resid = (m - design @ coef) / slope
    return Linearity(
        slope=slope,
        intercept=intercept,
        max_error=float(np.abs(resid).max()),
        rms_error=float(np.sqrt(np.mean(resid**2))),
        tolerance=tolerance,
    )


def brightness_scale(
    responses: Sequence[FittedResponse],
    reference: FittedResponse | float | np.ndarray,
    *,
    channel_weights: Sequence[float] | None = None,
) -> BrightnessMatch:
    """One uniform gain so the rig's white matches ``reference`` (for example one projector's).

    Parameters
    ----------
    responses : sequence of FittedResponse
        Every projector of the rig (their ``peak`` add up on the surface they share).
    reference : FittedResponse, float or (C,) array
        Reference white above black: a response (its ``peak``), a luminance, or one per channel.
    channel_weights : sequence of C floats, optional
        How channels combine into one luminance (default: equal weights).
    """
    if not responses:
        raise ValueError("no responses")
    rig = np.sum([np.asarray(r.peak, dtype=np.float64) for r in responses], axis=0)
    ref = np.asarray(reference.peak if isinstance(reference, FittedResponse) else reference, dtype=np.float64)
    ref = np.broadcast_to(ref, rig.shape).astype(np.float64)
    if np.any(ref <= 0):
        raise ValueError("the reference brightness must be positive")
    w = np.ones(rig.shape) if channel_weights is None else np.asarray(channel_weights, dtype=np.float64)
    if w.shape != rig.shape:
        raise ValueError(f"channel_weights must have {rig.size} entries")
    w = w / w.sum()
    gain = float(np.dot(w, ref) / np.dot(w, rig))
    return BrightnessMatch(
        gain=gain,
        headroom=1.0 / gain,
        channel_headroom=rig / ref,
        rig_peak=rig,
        reference_peak=ref,
    )
