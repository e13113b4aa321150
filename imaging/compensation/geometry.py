"""Where content, projector and camera pixels meet on a planar rig: the numerics that place
the light transport's windows and the compensation target.

``content -> camera`` is the table -> camera homography of ``calibration/cameras.json``
composed with the content's placement on the table (:func:`content_to_camera`). From it and
the projectors' poses follow the PSF recovery radius (:func:`psf_radius`), the dot-grid
spacing whose windows stay apart (:func:`choose_spacing`), the share of a measured ``L`` its
windows may have cut off (:func:`edge_energy`), the target as the camera would see it on a
blur-free rig (:func:`camera_target`) at a level the rig reaches (:func:`target_level`) and the camera
rectangle inside the content (:func:`inscribed_region`).
"""
from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
import scipy.sparse as sp

from imaging.calibration.planar import apply_homography
from imaging.compensation.errors import CompensationError
from imaging.compensation.transport import dot_gap, transport_windows
from protos.spaces import as_linear, content_to_table

__all__ = [
    "EDGE_WARNING",
    "content_to_camera",
    "choose_spacing",
    "psf_profile",
    "psf_radius",
    "psf_radius_at_scales",
    "edge_energy",
    "camera_target",
    "inscribed_region",
    "row_white",
    "target_level",
]

#: share of a measured L's light on its windows' outer ring above which a larger radius is advised
EDGE_WARNING = 0.06
#: percentile of the rig's white (inside the content) the target's full white is a fraction of
TARGET_PERCENTILE = 2.0


def content_to_camera(rig_dir: str | Path, content_size: tuple[int, int], *, camera: int = 0,
                      table_mm: tuple[float, float] | None = None) -> tuple[np.ndarray, tuple[int, int]]:
    """Content -> camera homography of a calibrated planar rig.

    Parameters
    ----------
    rig_dir : path
        Rig directory holding ``calibration/cameras.json`` (written by calibration).
    content_size : (W, H)
        The rig's content size in pixels.
    camera : int
        Camera index.
    table_mm : (W, H) mm, optional
        Table size; default: the one the calibration used.

    Returns
    -------
    H : (3, 3) float64
        Content pixels -> camera pixels, ``H[2, 2] == 1``.
    camera_size : (W, H)
        The camera image size the mapping was made at.

    Raises
    ------
    CompensationError
        No calibration, no table mapping for that camera, or another content size.
    """
    f = Path(rig_dir) / "calibration" / "cameras.json"
    try:
        doc = json.loads(f.read_text())
    except FileNotFoundError:
        raise CompensationError(f"{f}: no camera calibration; run `shadowless calibrate` first (compensation "
                                "needs the table -> camera mapping)") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise CompensationError(f"{f}: unreadable camera calibration ({exc}); run `shadowless calibrate` again") from exc
    entry = next((c for c in doc.get("cameras", []) if int(c.get("camera", -1)) == camera), None)
    if entry is None or "table_to_camera" not in entry:
        raise CompensationError(f"{f}: camera {camera} has no table mapping; calibrate with table points for it")
    stored = doc.get("content_size")
    if stored is not None and tuple(int(v) for v in stored) != tuple(content_size):
        raise CompensationError(f"{f}: calibrated for content {stored[0]}x{stored[1]}, the rig's content is now "
                                f"{content_size[0]}x{content_size[1]}: calibrate again")
    tmm = tuple(float(v) for v in (table_mm or doc.get("table_mm") or (1200.0, 600.0)))
    H = np.asarray(entry["table_to_camera"], np.float64) @ content_to_table(content_size, tmm)
    if H.shape != (3, 3) or not np.all(np.isfinite(H)) or abs(H[2, 2]) < 1e-15:
        raise CompensationError(f"{f}: camera {camera}'s table mapping is degenerate; calibrate again")
    size = tuple(int(v) for v in entry.get("size", (0, 0)))
    return H / H[2, 2], size


def choose_spacing(homography: np.ndarray, content_shape: Sequence[int], camera_shape: Sequence[int], radius: int, *,
                   guard: int = 0, limit: int = 64) -> int:
    """Smallest dot-grid spacing ``S`` whose dots' camera windows never overlap (plus ``guard`` px).

    Parameters
    ----------
    homography : (3, 3) float64
        Content -> camera.
    content_shape, camera_shape : (H, W)
    radius : int
        PSF recovery radius R; windows are ``2R + 1`` camera pixels wide.

    Raises
    ------
    CompensationError
        If no spacing up to ``limit`` separates the windows (content far coarser than the camera).
    """
    base, _, _ = transport_windows(homography, content_shape, camera_shape, 0)
    need = 2 * radius + 1 + guard
    for s in range(1, limit + 1):
        if dot_gap(base, content_shape, s) >= need:
            return s
    raise CompensationError(f"no dot spacing up to {limit} separates {2 * radius + 1}-pixel windows: the content is "
                            "much coarser than the camera; lower the radius")


