"""The photometric watchdog's numerics: each projector's effective gain from one capture of the
content on screen.

A capture ``c`` of known content is, on the contributions' camera grid, the sum of what each
projector sends there, each scaled by its lamp's effective gain ``g_i`` (1: as measured, 0.5: a
lamp at half, 0: dead)::

    c(x) ~= sum_i g_i * P_i(x)

where ``P_i`` is projector i's predicted light at full lamp for what it shows now: its measured
white scaled by its blend maps and the content, plus its share of the black level. That is N
unknowns and a measurement per grid cell and channel: a bounded linear least-squares problem,

    minimise  sum_x w(x) * ((c(x) - sum_i g_i P_i(x)) / s(x))^2  +  prior * sum_i (g_i - 1)^2
    with      0 <= g_i <= max_gain,

residuals relative to the predicted light ``s(x) = sum_i P_i(x)`` (camera noise and model error
grow with the light), a weak prior toward 1 (a projector whose light is nowhere its own is not
made up), and robust weights ``w`` (Tukey's biweight on the relative residuals, iterated): a
hand or a person in front of the camera removes light from some cells, which are then given no
weight instead of dimming every projector that reaches them.

**What limits it.** Where all projectors overlap everywhere with the same shape of light, the
columns ``P_i`` are nearly parallel and only their sum is measured: the gains are then
ill-conditioned. What separates them is each footprint's edge, fall-off and hot spot, and the
blend maps themselves (which shape each projector's light differently). :class:`GainFit` reports
the condition number of the (weighted, column-normalised) design and a standard error per gain,
so a caller names a lamp only when its gain is off by more than its uncertainty allows. On the
5x5 table (every projector reaches almost all of it) the condition number is in the thousands:
:func:`fit_gains` cannot separate 25 gains from one capture. :func:`fit_changes` asks a
question the capture can answer: which one or two lamps changed, all others as measured (a
lamp dims or dies rarely, and one at a time); each hypothesis has one or two unknowns, and the
hypotheses compete on their residuals. Footprint edges, where the light steps within a grid
cell and the model is least exact, are left out (:func:`steady_cells`).

Everything here is NumPy and SciPy (``scipy.optimize.lsq_linear``) on small arrays; OpenCV warps
the maps and the content onto the camera grid.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import cv2
import numpy as np

from imaging.blending.predict import sample_map
from protos.blend import BlendMaps

__all__ = ["GainFit", "camera_grid_to_camera", "columns_for", "content_on_grid", "fit_changes", "fit_gains",
           "gain_objective", "grid_mean", "maps_on_grid", "predicted_light", "steady_cells"]

#: Tukey's biweight constant (95 % efficiency under Gaussian noise), in robust standard deviations
TUKEY_C = 4.685


@dataclass(frozen=True)
class GainFit:
    """One fit's figures.

    Attributes
    ----------
    gains : (N,) float64
        Each projector's effective gain, in the order of the columns given.
    stderr : (N,) float64
        Each gain's standard error (from the residuals' robust spread and the design).
    condition : float
        Condition number of the weighted design with unit-norm columns (1: independent
        projectors; large: only sums of gains are measured).
    inliers : float
        Fraction of the measurements the robust weights kept (weight > 0).
    residual : float
        Robust spread (1.4826 MAD) of the relative residuals of the inliers.
    iterations : int
    prior : float
        The weight the prior had on the mean squared relative residual (see :func:`fit_gains`).
    changed : tuple of int
        :func:`fit_changes` only: the columns whose gain it found changed (the others are 1).
    """

    gains: np.ndarray
    stderr: np.ndarray
    condition: float
    inliers: float
    residual: float
    iterations: int
    prior: float = 0.0
    changed: tuple[int, ...] = ()


# ---------------------------------------------------------------------- grids
def camera_grid_to_camera(scale: float) -> np.ndarray:
    """(3, 3) float64 mapping a camera-grid texel to full camera pixels: texel (i, j) of a grid
    ``scale`` times coarser than the camera has its centre at camera pixel
    ``((j + 0.5) * scale - 0.5, (i + 0.5) * scale - 0.5)`` (the blend maps' convention)."""
    s = float(scale)
    if not (np.isfinite(s) and s > 0):
        raise ValueError(f"grid scale must be positive, got {scale!r}")
    return np.array([[s, 0.0, 0.5 * s - 0.5], [0.0, s, 0.5 * s - 0.5], [0.0, 0.0, 1.0]])


def grid_mean(image: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """``image`` (H, W, C) float32 area-averaged down to ``shape`` (h, w): (h, w, C) float32.

    Each output texel is the mean of the camera pixels it covers (OpenCV's INTER_AREA), which is
    what the contributions' grid holds."""
    img = np.asarray(image, np.float32)
    if img.ndim != 3:
        raise ValueError(f"image must be (H, W, C), got shape {img.shape}")
    h, w = int(shape[0]), int(shape[1])
    if img.shape[:2] == (h, w):
        return img
    out = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
    return out.reshape(h, w, img.shape[2])


def maps_on_grid(maps: BlendMaps, grid_to_projector: np.ndarray, projector_size: tuple[int, int],
                 shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A projector's blend maps seen from the camera grid.

    Parameters
    ----------
    maps : BlendMaps
        alpha (mh, mw, 3), beta (mh, mw) on the projector's map grid (:mod:`protos.blend`).
    grid_to_projector : (3, 3) float64
        Camera-grid texel -> projector pixel.
    projector_size : (W, H)
    shape : (h, w) of the camera grid

    Returns
    -------
    alpha : (h, w, 3) float32
    beta : (h, w) float32
    inside : (h, w) bool
        Grid texels whose projector pixel lies on the projector's frame.
    """
    W, H = int(projector_size[0]), int(projector_size[1])
    h, w = int(shape[0]), int(shape[1])
    ii, jj = np.mgrid[0:h, 0:w]
    pts = np.stack([jj.ravel(), ii.ravel(), np.ones(h * w)]).astype(np.float64)
    u = np.asarray(grid_to_projector, np.float64) @ pts
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = u[0] / u[2], u[1] / u[2]
    inside = ((u[2] > 0) & (x >= -0.5) & (x <= W - 0.5) & (y >= -0.5) & (y <= H - 0.5)).reshape(h, w)
    # the maps at those projector pixels, sampled as the blend's forward model samples them
    xy = np.stack([x, y], axis=1).reshape(h, w, 2)
    return sample_map(maps.alpha, xy, (W, H)), sample_map(maps.beta, xy, (W, H)), inside


def content_on_grid(content: np.ndarray, grid_to_content: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The content each camera-grid texel sees: ``content`` (Hc, Wc, C) float32 in 0..1 (linear)
    warped through ``grid_to_content`` (3, 3) float64 (grid texel -> content pixel, texel centres
    at integers), bilinear, 0 outside the content (as the nodes render it). Returns (h, w, 3)
    float32; a one-channel content is repeated."""
    img = np.asarray(content, np.float32)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.ndim != 3 or img.shape[2] not in (1, 3, 4):
        raise ValueError(f"content must be (H, W) or (H, W, 1|3|4), got shape {img.shape}")
    img = np.repeat(img[:, :, :1], 3, axis=2) if img.shape[2] == 1 else np.ascontiguousarray(img[:, :, :3])
    h, w = int(shape[0]), int(shape[1])
    out = cv2.warpPerspective(img, np.asarray(grid_to_content, np.float64), (w, h),
                              flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT,
                              borderValue=(0.0, 0.0, 0.0, 0.0))
    return out.reshape(h, w, 3).astype(np.float32)


def predicted_light(white: np.ndarray, black: np.ndarray, value: np.ndarray, alpha: np.ndarray | None = None,
                    beta: np.ndarray | None = None) -> np.ndarray:
    """One projector's light on the camera grid at full lamp, for what it shows.

    The node shows ``clamp(alpha * value + beta)`` in linear light (its LUT linearises the
    response), so the projector adds ``white * that + black``.

    Parameters
    ----------
    white : (h, w, 3) float32
        Light above black at full linear white (the contributions' ``white``).
    black : (h, w, 3) float32
        The projector's share of the black level.
    value : (h, w, 3) float32
        The linear content value the projector shows at each texel.
    alpha : (h, w, 3) float32, optional
    beta : (h, w) float32, optional
        The blend maps on the grid (:func:`maps_on_grid`); none: alpha 1, beta 0.

    Returns
    -------
    (h, w, 3) float32
    """
    shown = np.asarray(value, np.float32)
    if alpha is not None:
        shown = shown * alpha
    if beta is not None:
        shown = shown + np.asarray(beta, np.float32)[:, :, None]
    shown = np.clip(shown, 0.0, 1.0)
    return (np.asarray(white, np.float32) * shown + np.asarray(black, np.float32)).astype(np.float32)


# ---------------------------------------------------------------------- the fit
def _design(capture: np.ndarray, columns: Sequence[np.ndarray], valid: np.ndarray | None,
            floor: float) -> tuple[np.ndarray, np.ndarray]:
    """The relative system: rows are the valid texel channels, ``A`` (M, N) float64 the columns
    divided by the predicted sum, ``b`` (M,) the capture divided by it."""
    c = np.asarray(capture, np.float64)
    if c.ndim != 3:
        raise ValueError(f"capture must be (h, w, C), got shape {c.shape}")
    if not len(columns):
        raise ValueError("at least one projector's predicted light is needed")
    P = np.stack([np.asarray(p, np.float64) for p in columns], axis=-1)     # (h, w, C, N)
    if P.shape[:3] != c.shape:
        raise ValueError(f"predicted light must be {c.shape} per projector like the capture, got {P.shape[:3]}")
    s = P.sum(axis=-1)
    ok = np.isfinite(c) & np.all(np.isfinite(P), axis=-1) & (s > floor * max(float(s.max()), 1e-12))
    if valid is not None:
        v = np.asarray(valid, bool)
        if v.shape != c.shape[:2]:
            raise ValueError(f"valid must be (h, w) = {c.shape[:2]}, got {v.shape}")
        ok &= v[:, :, None]
    A = P[ok] / s[ok][:, None]
    b = c[ok] / s[ok]
    return A, b


def gain_objective(gains: np.ndarray, capture: np.ndarray, columns: Sequence[np.ndarray], *, prior: float,
                   valid: np.ndarray | None = None, floor: float = 0.02) -> float:
    """The unweighted objective :func:`fit_gains` minimises (robust weights all 1): the mean
    squared relative residual plus ``prior * sum (g - 1)^2``. For checks against a brute-force
    search."""
    A, b = _design(capture, columns, valid, floor)
    g = np.asarray(gains, np.float64)
    r = A @ g - b
    return float(np.mean(r * r) + prior * np.sum((g - 1.0) ** 2))


def fit_gains(capture: np.ndarray, columns: Sequence[np.ndarray], *, prior_sd: float = 0.5, max_gain: float = 1.5,
              robust: bool = True, iterations: int = 10, valid: np.ndarray | None = None, floor: float = 0.02,
              noise_floor: float = 0.002) -> GainFit:
    """Each projector's effective gain from a capture and its predicted light.

    Parameters
    ----------
    capture : (h, w, C) float32
        The camera's capture on the contributions' grid (:func:`grid_mean`).
    columns : sequence of N (h, w, C) float32
        Each projector's predicted light at full lamp for what it shows (:func:`predicted_light`),
        black share included.
    prior_sd : float
        The prior's standard deviation around a gain of 1. The prior weighs against the data as a
        Gaussian would: ``prior = sigma^2 / (M * prior_sd^2)`` on the mean squared relative residual,
        ``sigma`` the residuals' robust spread (at least ``noise_floor``) and ``M`` the measurements
        kept, so a gain the capture measures is barely moved, and one it cannot separate (twin
        footprints) stays near 1 instead of anywhere on a line.
    max_gain : float
        Upper bound of every gain (a lamp brighter than measured is allowed, within reason).
    robust : bool
        Iterate Tukey-biweight weights on the relative residuals (hands, people, reflections).
    iterations : int
        Re-weightings at most.
    valid : (h, w) bool, optional
        Texels to use (e.g. the covered region).
    floor : float
        Texels whose predicted light is below ``floor`` times the brightest are not used (their
        relative residual is noise).
    noise_floor : float
        The least relative noise assumed (a capture without noise must not make the prior vanish).

    Returns
    -------
    GainFit
    """
    if not (prior_sd > 0 and max_gain > 0 and iterations >= 1 and noise_floor > 0):
        raise ValueError("prior_sd, max_gain and noise_floor must be > 0 and iterations >= 1")
    A, b = _design(capture, columns, valid, floor)
    M, N = A.shape
    if M < N:
        raise ValueError(f"{M} usable measurements cannot fit {N} gains (is the camera seeing the projectors?)")
    w = np.ones(M)
    g = np.ones(N)
    prior = 0.0
    sigma = noise_floor
    done = 0
    for done in range(1, iterations + 1):
        # the prior's weight follows the current noise estimate and the measurements kept
        prior = sigma ** 2 / (max(float(w.sum()), 1.0) * prior_sd ** 2)
        sw = np.sqrt(w / max(w.sum(), 1.0))
        Aw = np.vstack([A * sw[:, None], np.sqrt(prior) * np.eye(N)])
        bw = np.concatenate([b * sw, np.sqrt(prior) * np.ones(N)])
        from scipy.optimize import lsq_linear    # at use: the coordinator imports this module at start
        g_new = lsq_linear(Aw, bw, bounds=(0.0, max_gain), method="bvls", tol=1e-12).x
        r = A @ g_new - b
        kept = w > 0
        mad = 1.4826 * float(np.median(np.abs(r[kept] - np.median(r[kept])))) if kept.any() else 0.0
        sigma_new = max(mad, noise_floor)
        converged = np.max(np.abs(g_new - g)) < 1e-6 and abs(sigma_new - sigma) < 1e-3 * sigma
        g, sigma = g_new, sigma_new
        if robust:
            u = r / (TUKEY_C * sigma)
            w = np.where(np.abs(u) < 1.0, (1.0 - u * u) ** 2, 0.0)
        if converged and done > 1:
            break
    # the uncertainty: the weighted normal matrix (with the prior) and the inliers' spread
    Aw = A * np.sqrt(w)[:, None]
    cov = np.linalg.pinv(Aw.T @ Aw + (sigma / prior_sd) ** 2 * np.eye(N))
    stderr = sigma * np.sqrt(np.maximum(np.diag(cov), 0.0))
    norms = np.linalg.norm(Aw, axis=0)
    if np.all(norms > 0):
        sv = np.linalg.svd(Aw / norms, compute_uv=False)
        condition = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    else:
        condition = float("inf")
    return GainFit(gains=g, stderr=stderr, condition=condition, inliers=float(np.mean(w > 0)), residual=sigma,
                   iterations=done, prior=prior)


def steady_cells(whites: Sequence[np.ndarray], *, drop: float = 0.15, size: int = 3) -> np.ndarray:
    """(h, w) bool: grid cells away from every footprint edge, where each projector's light (its
    white's luminance) varies over the ``size`` x ``size`` cells around by less than ``drop`` of
    its largest value there, or is 0 throughout. At an edge the light steps inside a cell, and a
    prediction sampled at the cell's centre is least exact."""
    if not len(whites):
        raise ValueError("at least one projector's light is needed")
    ok = None
    for wt in whites:
        y = np.asarray(wt, np.float32).sum(axis=-1)
        lo = cv2.erode(y, np.ones((size, size), np.uint8), borderType=cv2.BORDER_REPLICATE)
        hi = cv2.dilate(y, np.ones((size, size), np.uint8), borderType=cv2.BORDER_REPLICATE)
        here = ~((hi > 0) & (lo < (1.0 - drop) * hi))
        ok = here if ok is None else ok & here
    return ok


def _bounded(G: np.ndarray, rhs: np.ndarray, hi: float) -> np.ndarray:
    """argmin h'Gh - 2 h'rhs over 0 <= h <= hi, for a small positive-definite G."""
    try:
        h = np.linalg.solve(G, rhs)
    except np.linalg.LinAlgError:
        h = np.full(len(rhs), np.nan)
    if np.all(np.isfinite(h)) and np.all(h >= 0) and np.all(h <= hi):
        return h
    L = np.linalg.cholesky(G + 1e-12 * np.trace(G) * np.eye(len(rhs)))
    from scipy.optimize import lsq_linear
    return lsq_linear(L.T, np.linalg.solve(L, rhs), bounds=(0.0, hi), method="bvls").x


def fit_changes(capture: np.ndarray, columns: Sequence[np.ndarray], *, valid: np.ndarray | None = None,
                baseline: Sequence[float] | None = None, max_changes: int = 2, threshold: float = 25.0, min_change: float = 0.05, max_gain: float = 1.5,
                robust: bool = True, iterations: int = 3, floor: float = 0.02,
                noise_floor: float = 0.002) -> GainFit:
    """Which lamps changed, and their gains: every other projector's gain is its ``baseline`` (1:
as measured; or what an earlier check found).

    For k = 1 .. ``max_changes`` every set of k projectors is tried, each with its gains free in
    0..``max_gain`` (a small bounded least-squares problem over the normal equations of the
    relative residuals, as :func:`fit_gains` weighs them); the best set of k is taken when it
    lowers the residual below the best of k - 1 by more than ``threshold`` times the residuals'
    robust variance (25: five standard deviations for one unknown) and each of its gains moved by
    at least ``min_change``. Robust (Tukey) weights are refitted ``iterations`` times.

    Parameters
    ----------
    capture : (h, w, C) float32
    columns : sequence of N (h, w, C) float32
        As for :func:`fit_gains`.
    valid : (h, w) bool, optional
        Cells to use (e.g. :func:`steady_cells` within the covered region).
    baseline : (N,) floats, optional
        The gains held by the projectors that did not change (default all 1); a change is a move
        away from it by at least ``min_change``.

    Returns
    -------
    GainFit
        ``gains`` the baseline but for ``changed``; ``stderr`` each gain's standard error were it the one
        to change (the others held); ``condition`` that of the whole design, for the record.
    """
    if not (max_changes >= 1 and threshold > 0 and max_gain > 0 and iterations >= 1 and noise_floor > 0):
        raise ValueError("max_changes >= 1, threshold, max_gain and noise_floor > 0, iterations >= 1")
    A, b = _design(capture, columns, valid, floor)
    M, N = A.shape
    if M < N:
        raise ValueError(f"{M} usable measurements cannot fit {N} gains (is the camera seeing the projectors?)")
    from itertools import combinations

    base = np.ones(N) if baseline is None else np.asarray(baseline, np.float64)
    if base.shape != (N,) or not np.all(np.isfinite(base)):
        raise ValueError(f"baseline must hold {N} finite gains, got shape {base.shape}")
    w = np.ones(M)
    g = base.copy()
    changed: tuple[int, ...] = ()
    sigma = noise_floor
    for _ in range(iterations):
        Aw = A * w[:, None]
        G = Aw.T @ A
        c = Aw.T @ b
        bb = float(np.sum(w * b * b))
        Gb = G @ base

        def rss(x: np.ndarray) -> float:
            return bb - 2.0 * float(x @ c) + float(x @ G @ x)

        r = A @ g - b
        kept = w > 0
        sigma = max(1.4826 * float(np.median(np.abs(r[kept] - np.median(r[kept])))), noise_floor) if kept.any() \
            else noise_floor
        best_g, best_set, best_rss = base.copy(), (), rss(base)
        for k in range(1, min(max_changes, N) + 1):
            found = None
            for T in combinations(range(N), k):
                idx = list(T)
                # the others held at their baseline: the right-hand side loses their light
                rhs = c[idx] - (Gb[idx] - G[np.ix_(idx, idx)] @ base[idx])
                h = _bounded(G[np.ix_(idx, idx)], rhs, max_gain)
                x = base.copy()
                x[idx] = h
                v = rss(x)
                if found is None or v < found[0]:
                    found = (v, T, x)
            v, T, x = found
            if (best_rss - v) / sigma ** 2 < threshold or np.any(np.abs(x[list(T)] - base[list(T)]) < min_change):
                break
            best_g, best_set, best_rss = x, T, v
        g, changed = best_g, best_set
        if not robust:
            break
        r = A @ g - b
        u = r / (TUKEY_C * sigma)
        w = np.where(np.abs(u) < 1.0, (1.0 - u * u) ** 2, 0.0)
    Aw = A * np.sqrt(w)[:, None]
    diag = np.einsum("ij,ij->j", Aw, Aw)
    stderr = sigma / np.sqrt(np.maximum(diag, 1e-30))
    norms = np.sqrt(diag)
    if np.all(norms > 0):
        sv = np.linalg.svd(Aw / norms, compute_uv=False)
        condition = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    else:
        condition = float("inf")
    return GainFit(gains=g, stderr=stderr, condition=condition, inliers=float(np.mean(w > 0)), residual=sigma,
                   iterations=iterations, changed=tuple(int(i) for i in changed))


def columns_for(slots: Sequence[str], white: Mapping[str, np.ndarray], black: Mapping[str, np.ndarray],
                value: Mapping[str, np.ndarray], maps: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None
                ) -> list[np.ndarray]:
    """:func:`predicted_light` of each of ``slots`` in order (``maps``: slot -> (alpha, beta) on the
    grid, absent: none)."""
    maps = maps or {}
    return [predicted_light(white[s], black[s], value[s], *maps.get(s, (None, None))) for s in slots]