def _jacobian_scale(homography: np.ndarray, x: float, y: float) -> float:
    """``sqrt(|det J|)`` of a homography at ``(x, y)``: how many destination px one source px spans."""
    d = 0.5
    p = apply_homography(np.asarray(homography, np.float64),
                         np.array([[x - d, y], [x + d, y], [x, y - d], [x, y + d]]))
    jx = p[1] - p[0]
    jy = p[3] - p[2]
    return float(np.sqrt(abs(jx[0] * jy[1] - jx[1] * jy[0])))


def psf_profile(c: float, p: float, *, blur: float = 0.0, step: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """1-D light profile of one content pixel on the camera (model), for :func:`psf_radius`.

    A node samples the content bilinearly: projector pixel centres within one content pixel
    (``c`` camera px) of a content pixel get weight ``1 - |d| / c`` (a triangle); each of them
    lights a box one projector pixel (``p`` camera px) wide; an optional Gaussian ``blur`` (sigma,
    camera px) stands for defocus. Returns ``(x, f)``: positions (camera px) and the normalised
    profile (float64), ``f`` summing to 1 over the grid of spacing ``step``.
    """
    half = c + p / 2 + 4 * blur + 1
    x = np.arange(-half, half + step / 2, step)
    f = np.clip(1 - np.abs(x) / max(c, step), 0, None)
    m = max(1, int(round(p / step)))
    box = np.ones(m + 1 - m % 2)  # odd length: the convolution stays centred
    f = np.convolve(f, box, mode="same")
    if blur > 0:
        g = np.exp(-0.5 * (x / blur) ** 2)
        f = np.convolve(f, g / g.sum(), mode="same")
    return x, f / f.sum()


def psf_radius(homography: np.ndarray, poses: Sequence[np.ndarray], content_size: tuple[int, int], *,
               tolerance: float = 1e-4, blur: float = 0.0, limit: int = 16) -> int:
    """The smallest camera-pixel radius whose windows hold a content pixel's light, from the rig's geometry.

    Scales at the content's centre: ``c`` camera px per content px (``homography``, content ->
    camera) and ``p`` camera px per projector px (the median over ``poses``, content ->
    projector). The light profile (:func:`psf_profile`) is integrated over camera pixels for
    sub-pixel offsets of the window centre in [-0.5, 0.5]; the radius is the smallest whose
    ``(2R+1)^2`` window leaves at most ``tolerance`` of the squared light (the Frobenius norm of a
    column of ``L``) outside, on average. A radius larger than needed only adds noisy entries to
    a measured ``L`` (they cost quality); defocus needs more (``blur``, or see :func:`edge_energy`).
    """
    w, h = content_size
    x0, y0 = (w - 1) / 2, (h - 1) / 2
    c = _jacobian_scale(homography, x0, y0)
    p = float(np.median([c / _jacobian_scale(pose, x0, y0) for pose in poses])) if len(poses) else c
    return psf_radius_at_scales(c, p, tolerance=tolerance, blur=blur, limit=limit)


def psf_radius_at_scales(c: float, p: float, *, tolerance: float = 1e-4, blur: float = 0.0, limit: int = 16) -> int:
    """:func:`psf_radius` from the scales themselves: ``c`` camera px per content px, ``p`` camera px per
    projector px (a mesh rig has no homography; :mod:`imaging.compensation.mesh_geometry` measures them)."""
    step = 0.01
    x, f = psf_profile(c, p, blur=blur, step=step)
    cdf = np.concatenate([[0.0], np.cumsum(f)])
    n = int(np.ceil(x[-1])) + 2
    for r in range(1, limit + 1):
        missing = []
        for u in np.linspace(-0.5, 0.5, 11):
            edges = np.arange(-n, n + 1) + 0.5 + u          # camera pixel edges around the rounded centre
            idx = np.clip(np.searchsorted(x, edges), 0, len(f))
            v = np.diff(cdf[idx])                            # light of camera pixels k = -n .. n-1
            k = np.arange(-n, n) + 1
            e = v ** 2
            inside = e[np.abs(k) <= r].sum() / e.sum()
            missing.append(1 - inside ** 2)                   # separable: the same profile along y
        if float(np.mean(missing)) <= tolerance:
            return r
    return limit


def edge_energy(L: sp.spmatrix, homography: np.ndarray, content_shape: Sequence[int], camera_shape: Sequence[int],
                radius: int) -> float:
    """Share of a measured ``L``'s squared entries (its Frobenius norm) on the outer ring of its windows.

    The light of a content pixel decays away from its centre, so what a ``(2R+1)^2`` window
    cut off is at most about what lies on its outer ring: a share near zero says the windows
    hold the PSFs; a few per cent says light was cut off (missing from ``L``): measure with a
    larger radius (see :data:`EDGE_WARNING`).
    """
    wc = int(camera_shape[1])
    base, _, _ = transport_windows(homography, content_shape, camera_shape, 0)
    csc = sp.csc_matrix(L)
    cols = np.repeat(np.arange(csc.shape[1]), np.diff(csc.indptr))
    rows = csc.indices.astype(np.int64)
    dx = rows % wc - base[cols, 0]
    dy = rows // wc - base[cols, 1]
    ring = (np.abs(dx) == radius) | (np.abs(dy) == radius)
    v = csc.data.astype(np.float64) ** 2
    total = float(v.sum())
    return float(v[ring].sum()) / total if total > 0 else 0.0


def camera_target(image: np.ndarray, homography: np.ndarray, camera_shape: Sequence[int]) -> np.ndarray:
    """The content image as the camera would see it on a blur-free rig: ``(Hc, Wc, C) float32``.

    ``image`` is ``(H, W)`` or ``(H, W, C)`` linear content; the content -> camera
    ``homography`` resamples it bilinearly (0 outside the content).
    """
    img = as_linear(image)
    hc, wc = int(camera_shape[0]), int(camera_shape[1])
    out = cv2.warpPerspective(img, np.asarray(homography, np.float64), (wc, hc), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    if out.ndim == 2:
        out = out[:, :, None]
    return np.ascontiguousarray(out, dtype=np.float32)


def inscribed_region(homography: np.ndarray, content_size: tuple[int, int], camera_shape: Sequence[int], *,
                     margin: int = 4) -> tuple[slice, slice]:
    """The largest axis-aligned camera rectangle inside the content's outline, shrunk by ``margin`` px.

    The outline is the content rectangle's four corners mapped by ``homography``
    (content -> camera); for a camera looking roughly down, the inscribed rectangle
    is bounded by the inner corner coordinates. Returns ``(rows, cols)`` slices.

    Raises
    ------
    CompensationError
        If less than 8 x 8 camera pixels remain (the camera hardly sees the content).
    """
    w, h = content_size
    corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
    mapped = apply_homography(np.asarray(homography, np.float64), corners)
    if not np.all(np.isfinite(mapped)):
        raise CompensationError("the content's corners do not map into the camera image; check the camera calibration")
    x, y = mapped[:, 0], mapped[:, 1]
    hc, wc = int(camera_shape[0]), int(camera_shape[1])
    x0 = max(math.ceil(max(x[0], x[3])) + margin, 0)
    x1 = min(math.floor(min(x[1], x[2])) - margin + 1, wc)
    y0 = max(math.ceil(max(y[0], y[1])) + margin, 0)
    y1 = min(math.floor(min(y[2], y[3])) - margin + 1, hc)
    if x1 - x0 < 8 or y1 - y0 < 8:
        raise CompensationError("the camera sees too little of the content (less than 8x8 pixels inside it); "
                                "check the camera calibration")
    return slice(y0, y1), slice(x0, x1)


def row_white(L: sp.spmatrix, camera_shape: Sequence[int]) -> np.ndarray:
    """The rig's light above black at full white content, ``L @ 1``: ``(Hc, Wc) float32``."""
    return np.asarray(L.sum(axis=1), dtype=np.float32).reshape(int(camera_shape[0]), int(camera_shape[1]))


def target_level(white: np.ndarray, region: tuple[slice, slice], level: float) -> float:
    """Camera signal of the target's full white: ``level`` times the rig's white (:func:`row_white`) at its
    2nd percentile inside ``region``, so the target stays within what the rig reaches almost everywhere."""
    return level * float(np.percentile(white[region], TARGET_PERCENTILE))
