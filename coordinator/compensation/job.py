"""Blur compensation on the rig: the ``response``, ``transport``, ``compensate`` and
``compensate_sequence`` coordinator jobs, and the numerics that tie captures to the rig.

Everything after the response stage works in linear luminance (DESIGN.md section 1): each
node applies ``gain`` then its inverse-response LUT, so the camera sees ``c = L p + b`` for
the one content image ``p`` every projector shows (``b``: the rig's black level).

``response`` (per projector, the others black)
    Grey levels shown by that projector alone (projector space, LUT off). The default
    ``patches`` mode shows a white frame, then frames of grey patches (``rows x cols``
    levels at once, each level at two positions); a patch's normalised response is
    ``mean(capture - black) / mean(white - black)`` over the camera pixels it covers (the
    pose and the table -> camera mapping place it), which cancels the projector's fall-off
    across the table. ``full`` mode shows one uniform grey level per capture. A monotone
    curve is fitted per channel (:func:`~coordinator.compensation.fit_response`), its
    inverse LUT stored and pushed (``set_slot``), then one uniform gain is chosen so the
    rig matches a reference brightness, and the rig's light after the LUTs is checked to
    be a straight line of the requested level.
``transport``
    ``S*S`` dot-grid captures with every projector showing the same content pattern
    through its pose (plus one black capture): the summed light transport ``L`` (camera
    pixels x content pixels), stored in ``compensation/transport.npz``. The PSF radius
    follows the geometry (:func:`psf_radius`: bilinear lookup, projector and camera pixel
    sizes) and the spacing is the smallest that keeps the dots' windows apart
    (:func:`choose_spacing`); a measured ``L`` whose windows cut light is reported
    (:func:`edge_energy`). With ``baseline``, each projector's ``L_i`` is measured too, one
    projector at a time (``N*S*S`` captures), for the conventional method only.
``compensate``
    One bounded least-squares solve ``p' = argmin ||L p - c'||^2 + lam ||p - p0||^2,
    0 <= p <= 1`` for an image (:class:`RidgeProblem`; ``p0`` the uncompensated image, the
    small ridge keeps the measured ``L``'s noise out of the result); the result becomes the
    rig's content (float32) and is shown on every node. With ``evaluate``, the result
    without compensation, with ours and (``baseline``) with the per-projector method are
    captured and scored against the target (PSNR/SSIM) and put side by side in
    ``compensation/quality.png``.
``compensate_sequence``
    Frame-by-frame warm-started solves of a sequence, then synchronized playback.

Spaces: ``L`` maps ``content`` pixels to ``camera`` pixels; the content -> camera mapping is
the table -> camera homography of ``calibration/cameras.json`` composed with the content
placement on the table (:func:`content_to_camera`). Planar (homography) poses only.

Rig directory (all writes atomic)::

    compensation/responses/<slot>.json   fitted response of a projector (its LUT is in luts/)
    compensation/response.json           brightness match and linearity of the last run
    compensation/transport.npz           L and its metadata (fingerprint, radius, spacing, ...)
    compensation/black.npy               (Hc, Wc, 3) float32 black capture of that measurement
    compensation/baseline/<slot>.npz     the per-projector L_i (baseline only)
    compensation/result.json             figures of the last solve (the result is the content)
    compensation/quality.json, .png      the last evaluation
    compensation/sequence.json           figures of the last compensated sequence

A stored ``L`` is reused while the rig is as it was measured (poses, LUTs, gains, content
size, camera, table mapping) and its dot grid matches whatever radius, spacing or frames the
caller sets; ``force`` measures again. Responses and baseline
matrices are stored per projector, so an interrupted run resumes where it stopped.
"""
from __future__ import annotations

import asyncio
import base64
import hashlib
import json
import math
import queue
import time
import zlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import scipy.sparse as sp

from coordinator.compensation.errors import CompensationError, TransportFileError
from coordinator.compensation.quality import quality, side_by_side, srgb_to_linear
from coordinator.compensation.response import (
    Response,
    apply_lut,
    brightness_scale,
    fit_response,
    grey_levels,
    inverse_lut,
    response_mask,
    verify_linearity,
)
from coordinator.compensation.response import measure_response as response_means
from coordinator.compensation.solver import TransportOperator, solve
from coordinator.compensation.transport import (
    DotGrid,
    apply_homography,
    load_transport,
    save_transport,
    transport_windows,
)
from coordinator.compensation.transport import measure_transport as transport_from_captures
from coordinator.jobs import JobError
from coordinator.rig import Content, HomographyPose
from coordinator.store import atomic_save_npy, atomic_write_bytes, atomic_write_json

__all__ = [
    "measure_response",
    "measure_transport",
    "compensate",
    "compensate_sequence",
    "ContentWarmStart",
    "RidgeProblem",
    "content_to_camera",
    "projector_frame",
    "choose_spacing",
    "psf_radius",
    "psf_profile",
    "edge_energy",
    "camera_target",
    "inscribed_region",
    "patch_labels",
    "patch_response",
    "encode_image_param",
    "decode_image_param",
]

SUBDIR = "compensation"
#: fewest camera pixels a response patch must cover to count
MIN_PATCH_PIXELS = 12
#: fraction of a measured L's light on its windows' outer ring above which a larger radius is advised
EDGE_WARNING = 0.06
#: default ridge weight of the solves, relative to ||L||_2^2 (see RidgeProblem)
DEFAULT_REGULARIZATION = 0.02
#: relative white level below which the rig's light is "not reached" when choosing the target level
TARGET_PERCENTILE = 2.0


# ====================================================================== numerics
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
    from coordinator.calibration.planar import content_to_table

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


def projector_frame(content: np.ndarray, pose: np.ndarray, size: tuple[int, int], *, lut: np.ndarray | None = None,
                    gain: float = 1.0, apply: bool = True) -> np.ndarray:
    """What a node outputs for linear content, computed on the coordinator: ``(h, w, 3) uint8``.

    The same steps as the node's shader (``node/render/pipeline.glsl``): bilinear lookup of
    the content through the pose (``cv2.warpPerspective``, ``INTER_LINEAR``, 0 outside),
    then ``gain`` and the inverse-response LUT when ``apply``, then ``round(255 * value)``.

    Parameters
    ----------
    content : (H, W) or (H, W, C) float32/uint8/uint16
        Linear content (integers are normalised by their maximum value).
    pose : (3, 3) float64
        Content px -> projector px.
    size : (w, h)
        Projector size.
    lut : (C, E) float32, optional
        Inverse-response LUT (None: identity).
    """
    img = _as_linear(content)
    w, h = (int(v) for v in size)
    warped = cv2.warpPerspective(img, np.asarray(pose, np.float64), (w, h), flags=cv2.INTER_LINEAR,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    if warped.ndim == 2:
        warped = warped[:, :, None]
    if warped.shape[2] == 1:
        warped = np.repeat(warped, 3, axis=2)
    warped = warped[:, :, :3]
    if not apply:
        return np.rint(np.clip(warped, 0.0, 1.0) * 255.0).astype(np.uint8)
    table = np.array([[0.0, 1.0]] * 3, np.float32) if lut is None else np.asarray(lut, np.float32)
    if table.shape[0] == 1:
        table = np.repeat(table, 3, axis=0)
    return apply_lut(table, warped, gain=gain)


def _as_linear(image: np.ndarray) -> np.ndarray:
    a = np.asarray(image)
    if a.dtype == np.uint8:
        return a.astype(np.float32) / np.float32(255)
    if a.dtype == np.uint16:
        return a.astype(np.float32) / np.float32(65535)
    return a.astype(np.float32, copy=False)


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
    h, w = int(content_shape[0]), int(content_shape[1])
    bx = base[:, 0].reshape(h, w)
    by = base[:, 1].reshape(h, w)
    need = 2 * radius + 1 + guard
    for s in range(1, limit + 1):
        gaps = []
        if w > s:
            gaps.append(np.maximum(np.abs(bx[:, s:] - bx[:, :-s]), np.abs(by[:, s:] - by[:, :-s])).min())
        if h > s:
            gaps.append(np.maximum(np.abs(bx[s:] - bx[:-s]), np.abs(by[s:] - by[:-s])).min())
        if h > s and w > s:
            gaps.append(np.maximum(np.abs(bx[s:, s:] - bx[:-s, :-s]), np.abs(by[s:, s:] - by[:-s, :-s])).min())
            gaps.append(np.maximum(np.abs(bx[s:, :-s] - bx[:-s, s:]), np.abs(by[s:, :-s] - by[:-s, s:])).min())
        if not gaps or min(gaps) >= need:
            return s
    raise CompensationError(f"no dot spacing up to {limit} separates {2 * radius + 1}-pixel windows: the content is "
                            "much coarser than the camera; lower the radius")


def _jacobian_scale(homography: np.ndarray, x: float, y: float) -> float:
    """``sqrt(|det J|)`` of a homography at ``(x, y)``: how many destination px one source px spans."""
    h = np.asarray(homography, np.float64)
    d = 0.5
    px, py = apply_homography(h, np.array([x - d, x + d, x, x]), np.array([y, y, y - d, y + d]))
    jx = np.array([px[1] - px[0], py[1] - py[0]])
    jy = np.array([px[3] - px[2], py[3] - py[2]])
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
    larger radius.
    """
    hc, wc = int(camera_shape[0]), int(camera_shape[1])
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
    img = _as_linear(image)
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
    x, y = apply_homography(homography, corners[:, 0], corners[:, 1])
    hc, wc = int(camera_shape[0]), int(camera_shape[1])
    x0 = max(math.ceil(max(x[0], x[3])) + margin, 0)
    x1 = min(math.floor(min(x[1], x[2])) - margin + 1, wc)
    y0 = max(math.ceil(max(y[0], y[1])) + margin, 0)
    y1 = min(math.floor(min(y[2], y[3])) - margin + 1, hc)
    if x1 - x0 < 8 or y1 - y0 < 8:
        raise CompensationError("the camera sees too little of the content (less than 8x8 pixels inside it); "
                                "check the camera calibration")
    return slice(y0, y1), slice(x0, x1)


def patch_labels(size: tuple[int, int], grid: tuple[int, int], *, border: int = 3) -> np.ndarray:
    """Projector-space patch layout: ``(h, w) int32``, patch ``k = row * cols + col``, -1 on borders.

    The frame is cut into ``rows x cols`` equal patches; ``border`` projector pixels along every
    patch edge (where the blur mixes two levels) are labelled -1.
    """
    w, h = (int(v) for v in size)
    rows, cols = (int(v) for v in grid)
    if rows < 1 or cols < 1 or w < 2 * cols or h < 2 * rows:
        raise ValueError(f"cannot cut a {w}x{h} frame into {rows}x{cols} patches")
    ys = np.minimum((np.arange(h) * rows) // h, rows - 1)
    xs = np.minimum((np.arange(w) * cols) // w, cols - 1)
    labels = (ys[:, None] * cols + xs[None, :]).astype(np.int32)
    if border > 0:
        edge = np.zeros((h, w), bool)
        edge[:, :border] = edge[:, -border:] = True
        edge[:border, :] = edge[-border:, :] = True
        dy = np.diff(ys) != 0
        dx = np.diff(xs) != 0
        for i in np.flatnonzero(dy):
            edge[max(0, i - border + 1): i + border + 1, :] = True
        for i in np.flatnonzero(dx):
            edge[:, max(0, i - border + 1): i + border + 1] = True
        labels[edge] = -1
    return labels


def patch_response(captures: Sequence[np.ndarray], layouts: Sequence[np.ndarray], *, white: np.ndarray,
                   black: np.ndarray, camera_labels: np.ndarray, valid: np.ndarray,
                   min_pixels: int = MIN_PATCH_PIXELS) -> tuple[np.ndarray, np.ndarray]:
    """Normalised response of the patches of several captures.

    Parameters
    ----------
    captures : sequence of (Hc, Wc, C) float32
        Capture ``j`` shows level ``layouts[j][k]`` in patch ``k``.
    layouts : sequence of (P,) float64
        The input value each patch showed, per capture.
    white, black : (Hc, Wc, C) float32
        The projector at full white alone, and every projector black.
    camera_labels : (Hc, Wc) int32
        Patch index seen by each camera pixel (-1: none).
    valid : (Hc, Wc) bool
        Camera pixels the projector lights well.

    Returns
    -------
    levels : (M,) float64
        Input values of the usable patches.
    rho : (M, C) float64
        ``mean(capture - black) / mean(white - black)`` over each patch's pixels.
    """
    wb = np.asarray(white, np.float64) - np.asarray(black, np.float64)
    if wb.ndim == 2:
        wb = wb[:, :, None]
    levels: list[float] = []
    rhos: list[np.ndarray] = []
    lab = np.where(valid, camera_labels, -1)
    flat = lab.ravel()
    order = np.argsort(flat, kind="stable")
    bounds = np.searchsorted(flat[order], np.arange(-1, int(flat.max(initial=-1)) + 2))
    den_cache: dict[int, np.ndarray] = {}
    for cap, layout in zip(captures, layouts):
        d = np.asarray(cap, np.float64) - np.asarray(black, np.float64)
        if d.ndim == 2:
            d = d[:, :, None]
        d = d.reshape(-1, d.shape[2])
        wbf = wb.reshape(-1, wb.shape[2])
        for k, level in enumerate(np.asarray(layout, np.float64)):
            if k + 1 >= len(bounds) - 1:
                continue
            idx = order[bounds[k + 1]: bounds[k + 2]]
            if idx.size < min_pixels:
                continue
            if k not in den_cache:
                den_cache[k] = wbf[idx].mean(axis=0)
            den = den_cache[k]
            if np.any(den <= 0):
                continue
            levels.append(float(level))
            rhos.append(d[idx].mean(axis=0) / den)
    if not levels:
        raise CompensationError("no response patch covers enough lit camera pixels; check the camera calibration")
    return np.asarray(levels), np.stack(rhos)


def _patch_layouts(levels: np.ndarray, patches: int, repeats: int, seed: int) -> list[np.ndarray]:
    """Assign interior levels to patches: every level ``repeats`` times, at different patches when possible."""
    rng = np.random.default_rng(seed)
    pool = np.concatenate([rng.permutation(levels) for _ in range(repeats)])
    count = math.ceil(len(pool) / patches)
    pool = np.concatenate([pool, rng.choice(levels, count * patches - len(pool))]) if count * patches > len(pool) else pool
    return [pool[i * patches:(i + 1) * patches] for i in range(count)]


def encode_image_param(path: str | Path) -> dict:
    """An image file as a job parameter: ``{"name", "data"}`` with the file's bytes, compressed and base64."""
    p = Path(path)
    raw = p.read_bytes()
    return {"name": p.name, "data": base64.b64encode(zlib.compress(raw, 6)).decode("ascii")}


def decode_image_param(value: dict) -> tuple[np.ndarray, str]:
    """Inverse of :func:`encode_image_param`: ``(image, name)``; image (H, W, C) uint8/uint16/float32, RGB.

    Raises
    ------
    CompensationError
        If the bytes are not an image OpenCV or numpy can read.
    """
    if not isinstance(value, dict) or not isinstance(value.get("data"), str):
        raise CompensationError("image parameter must be {\"name\": ..., \"data\": base64}")
    name = str(value.get("name", "image"))
    try:
        raw = zlib.decompress(base64.b64decode(value["data"], validate=True))
    except (ValueError, zlib.error) as exc:
        raise CompensationError(f"image {name}: corrupt image parameter ({exc})") from exc
    if name.lower().endswith(".npy") or raw[:6] == b"\x93NUMPY":
        import io

        try:
            img = np.load(io.BytesIO(raw), allow_pickle=False)
        except ValueError as exc:
            raise CompensationError(f"image {name}: not a numpy array file ({exc})") from exc
    else:
        img = cv2.imdecode(np.frombuffer(raw, np.uint8), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise CompensationError(f"image {name}: OpenCV cannot read it (PNG, TIFF, JPEG or .npy expected)")
        if img.ndim == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB if img.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    img = np.asarray(img)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.ndim != 3 or img.shape[2] not in (1, 3, 4) or min(img.shape[:2]) < 2:
        raise CompensationError(f"image {name}: shape {img.shape} is not an (H, W) or (H, W, C) picture")
    if img.dtype not in (np.uint8, np.uint16, np.float32):
        img = img.astype(np.float32)
    if img.dtype == np.float32 and not np.all(np.isfinite(img)):
        raise CompensationError(f"image {name}: contains NaN or infinity")
    return img[:, :, :3], name


def prepare_image(image: np.ndarray, content_size: tuple[int, int], *, srgb: bool = False) -> np.ndarray:
    """An image as linear content at the rig's content size: ``(H, W, C) float32`` in [0, 1].

    Integers are normalised by their maximum (the rig treats content values as linear
    luminance, like `shadowless show`); ``srgb`` decodes sRGB-encoded values first.
    """
    img = _as_linear(image)
    if img.ndim == 2:
        img = img[:, :, None]
    w, h = content_size
    if img.shape[:2] != (h, w):
        interp = cv2.INTER_AREA if img.shape[1] > w else cv2.INTER_LINEAR
        img = cv2.resize(img, (w, h), interpolation=interp)
        if img.ndim == 2:
            img = img[:, :, None]
    img = np.clip(img, 0.0, 1.0)
    if srgb:
        img = srgb_to_linear(img)
    return np.ascontiguousarray(img, dtype=np.float32)


def row_white(L: sp.spmatrix, camera_shape: Sequence[int]) -> np.ndarray:
    """The rig's light above black at full white content, ``L @ 1``: ``(Hc, Wc) float32``."""
    return np.asarray(L.sum(axis=1), dtype=np.float32).reshape(int(camera_shape[0]), int(camera_shape[1]))


def best_scale(prediction: np.ndarray, target: np.ndarray) -> float:
    """The scalar ``a >= 0`` minimising ``||a * prediction - target||^2`` (float64 sums)."""
    p = np.asarray(prediction, np.float64).ravel()
    t = np.asarray(target, np.float64).ravel()
    den = float(np.dot(p, p))
    return max(float(np.dot(p, t)) / den, 0.0) if den > 0 else 0.0


class RidgeProblem:
    """``min ||L x - c'||^2 + lam ||x - x_prior||^2, 0 <= x <= 1`` as one bounded least-squares problem.

    A measured ``L`` carries camera noise; the plain solve fits it, and the content it finds
    carries a fine texture that the real rig shows (lower SSIM). The penalty keeps ``x`` near a
    prior (the uncompensated image, scaled) along directions ``L`` hardly sees; ``lam = mu *
    ||L||_2^2`` makes ``mu`` independent of the rig's brightness. The system is solved as the
    stacked least squares ``[L; sqrt(lam) I] x ~ [c'; sqrt(lam) x_prior]`` with the bounded
    solver of :mod:`coordinator.compensation.solver`.

    Parameters
    ----------
    L : scipy.sparse matrix or TransportOperator, (n_camera, n_content)
    mu : float
        Relative weight (0: the plain problem).
    """

    def __init__(self, L: sp.spmatrix, mu: float) -> None:
        if mu < 0 or not math.isfinite(mu):
            raise ValueError(f"mu must be finite and >= 0, got {mu}")
        self.data = L if isinstance(L, TransportOperator) else TransportOperator(L)
        self.mu = float(mu)
        self.lam = self.mu * self.data.lipschitz() if mu > 0 else 0.0
        self.shape = self.data.shape
        if self.lam > 0:
            eye = sp.identity(self.shape[1], dtype=np.float32, format="csr") * np.float32(math.sqrt(self.lam))
            self.op = TransportOperator(sp.vstack([self.data.L, eye], format="csr"))
        else:
            self.op = self.data

    def target(self, target: np.ndarray, prior: np.ndarray) -> np.ndarray:
        """The stacked target: ``(n_camera [+ n_content], C) float32``."""
        t = np.asarray(target, np.float32)
        channels = t.shape[-1] if t.ndim == 3 else (t.shape[1] if t.ndim == 2 and t.shape[0] == self.shape[0] else 1)
        t = t.reshape(self.shape[0], channels)
        if self.lam == 0:
            return np.ascontiguousarray(t)
        x = np.asarray(prior, np.float32).reshape(self.shape[1], channels)
        return np.ascontiguousarray(np.vstack([t, np.float32(math.sqrt(self.lam)) * x]))

    def data_objective(self, x: np.ndarray, target: np.ndarray) -> float:
        """``||L x - c'||^2`` (float64), without the penalty."""
        from coordinator.compensation.solver import objective

        return objective(self.data, x, target)


class ContentWarmStart:
    """Warm-started compensation of a sequence when content and camera grids differ.

    :class:`~coordinator.compensation.FrameCompensator` adds the target's change to the
    previous solution only when ``L`` is square (content = camera grid). Here the content's own
    change is known: frame ``k`` starts from ``x_{k-1} + a (content_k - content_{k-1})``, where
    ``a`` is the scale that best maps content to the target (``L a content ~ target``), clipped to
    [0, 1]; the first frame (or one after :meth:`reset`) starts from ``a content``. Each frame then
    runs ``iterations`` APG iterations (``first_iterations`` for the first), so the time per
    frame is bounded. With ``mu > 0`` (or a :class:`RidgeProblem` for ``L``) every frame is
    solved with the ridge penalty towards its scaled content.

    Parameters
    ----------
    L : scipy.sparse matrix, TransportOperator or RidgeProblem, (n_camera, n_content)
    iterations, first_iterations : int
    content_shape : (H, W)
    mu : float
        Ridge weight (see :class:`RidgeProblem`; ignored when ``L`` is one).
    solve_options :
        Passed to :func:`~coordinator.compensation.solve` (``tol``, ``threads``, ...).
    """

    def __init__(self, L, *, iterations: int = 4, first_iterations: int = 60, content_shape: Sequence[int],
                 mu: float = 0.0, **solve_options: Any) -> None:
        if iterations < 1 or first_iterations < 1:
            raise ValueError("iteration budgets must be >= 1")
        self.problem = L if isinstance(L, RidgeProblem) else RidgeProblem(L, mu)
        self.op = self.problem.data
        self.iterations, self.first_iterations = iterations, first_iterations
        self.content_shape = (int(content_shape[0]), int(content_shape[1]))
        if self.content_shape[0] * self.content_shape[1] != self.op.shape[1]:
            raise ValueError(f"content_shape {self.content_shape} does not hold L's {self.op.shape[1]} content pixels")
        solve_options.setdefault("gap_tol", 0.0)
        solve_options.setdefault("pg_tol", 0.0)
        self.options = solve_options
        self._x: np.ndarray | None = None
        self._content: np.ndarray | None = None
        self._scale: float | None = None

    @property
    def scale(self) -> float | None:
        """The content -> target scale found on the first frame (None before it)."""
        return self._scale

    def reset(self) -> None:
        """Forget the previous frame (e.g. after a cut)."""
        self._x = self._content = self._scale = None

    def __call__(self, target: np.ndarray, content: np.ndarray):
        """Compensate one frame: ``target`` (Hc, Wc, C) camera signal, ``content`` (H, W, C) linear; a SolveResult."""
        content = np.asarray(content, np.float32)
        if content.ndim == 2:
            content = content[:, :, None]
        if self._x is None or self._content is None or self._content.shape != content.shape:
            flat = content.reshape(-1, content.shape[2])
            self._scale = best_scale(self.op.matvec(flat), np.asarray(target, np.float32).reshape(-1, content.shape[2]))
            x0 = np.clip(content * np.float32(self._scale), 0, 1)
            budget = self.first_iterations
        else:
            x0 = np.clip(self._x.reshape(content.shape) + np.float32(self._scale) * (content - self._content), 0, 1)
            budget = self.iterations
        if self._scale is not None and self.problem.lam > 0:
            prior = np.clip(content * np.float32(self._scale), 0, 1)
            goal = self.problem.target(target, prior)
        else:
            goal = target
        res = solve(self.problem.op, goal, x0=x0, max_iter=budget, content_shape=self.content_shape, **self.options)
        self._x = res.x
        self._content = content
        return res


# ====================================================================== job plumbing
def _dir(rig) -> Path:
    return Path(rig.path) / SUBDIR


def _threadsafe(ctx) -> Callable[..., None]:
    """``ctx.progress`` callable from a worker thread (events are queued on the job's loop)."""
    loop = asyncio.get_running_loop()

    def report(*args, **kwargs) -> None:
        loop.call_soon_threadsafe(lambda: ctx.progress(*args, **kwargs))

    return report


def _throttled(fn: Callable[[int, float], None], period: float = 0.2) -> Callable[[int, float], None]:
    last = [0.0]

    def cb(k: int, f: float) -> None:
        now = time.monotonic()
        if now - last[0] >= period:
            last[0] = now
            fn(k, f)

    return cb


class _Feed:
    """A blocking iterator over captures, fed from the job's loop and consumed on a worker thread."""

    _END = object()

    def __init__(self) -> None:
        self._q: queue.Queue = queue.Queue(maxsize=4)
        self._error: BaseException | None = None

    def offer(self, item: object) -> bool:
        """Queue ``item`` if there is room (the queue is bounded: the consumer sets the pace)."""
        try:
            self._q.put_nowait(item)
            return True
        except queue.Full:
            return False

    def offer_end(self) -> bool:
        """Queue the end of the captures if there is room."""
        return self.offer(self._END)

    def abort(self, exc: BaseException) -> None:
        self._error = exc
        try:
            while True:
                self._q.get_nowait()
        except queue.Empty:
            pass
        self._q.put(self._END)

    def __iter__(self) -> Iterator[np.ndarray]:
        while True:
            item = self._q.get()
            if item is self._END:
                if self._error is not None:
                    raise CompensationError(f"captures stopped: {self._error}")
                return
            yield item


class _Shots:
    """Show, capture (averaging ``frames`` captures of the same pattern), count."""

    def __init__(self, ctx, *, camera: int, settle_s: float, frames: int = 1):
        self.ctx = ctx
        self.camera = camera
        self.settle_s = settle_s
        self.frames = frames
        self.count = 0

    async def _grab(self) -> np.ndarray:
        from coordinator.camera import CameraError

        try:
            img = np.asarray(await self.ctx.capture(self.camera), np.float32)
        except CameraError as exc:
            raise JobError(str(exc)) from exc
        if img.ndim != 3 or img.shape[2] != 3:
            raise JobError(f"camera {self.camera} delivered an image of shape {img.shape}; expected (H, W, 3)")
        self.count += 1
        return img

    async def content(self, image: np.ndarray | None, *, frames: int | None = None) -> np.ndarray:
        """Every projector shows ``image`` (content space, through LUT and gain); the average capture."""
        n = frames or self.frames
        acc = None
        for _ in range(n):
            await self.ctx.show_content(image, apply_lut=True, settle_s=self.settle_s)
            img = await self._grab()
            acc = img if acc is None else acc + img
        return acc / np.float32(n) if n > 1 else acc

    async def projector(self, images: dict[str, np.ndarray | None], *, require: list[str],
                        frames: int | None = None) -> np.ndarray:
        """Projector-space images (others black, LUT off); the average capture."""
        n = frames or self.frames
        acc = None
        for _ in range(n):
            await self.ctx.show(images, settle_s=self.settle_s, require=require)
            img = await self._grab()
            acc = img if acc is None else acc + img
        return acc / np.float32(n) if n > 1 else acc


def _float(params: dict, key: str, default: float, lo: float, hi: float) -> float:
    try:
        v = float(params.get(key, default))
    except (TypeError, ValueError):
        raise JobError(f"{key} must be a number") from None
    if not (lo <= v <= hi) or not math.isfinite(v):
        raise JobError(f"{key} must be in {lo:g}..{hi:g}, got {v:g}")
    return v


def _int(params: dict, key: str, default: int | None, lo: int, hi: int) -> int | None:
    value = params.get(key, default)
    if value is None:
        return None
    try:
        v = int(value)
    except (TypeError, ValueError):
        raise JobError(f"{key} must be an integer") from None
    if not lo <= v <= hi or v != float(value):
        raise JobError(f"{key} must be an integer in {lo}..{hi}, got {value}")
    return v


def _check_known(params: dict, known: set[str], what: str) -> None:
    unknown = sorted(set(params) - known)
    if unknown:
        raise JobError(f"unknown {what} parameter(s) {', '.join(unknown)} (known: {', '.join(sorted(known))})")


def _slots_param(ctx, params: dict, *, need_pose: bool) -> list[str]:
    rig = ctx.rig
    live = ctx.live_slots()
    if params.get("slots") is not None:
        slots = params["slots"]
        if not isinstance(slots, list) or not all(isinstance(s, str) for s in slots) or not slots:
            raise JobError("slots must be a non-empty list of slot names")
        unknown = [s for s in slots if s not in rig.slots]
        if unknown:
            raise JobError(f"slot(s) {', '.join(unknown)} not in rig {rig.config.name!r} (slots: {', '.join(rig.slots)})")
        missing = [s for s in slots if s not in live]
        if missing:
            raise JobError(f"projector(s) {', '.join(missing)} not connected: start their nodes (see `shadowless status`)")
    else:
        slots = list(live)
        if not slots:
            raise JobError("no projector is connected: start the nodes (see `shadowless status`)")
        if need_pose:
            slots = [s for s in slots if rig.slot(s).pose is not None]
    if need_pose:
        for s in slots:
            pose = rig.slot(s).pose
            if pose is None:
                raise JobError(f"projector {s} has no pose: calibrate it first (`shadowless calibrate`)")
            if not isinstance(pose, HomographyPose):
                raise JobError(f"projector {s} has a 3D pose: blur compensation supports planar rigs (a table) only")
        if not slots:
            raise JobError("no connected projector has a pose: calibrate first (`shadowless calibrate`)")
    return slots


def _camera_spec(ctx, camera: int) -> str:
    specs = list(getattr(ctx, "camera_specs", []) or [])
    if camera >= len(specs):
        raise JobError(f"no camera {camera}: the job has {len(specs)} (set `cameras = [\"room://HOST:PORT\"]` in rig.toml, "
                       "or pass --camera)")
    return specs[camera]


def _geometry(ctx, camera: int) -> tuple[np.ndarray, tuple[int, int]]:
    rig = ctx.rig
    cs = (rig.config.content_width, rig.config.content_height)
    try:
        return content_to_camera(rig.path, cs, camera=camera)
    except CompensationError as exc:
        raise JobError(str(exc)) from exc


def _round(v: float, nd: int = 4) -> float | None:
    return None if v is None or not math.isfinite(float(v)) else round(float(v), nd)


# ====================================================================== response
_RESPONSE_KEYS = {"slots", "levels", "mode", "grid", "repeats", "reference", "lut_entries", "settle_s", "camera",
                  "force", "verify_levels", "tolerance", "seed", "keep_going", "frames"}


@dataclass
class _ResponseOptions:
    levels: int
    mode: str
    grid: tuple[int, int]
    repeats: int
    reference: str | float | None
    lut_entries: int
    settle_s: float
    camera: int
    force: bool
    verify_levels: int
    tolerance: float
    seed: int
    keep_going: bool
    frames: int = 1

    @classmethod
    def parse(cls, params: dict) -> "_ResponseOptions":
        _check_known(params, _RESPONSE_KEYS, "response")
        mode = str(params.get("mode", "patches"))
        if mode not in ("patches", "full"):
            raise JobError(f"mode must be 'patches' or 'full', got {mode!r}")
        grid = params.get("grid", [4, 4])
        try:
            grid = (int(grid[0]), int(grid[1]))
        except (TypeError, ValueError, IndexError):
            raise JobError("grid must be [rows, cols]") from None
        if not (1 <= grid[0] <= 16 and 1 <= grid[1] <= 16):
            raise JobError("grid rows and cols must be in 1..16")
        ref = params.get("reference")
        if ref is not None and not isinstance(ref, (str, int, float)):
            raise JobError("reference must be a slot name or a luminance (camera units above black)")
        if isinstance(ref, (int, float)) and not (math.isfinite(ref) and ref > 0):
            raise JobError("a reference luminance must be positive")
        return cls(
            levels=_int(params, "levels", 17, 3, 256), mode=mode, grid=grid,
            repeats=_int(params, "repeats", 2, 1, 8), reference=ref,
            lut_entries=_int(params, "lut_entries", 1024, 1024, 65536),
            settle_s=_float(params, "settle_s", 0.05, 0.0, 30.0), camera=_int(params, "camera", 0, 0, 64),
            force=bool(params.get("force", False)), verify_levels=_int(params, "verify_levels", 6, 3, 64),
            tolerance=_float(params, "tolerance", 0.01, 1e-4, 0.5), seed=_int(params, "seed", 0, 0, 2**31),
            keep_going=bool(params.get("keep_going", True)), frames=_int(params, "frames", 1, 1, 64),
        )


def _response_doc(resp: Response) -> dict:
    return {"levels": resp.levels.tolist(), "curve": resp.curve.tolist(), "black": resp.black.tolist(),
            "peak": resp.peak.tolist(), "gamma": resp.gamma.tolist()}


def _response_from_doc(doc: dict) -> Response:
    return Response(levels=np.asarray(doc["levels"], np.float64), curve=np.asarray(doc["curve"], np.float64),
                    black=np.asarray(doc["black"], np.float64), peak=np.asarray(doc["peak"], np.float64),
                    gamma=np.asarray(doc["gamma"], np.float64))


def _response_fingerprint(ctx, slot: str, opts: _ResponseOptions, H: np.ndarray | None) -> str:
    st = ctx.rig.slot(slot)
    h = hashlib.blake2b(digest_size=8)
    h.update(repr((slot, st.width, st.height, opts.mode, opts.levels, opts.grid, opts.repeats, opts.seed,
                   _camera_spec(ctx, opts.camera), opts.camera, opts.frames)).encode())
    if isinstance(st.pose, HomographyPose):
        h.update(st.pose.matrix.tobytes())
    if H is not None:
        h.update(np.asarray(H, np.float64).tobytes())
    return h.hexdigest()


def _load_stored_response(path: Path, fingerprint: str | None) -> tuple[Response, dict] | None:
    try:
        doc = json.loads(path.read_text())
        if fingerprint is not None and doc.get("fingerprint") != fingerprint:
            return None
        return _response_from_doc(doc["response"]), doc
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError):
        return None


async def measure_response(ctx, params: dict) -> dict:
    """The ``response`` job: each projector's luminance response, LUT, brightness match, linearity check.

    Parameters (JSON)::

        slots          projectors to measure (default: every connected one)
        mode           "patches" (default; needs planar poses and the camera calibration) or "full"
        levels         grey levels from 0 to 1 (default 17)
        grid           [rows, cols] of patches per frame (default [4, 4]); repeats: positions per level (2)
        reference      brightness reference: a slot name (its measured response) or a luminance in camera
                       units above black; default none (gains 1, headroom against the dimmest projector reported)
        lut_entries    LUT size (default 1024, at least 1024)
        verify_levels  linear levels shown through the LUTs to check linearity (6); tolerance (0.01)
        frames         captures averaged per pattern (default 1): a projector alone may give the camera
                       little light, and its patches then carry the camera's noise into the fitted curve
        settle_s, camera, force, seed, keep_going
    """
    t0 = time.monotonic()
    opts = _ResponseOptions.parse(dict(params))
    rig = ctx.rig
    _camera_spec(ctx, opts.camera)
    slots = _slots_param(ctx, params, need_pose=opts.mode == "patches")
    H = None
    if opts.mode == "patches":
        H, _ = _geometry(ctx, opts.camera)
    out_dir = _dir(rig) / "responses"
    shots = _Shots(ctx, camera=opts.camera, settle_s=opts.settle_s, frames=opts.frames)
    sizes = {s: ctx.projector_size(s) for s in slots}
    levels = grey_levels(opts.levels)
    responses: dict[str, Response] = {}
    docs: dict[str, dict] = {}
    failed: dict[str, str] = {}
    todo = []
    for s in slots:
        fp = _response_fingerprint(ctx, s, opts, H)
        stored = None if opts.force else _load_stored_response(out_dir / f"{s}.json", fp)
        if stored is not None and rig.slot(s).lut is not None:
            responses[s], docs[s] = stored[0], {**stored[1], "resumed": True}
        else:
            todo.append(s)
    ctx.log(f"luminance response: {len(todo)} of {len(slots)} projector(s) to measure ({opts.mode} mode)"
            + (f"; {len(slots) - len(todo)} kept from an earlier run" if len(todo) < len(slots) else ""))
    black = None
    if todo:
        ctx.progress("response", "", 0, len(todo), "every projector black")
        black = await shots.projector({s: None for s in slots}, require=[])
    for n, s in enumerate(todo):
        before = shots.count
        try:
            resp, extra = await _measure_one(ctx, shots, s, sizes[s], opts, levels, black, H)
        except (CompensationError, JobError) as exc:
            if not opts.keep_going:
                raise JobError(f"{s}: {exc}") from exc
            failed[s] = str(exc)
            ctx.log(f"{s}: {exc}")
            continue
        lut = await ctx.compute(inverse_lut, resp, opts.lut_entries)
        ctx.set_slot(s, lut=lut, source="response")
        doc = {"slot": s, "fingerprint": _response_fingerprint(ctx, s, opts, H), "mode": opts.mode,
               "captures": shots.count - before, "measured_at": time.time(), "response": _response_doc(resp),
               "lut_entries": opts.lut_entries, **extra}
        atomic_write_json(out_dir / f"{s}.json", doc)
        responses[s], docs[s] = resp, doc
        ctx.progress("response", s, n + 1, len(todo), "fitted", value=float(np.mean(resp.gamma)))
    if not responses:
        raise JobError("no projector's response could be measured: " + "; ".join(failed.values()))
    match = await _brightness(ctx, responses, opts, out_dir)
    linearity = await _verify(ctx, shots, slots, responses, opts, H)
    summary = {
        "mode": opts.mode, "captures": shots.count, "wall_s": round(time.monotonic() - t0, 3),
        "slots": {s: {"gamma": [round(float(g), 4) for g in responses[s].gamma],
                      "black": [_round(float(b), 6) for b in responses[s].black],
                      "peak": [_round(float(p), 6) for p in responses[s].peak],
                      "patches": docs[s].get("patches"), "captures": docs[s].get("captures"),
                      "resumed": bool(docs[s].get("resumed"))} for s in slots if s in responses},
        "failed": failed, "brightness": match, "linearity": linearity,
    }
    atomic_write_json(_dir(rig) / "response.json", {**summary, "finished_at": time.time()})
    if failed:
        raise JobError(f"measured {len(responses)} of {len(slots)} projector(s) (saved; run again to retry the others); "
                       + "; ".join(failed.values()))
    return summary


async def _measure_one(ctx, shots: _Shots, slot: str, size: tuple[int, int], opts: _ResponseOptions,
                       levels: np.ndarray, black: np.ndarray, H: np.ndarray | None) -> tuple[Response, dict]:
    w, h = size
    full = lambda v: np.full((h, w), int(round(255 * v)), np.uint8)  # noqa: E731
    if opts.mode == "full":
        caps = []
        for k, v in enumerate(levels):
            ctx.progress("grey levels", slot, k, len(levels))
            caps.append(black if v == 0 else await shots.projector({slot: full(v)}, require=[slot]))
        white = caps[-1]
        mask = await ctx.compute(response_mask, white, black)
        measured = await ctx.compute(response_means, caps, mask=mask)
        resp = fit_response(levels, measured, channels=3)
        return resp, {"mask_pixels": int(mask.sum())}
    white = await shots.projector({slot: full(1.0)}, require=[slot])
    interior = levels[(levels > 0) & (levels < 1)]
    # the frame is all patches; the bands along patch edges (where blur mixes two levels) are not measured
    shown = patch_labels(size, opts.grid, border=0)
    labels = patch_labels(size, opts.grid, border=max(3, min(w, h) // 40))
    patches = opts.grid[0] * opts.grid[1]
    layouts = _patch_layouts(interior, patches, opts.repeats, opts.seed + zlib.crc32(slot.encode()))
    caps = []
    for j, layout in enumerate(layouts):
        ctx.progress("grey patches", slot, j, len(layouts))
        frame = np.rint(layout[shown] * 255).astype(np.uint8)
        caps.append(await shots.projector({slot: frame}, require=[slot]))

    def reduce() -> tuple[Response, dict]:
        mask = response_mask(white, black)
        pose = ctx.rig.slot(slot).pose.matrix
        proj_to_cam = np.asarray(H, np.float64) @ np.linalg.inv(pose)
        hc, wc = white.shape[:2]
        cam_labels = cv2.warpPerspective(labels.astype(np.float32), proj_to_cam, (wc, hc), flags=cv2.INTER_NEAREST,
                                         borderMode=cv2.BORDER_CONSTANT, borderValue=-1).astype(np.int32)
        lv, rho = patch_response(caps, layouts, white=white, black=black, camera_labels=cam_labels, valid=mask)
        base = response_means([black, white], mask=mask)  # (2, C): black and white means over the lit area
        peak = base[1] - base[0]
        meas_levels = np.concatenate([[0.0], lv, [1.0]])
        measured = np.vstack([base[0], base[0] + rho * peak, base[1]])
        if len(np.unique(meas_levels)) < 3:
            raise CompensationError("too few grey patches landed in the camera image")
        return fit_response(meas_levels, measured, channels=3), {"patches": int(len(lv)), "mask_pixels": int(mask.sum())}

    return await ctx.compute(reduce)


async def _brightness(ctx, responses: dict[str, Response], opts: _ResponseOptions, out_dir: Path) -> dict:
    """One uniform gain for the rig (reference: a slot's white or a luminance); pushes the gains."""
    rig_slots = [s for s in responses if s != opts.reference]
    ref = opts.reference
    if isinstance(ref, str):
        if ref in responses:
            reference = responses[ref]
        else:
            stored = _load_stored_response(out_dir / f"{ref}.json", None)
            if stored is None:
                raise JobError(f"reference {ref!r}: no measured response (measure it first, e.g. "
                               f"`shadowless response --slots {ref}`)")
            reference = stored[0]
        kind = f"slot {ref}"
    elif ref is not None:
        reference = float(ref)
        kind = "luminance"
    else:
        # no reference: report the headroom over the dimmest projector's white, change nothing
        dimmest = min(rig_slots, key=lambda s: float(np.mean(responses[s].peak)))
        reference, kind = responses[dimmest], f"none (headroom over the dimmest projector, {dimmest})"
    match = brightness_scale([responses[s] for s in rig_slots], reference)
    gain = 1.0 if ref is None else match.gain
    if gain > 1.0:
        ctx.log(f"the rig cannot reach the reference brightness ({kind}): it is {match.headroom:.3f} x as bright; "
                "gains left at 1")
        gain = 1.0
    for s in rig_slots:
        if abs(ctx.rig.slot(s).gain - gain) > 1e-9:
            ctx.set_slot(s, gain=gain, source="response")
    ctx.progress("brightness", "", 1, 1, f"gain {gain:.4f}, headroom {match.headroom:.3f}", value=gain)
    return {"reference": kind, "gain": round(gain, 6), "headroom": round(match.headroom, 4),
            "reachable": match.reachable, "channel_headroom": [round(float(v), 4) for v in match.channel_headroom],
            "rig_white": [_round(float(v), 6) for v in match.rig_peak],
            "reference_white": [_round(float(v), 6) for v in match.reference_peak]}


async def _verify(ctx, shots: _Shots, slots: list[str], responses: dict[str, Response], opts: _ResponseOptions,
                  H: np.ndarray | None) -> dict:
    """Show linear levels through every LUT; fit a straight line to the rig's light."""
    cw, ch = ctx.rig.config.content_width, ctx.rig.config.content_height
    ys = np.linspace(0.0, 1.0, opts.verify_levels)
    caps = []
    for k, y in enumerate(ys):
        ctx.progress("linearity", "", k, len(ys), f"level {y:.3f}")
        caps.append(await shots.content(np.full((ch, cw), y, np.float32)))
    ctx.progress("linearity", "", len(ys), len(ys))

    def check() -> dict:
        if H is not None:
            rows, cols = inscribed_region(H, (cw, ch), caps[0].shape[:2], margin=4)
            mask = np.zeros(caps[0].shape[:2], bool)
            mask[rows, cols] = True
            mask &= response_mask(caps[-1], caps[0])
        else:
            mask = response_mask(caps[-1], caps[0])
        measured = response_means(caps, mask=mask)
        lin = verify_linearity(ys, measured, tolerance=opts.tolerance)
        return {"linear": lin.linear, "max_error": round(lin.max_error, 5), "rms_error": round(lin.rms_error, 5),
                "tolerance": lin.tolerance, "slope": [round(float(v), 6) for v in lin.slope],
                "intercept": [round(float(v), 6) for v in lin.intercept], "levels": [round(float(y), 4) for y in ys]}

    out = await ctx.compute(check)
    if not out["linear"]:
        ctx.log(f"warning: the rig's light after the LUTs deviates from a straight line by {100 * out['max_error']:.2f} % "
                f"(tolerance {100 * opts.tolerance:.2f} %)")
    return out


# ====================================================================== transport
_TRANSPORT_KEYS = {"slots", "radius", "spacing", "frames", "settle_s", "camera", "force", "baseline", "baseline_frames",
                   "baseline_exposure"}


@dataclass
class _TransportOptions:
    radius: int | None
    spacing: int | None
    frames: int
    settle_s: float
    camera: int
    force: bool
    baseline: bool
    baseline_frames: int
    baseline_exposure: float
    #: measurement options the caller set (radius, spacing, frames): a stored L must match only these
    given: frozenset = frozenset()

    @classmethod
    def parse(cls, params: dict, *, known: set[str] = _TRANSPORT_KEYS) -> "_TransportOptions":
        _check_known(params, known, "transport")
        frames = _int(params, "frames", 1, 1, 256)
        return cls(radius=_int(params, "radius", None, 1, 16), spacing=_int(params, "spacing", None, 2, 64),
                   frames=frames, settle_s=_float(params, "settle_s", 0.05, 0.0, 30.0),
                   camera=_int(params, "camera", 0, 0, 64), force=bool(params.get("force", False)),
                   baseline=bool(params.get("baseline", False)),
                   baseline_frames=_int(params, "baseline_frames", frames, 1, 4096),
                   baseline_exposure=_float(params, "baseline_exposure", 1.0, 1e-3, 1e4),
                   given=frozenset(k for k in ("radius", "spacing", "frames") if params.get(k) is not None))


@dataclass
class _Transport:
    """A measured (or reloaded) rig light transport and what it was measured with."""

    L: sp.csr_matrix
    meta: dict
    black: np.ndarray           # (Hc, Wc, 3) float32
    H: np.ndarray               # (3, 3) content -> camera
    camera_shape: tuple[int, int]
    slots: list[str]
    reused: bool

    @property
    def content_shape(self) -> tuple[int, int]:
        return int(self.meta["content_size"][1]), int(self.meta["content_size"][0])


def _rig_state_fingerprint(ctx, slots: list[str], H: np.ndarray, camera: int) -> str:
    """What a measured ``L`` depends on in the rig: content size, camera, and each slot's size, gain, pose, LUT."""
    rig = ctx.rig
    h = hashlib.blake2b(digest_size=10)
    # the camera is identified by its index and its calibration (H), not by how it is reached (its spec)
    h.update(repr((rig.config.content_width, rig.config.content_height, camera)).encode())
    h.update(np.asarray(H, np.float64).tobytes())
    for s in sorted(slots):
        st = rig.slot(s)
        h.update(f"{s}:{st.width}x{st.height}:{st.gain!r}".encode())
        h.update(st.pose.matrix.tobytes() if st.pose is not None else b"-")
        h.update(np.ascontiguousarray(st.lut, np.float32).tobytes() if st.lut is not None else b"identity")
    return h.hexdigest()


def _transport_fingerprint(state: str, opts: _TransportOptions) -> str:
    """One measurement: the rig's state and the dot grid it was measured with (names its black capture and
    ties the baseline's ``L_i`` to it)."""
    return hashlib.blake2b(repr((state, opts.radius, opts.spacing, opts.frames)).encode(), digest_size=10).hexdigest()


def _load_valid_transport(ctx, state: str, opts: _TransportOptions, H: np.ndarray, slots: list[str]) -> _Transport | None:
    """The stored ``L`` if it was measured with the rig as it is now and with every option the caller set."""
    d = _dir(ctx.rig)
    f = d / "transport.npz"
    if not f.exists():
        return None
    try:
        L, meta = load_transport(f)
    except TransportFileError as exc:
        ctx.log(f"stored light transport ignored: {exc}")
        return None
    if meta.get("rig_state") != state:
        return None
    if any(meta.get(k) != getattr(opts, k) for k in opts.given):
        return None
    try:
        black = np.load(d / str(meta["black_file"]), allow_pickle=False).astype(np.float32)
        cam = (int(meta["camera_size"][1]), int(meta["camera_size"][0]))
    except (OSError, KeyError, ValueError, TypeError) as exc:
        ctx.log(f"stored light transport ignored: its black capture is unreadable ({exc})")
        return None
    if black.shape != (*cam, 3) or L.shape[0] != cam[0] * cam[1]:
        return None
    return _Transport(L, meta, black, H, cam, slots, True)


async def _feed_measure(ctx, shots_iter, black: np.ndarray, **options) -> sp.csr_matrix:
    """Run :func:`transport_from_captures` on a worker thread while ``shots_iter`` captures on the loop."""
    feed = _Feed()
    task = asyncio.ensure_future(ctx.compute(transport_from_captures, feed, black, **options))
    try:
        async for img in shots_iter:
            while not task.done() and not feed.offer(img):
                await asyncio.sleep(0.005)
            if task.done():
                break
        while not task.done() and not feed.offer_end():
            await asyncio.sleep(0.005)
        return await task
    except BaseException as exc:
        feed.abort(exc)
        await asyncio.gather(task, return_exceptions=True)
        if isinstance(exc, ValueError):
            raise JobError(f"light transport: {exc}") from exc
        raise


async def _ensure_transport(ctx, opts: _TransportOptions, slots: list[str] | None = None, *,
                            measure: bool = True) -> _Transport:
    """The stored ``L`` when its fingerprint matches (and not ``force``), else a new measurement."""
    rig = ctx.rig
    if slots is None:
        slots = _slots_param(ctx, {}, need_pose=True)
    H, cal_size = _geometry(ctx, opts.camera)
    cw, ch = rig.config.content_width, rig.config.content_height
    if opts.radius is None:
        opts = replace(opts, radius=psf_radius(H, [rig.slot(s).pose.matrix for s in slots], (cw, ch)))
    state = _rig_state_fingerprint(ctx, slots, H, opts.camera)
    fp = _transport_fingerprint(state, opts)
    if not opts.force:
        found = _load_valid_transport(ctx, state, opts, H, slots)
        if found is not None:
            ctx.log(f"light transport: reusing the stored measurement of {found.meta.get('date', '?')} "
                    f"({found.meta.get('captures')} captures)")
            return found
    if not measure:
        asked = ", ".join(f"{k} {getattr(opts, k)}" for k in sorted(opts.given))
        raise JobError("no valid light-transport measurement for the rig as it is now (poses, LUTs or gains changed, "
                       f"or none was made{'; or it was measured with another ' + asked if asked else ''}): "
                       "run `shadowless transport`")
    _camera_spec(ctx, opts.camera)
    missing = [s for s in rig.slots if rig.slot(s).lut is None and s in slots]
    if missing:
        ctx.log(f"warning: {', '.join(missing)} have no inverse-response LUT: the light transport assumes linear "
                "projectors; run `shadowless response` first")
    t0 = time.monotonic()
    shots = _Shots(ctx, camera=opts.camera, settle_s=opts.settle_s, frames=opts.frames)
    ctx.progress("transport", "", 0, 1, "every projector black")
    black = await shots.content(np.zeros((ch, cw), np.uint8))
    cam = black.shape[:2]
    if cal_size != (0, 0) and tuple(cal_size) != (cam[1], cam[0]):
        raise JobError(f"camera {opts.camera} delivers {cam[1]}x{cam[0]} images but was calibrated at "
                       f"{cal_size[0]}x{cal_size[1]}: calibrate again")
    spacing = opts.spacing
    if spacing is None:
        try:
            spacing = choose_spacing(H, (ch, cw), cam, opts.radius, guard=1)
        except CompensationError as exc:
            raise JobError(str(exc)) from exc
    grid = DotGrid(cw, ch, spacing)
    ctx.log(f"light transport: {len(grid)} dot patterns (spacing {spacing}, radius {opts.radius}, "
            f"{opts.frames} frame(s) each), every projector at once")

    async def patterns():
        for k in range(len(grid)):
            yield await shots.content(grid.pattern(k, value=255, dtype=np.uint8))
            ctx.progress("transport", "", k + 1, len(grid), "dot patterns")

    L = await _feed_measure(ctx, patterns(), black, grid=grid, homography=H, radius=opts.radius)
    seconds = time.monotonic() - t0
    edge = await ctx.compute(edge_energy, L, H, (ch, cw), cam, opts.radius)
    if edge > EDGE_WARNING:
        ctx.log(f"warning: {100 * edge:.1f} % of the measured light lies on the edge of the {2 * opts.radius + 1}-pixel "
                f"windows: the PSFs are larger (defocus?); measure again with a larger radius (--radius "
                f"{opts.radius + 1})")
    meta = {"fingerprint": fp, "rig_state": state, "radius": opts.radius, "spacing": spacing, "frames": opts.frames,
            "captures": shots.count, "patterns": len(grid), "content_size": [cw, ch], "camera_size": [cam[1], cam[0]],
            "content_to_camera": np.asarray(H).tolist(), "camera": opts.camera,
            "camera_spec": _camera_spec(ctx, opts.camera), "slots": sorted(slots), "measured_at": time.time(),
            "date": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "seconds": round(seconds, 3), "nnz": int(L.nnz),
            "black_file": f"black-{fp}.npy", "edge_energy": round(edge, 5)}
    d = _dir(rig)
    atomic_save_npy(d / meta["black_file"], black)
    await ctx.compute(save_transport, d / "transport.npz", L, meta)
    atomic_write_json(d / "transport.json", meta)
    for old in d.glob("black-*.npy"):
        if old.name != meta["black_file"]:
            old.unlink(missing_ok=True)
    return _Transport(L, meta, black, H, cam, slots, False)


def _capture_exposure_supported(ctx) -> bool:
    import inspect

    try:
        return "exposure" in inspect.signature(ctx.capture).parameters
    except (TypeError, ValueError):
        return False


class _ExposedShots(_Shots):
    """Shots at a camera exposure relative to the camera's own (contexts that can set it)."""

    def __init__(self, ctx, *, exposure: float, **kw):
        super().__init__(ctx, **kw)
        self.exposure = exposure

    async def _grab(self) -> np.ndarray:
        if self.exposure == 1.0:
            return await super()._grab()
        from coordinator.camera import CameraError

        try:
            img = np.asarray(await self.ctx.capture(self.camera, exposure=self.exposure), np.float32)
        except CameraError as exc:
            raise JobError(str(exc)) from exc
        self.count += 1
        return img


async def _ensure_baseline(ctx, tr: _Transport, opts: _TransportOptions) -> tuple[dict[str, sp.csr_matrix], dict]:
    """The per-projector ``L_i`` (baseline only): stored ones with a matching fingerprint, the rest measured."""
    rig = ctx.rig
    if opts.baseline_exposure != 1.0 and not _capture_exposure_supported(ctx):
        raise JobError("this coordinator's cameras cannot change exposure per capture; average frames instead "
                       "(baseline_frames)")
    d = _dir(rig) / "baseline"
    fp = hashlib.blake2b(f"{tr.meta['fingerprint']}:{opts.baseline_frames}:{opts.baseline_exposure!r}".encode(),
                         digest_size=10).hexdigest()
    cw, ch = rig.config.content_width, rig.config.content_height
    grid = DotGrid(cw, ch, int(tr.meta["spacing"]))
    radius = int(tr.meta["radius"])
    out: dict[str, sp.csr_matrix] = {}
    todo = []
    for s in tr.slots:
        try:
            Li, m = load_transport(d / f"{s}.npz")
            if m.get("fingerprint") == fp and Li.shape == tr.L.shape:
                out[s] = Li
                continue
        except TransportFileError:
            pass
        todo.append(s)
    t0 = time.monotonic()
    shots = _ExposedShots(ctx, exposure=opts.baseline_exposure, camera=opts.camera, settle_s=opts.settle_s,
                          frames=opts.baseline_frames)
    if todo:
        ctx.log(f"baseline: measuring {len(todo)} projector(s) one at a time ({len(grid)} patterns x "
                f"{opts.baseline_frames} frame(s) each, exposure x{opts.baseline_exposure:g})")
        black = await shots.projector({s: None for s in tr.slots}, require=[])
        for n, s in enumerate(todo):
            st = rig.slot(s)
            size = (st.width, st.height)

            async def patterns(s=s, st=st, size=size):
                for k in range(len(grid)):
                    frame = projector_frame(grid.pattern(k, value=255, dtype=np.uint8), st.pose.matrix, size,
                                            lut=st.lut, gain=st.gain)
                    yield await shots.projector({s: frame}, require=[s])
                    ctx.progress("baseline transport", s, k + 1, len(grid), f"projector {n + 1}/{len(todo)}")

            Li = await _feed_measure(ctx, patterns(), black, grid=grid, homography=tr.H, radius=radius,
                                     dot_value=opts.baseline_exposure)
            await ctx.compute(save_transport, d / f"{s}.npz", Li,
                              {"fingerprint": fp, "slot": s, "frames": opts.baseline_frames,
                               "exposure": opts.baseline_exposure, "date": time.strftime("%Y-%m-%dT%H:%M:%S%z")})
            out[s] = Li
    total = float(tr.L.sum())
    excluded = [s for s in tr.slots if float(out[s].sum()) < 1e-3 * total / max(len(tr.slots), 1)]
    for s in excluded:
        ctx.log(f"baseline: {s} adds no light to the camera image (powered off?); left out")
        out.pop(s)
    summary = {"slots": sorted(out), "excluded": excluded, "measured": todo, "captures": shots.count,
               "captures_per_projector": len(grid) * opts.baseline_frames, "frames": opts.baseline_frames,
               "exposure": opts.baseline_exposure, "seconds": round(time.monotonic() - t0, 3)}
    return out, summary


def _transport_summary(tr: _Transport) -> dict:
    m = tr.meta
    return {"reused": tr.reused, "captures": m["captures"], "patterns": m["patterns"], "spacing": m["spacing"],
            "radius": m["radius"], "frames": m["frames"], "seconds": m["seconds"], "nnz": m["nnz"],
            "edge_energy": m.get("edge_energy"),
            "shape": list(tr.L.shape), "slots": len(tr.slots), "date": m["date"], "fingerprint": m["fingerprint"],
            "file": f"{SUBDIR}/transport.npz"}


async def measure_transport(ctx, params: dict) -> dict:
    """The ``transport`` job: the rig's light transport from dot-grid captures (+ the baseline's ``L_i``).

    Parameters (JSON)::

        radius            PSF recovery radius in camera pixels (default: from the geometry, :func:`psf_radius`)
        spacing           dot-grid spacing in content pixels (default: the smallest that separates the
                          windows, plus one pixel of guard)
        frames            captures averaged per pattern (default 1)
        baseline          also measure each projector's L_i alone (N x the captures)
        baseline_frames   captures averaged per pattern for the baseline (default: frames)
        baseline_exposure camera exposure of the baseline captures relative to the camera's (contexts that
                          can set it; e.g. N, since one projector gives 1/N of the light)
        slots, settle_s, camera, force
    """
    t0 = time.monotonic()
    opts = _TransportOptions.parse(dict(params))
    slots = _slots_param(ctx, params, need_pose=True)
    tr = await _ensure_transport(ctx, opts, slots)
    white = row_white(tr.L, tr.camera_shape)
    cw, ch = ctx.rig.config.content_width, ctx.rig.config.content_height
    rows, cols = inscribed_region(tr.H, (cw, ch), tr.camera_shape, margin=int(tr.meta["radius"]) + 2)
    region = white[rows, cols]
    summary = {**_transport_summary(tr), "white": {"p2": _round(float(np.percentile(region, 2)), 5),
                                                   "median": _round(float(np.median(region)), 5),
                                                   "max": _round(float(region.max()), 5)}}
    if opts.baseline:
        _, summary["baseline"] = await _ensure_baseline(ctx, tr, opts)
    summary["wall_s"] = round(time.monotonic() - t0, 3)
    return summary


# ====================================================================== compensate
_COMPENSATE_KEYS = {"image", "image_path", "srgb", "level", "max_iter", "tol", "method", "evaluate", "baseline",
                    "regularization",
                    "eval_frames", "measure", "persist", "camera", "settle_s", "radius", "spacing", "frames", "force",
                    "baseline_frames", "baseline_exposure", "slots"}


def _target_level(white: np.ndarray, region: tuple[slice, slice], level: float) -> float:
    """Camera signal of the target's full white: ``level`` times the rig's white at its 2nd percentile."""
    return level * float(np.percentile(white[region], TARGET_PERCENTILE))


def _score(target: np.ndarray, capture: np.ndarray, black: np.ndarray, s: float,
           region: tuple[slice, slice]) -> tuple[dict, np.ndarray]:
    """PSNR/SSIM of a capture (black removed, divided by the target level) against the target, in ``region``."""
    seen = (np.asarray(capture, np.float32) - black) / np.float32(s)
    if target.shape[2] == 1:
        seen = seen.mean(axis=2, keepdims=True)
    t, c = target[region], seen[region]
    return quality(t, c).as_dict(), c


def _load_image(params: dict) -> tuple[np.ndarray, str]:
    if params.get("image") is not None:
        return decode_image_param(params["image"])
    if params.get("image_path"):
        p = Path(str(params["image_path"]))
        try:
            return decode_image_param(encode_image_param(p))
        except OSError as exc:
            raise CompensationError(f"cannot read image {p} on the coordinator: {exc.strerror or exc}") from exc
    raise CompensationError("give an image (the `image` parameter, or `image_path` on the coordinator's machine)")


async def compensate(ctx, params: dict) -> dict:
    """The ``compensate`` job: one bounded least-squares solve for an image, stored and shown.

    Parameters (JSON)::

        image         {"name", "data"}: the file's bytes (see :func:`encode_image_param`); or image_path
        srgb          the image is sRGB-encoded (default: values are linear luminance, as `shadowless show`)
        level         target white as a fraction of the rig's white at its 2nd percentile inside the
                      content (default 0.9); with ``baseline`` the level the dimmest projector's share allows
        max_iter, tol, method   solver budget (300), relative objective decrease (1e-5), "apg"
        regularization  ridge weight towards the uncompensated image, relative to ||L||^2 (0.02; 0: none),
                      see :class:`RidgeProblem`
        evaluate      capture the result without compensation, with ours (and the baseline): PSNR/SSIM and
                      compensation/quality.png (eval_frames captures averaged, default 4)
        baseline      also solve and show the per-projector baseline (measures its L_i when missing)
        measure       measure L when no valid one is stored (default true)
        persist       make the result the rig's content and show it (default true)
        radius, spacing, frames, force, baseline_frames, baseline_exposure, settle_s, camera: as `transport`
    """
    t0 = time.monotonic()
    params = dict(params)
    _check_known(params, _COMPENSATE_KEYS, "compensate")
    level = _float(params, "level", 0.9, 0.01, 1.0)
    mu = _float(params, "regularization", DEFAULT_REGULARIZATION, 0.0, 100.0)
    max_iter = _int(params, "max_iter", 300, 1, 100_000)
    tol = _float(params, "tol", 1e-5, 0.0, 1.0)
    method = str(params.get("method", "apg"))
    if method not in ("apg", "steepest", "lbfgsb"):
        raise JobError(f"method must be apg, steepest or lbfgsb, got {method!r}")
    eval_frames = _int(params, "eval_frames", 4, 1, 256)
    evaluate = bool(params.get("evaluate", False))
    want_baseline = bool(params.get("baseline", False))
    topts = _TransportOptions.parse({k: v for k, v in params.items() if k in _TRANSPORT_KEYS and k != "baseline"},
                                    known=_TRANSPORT_KEYS)
    try:
        image, name = _load_image(params)
    except CompensationError as exc:
        raise JobError(str(exc)) from exc
    slots = _slots_param(ctx, params, need_pose=True)
    tr = await _ensure_transport(ctx, topts, slots, measure=bool(params.get("measure", True)))
    rig = ctx.rig
    cw, ch = rig.config.content_width, rig.config.content_height
    content = prepare_image(image, (cw, ch), srgb=bool(params.get("srgb", False)))
    T = camera_target(content, tr.H, tr.camera_shape)
    region = inscribed_region(tr.H, (cw, ch), tr.camera_shape, margin=int(tr.meta["radius"]) + 2)
    white = row_white(tr.L, tr.camera_shape)
    s = _target_level(white, region, level)
    level_note = "rig white"
    base_L: dict[str, sp.csr_matrix] = {}
    base_summary = None
    if want_baseline:
        base_L, base_summary = await _ensure_baseline(ctx, tr, topts)
        if not base_L:
            raise JobError("baseline: no projector adds light to the camera image")
        n = len(base_L)
        # the conventional method asks every projector for c'/N: the target must be within each one's reach
        s_base = level * n * min(float(np.percentile(row_white(Li, tr.camera_shape)[region], TARGET_PERCENTILE))
                                 for Li in base_L.values())
        if s_base < s:
            s, level_note = s_base, "dimmest projector's share x N (so the baseline can reach it)"
    if s <= 0:
        raise JobError("the rig adds no light inside the content area: check the light-transport measurement")
    target = np.ascontiguousarray(T * np.float32(s))
    problem = await ctx.compute(RidgeProblem, tr.L, mu)
    flat = content.reshape(-1, content.shape[2])
    alpha = best_scale(await ctx.compute(problem.data.matvec, flat), target.reshape(-1, target.shape[2]))
    none = np.clip(content * np.float32(alpha), 0, 1).astype(np.float32)
    report = _threadsafe(ctx)
    ctx.progress("solve", "", 0, max_iter, "objective")
    progress = _throttled(lambda k, f: report("solve", "", k, max_iter, "objective", f))
    res = await ctx.compute(solve, problem.op, problem.target(target, none), x0=none, content_shape=(ch, cw),
                            max_iter=max_iter, tol=tol, method=method, progress=progress)
    ctx.progress("solve", "", res.iterations, res.iterations, res.reason, res.objective)
    x = np.clip(res.x, 0, 1).astype(np.float32).reshape(ch, cw, -1)
    data_objective = await ctx.compute(problem.data_objective, x, target)
    initial_objective = await ctx.compute(problem.data_objective, none, target)
    result = {
        "image": name, "content_size": [cw, ch], "channels": int(x.shape[2]), "target_level": round(s, 6),
        "target_level_from": level_note, "level": level, "none_scale": round(alpha, 6),
        "solve": {"method": method, "iterations": res.iterations, "reason": res.reason, "converged": res.converged,
                  "objective": data_objective, "initial_objective": initial_objective,
                  "penalised_objective": res.objective, "regularization": mu, "gap": _round(res.gap, 6),
                  "seconds": round(res.seconds, 3), "lipschitz": res.lipschitz},
        "transport": _transport_summary(tr),
        "saturated_fraction": {"low": round(float(np.mean(x <= 1e-4)), 5), "high": round(float(np.mean(x >= 1 - 1e-4)), 5)},
    }
    base_res = None
    if want_baseline:
        names = sorted(base_L)
        share = target / np.float32(len(names))

        def run_baseline():
            # the conventional method, as ours: each projector's own ridge problem for c'/N, from its own
            # uncompensated start
            out = []
            for i, k in enumerate(names):
                p = RidgeProblem(base_L[k], mu)
                a = best_scale(p.data.matvec(flat), share.reshape(-1, share.shape[2]))
                start = np.clip(content * np.float32(a), 0, 1)
                out.append(solve(p.op, p.target(share, start), x0=start, content_shape=(ch, cw), max_iter=max_iter,
                                 tol=tol, method=method))
                report("baseline solve", k, i + 1, len(names), f"{out[-1].iterations} iterations")
            return out

        t_b = time.monotonic()
        results = await ctx.compute(run_baseline)
        base_res = dict(zip(names, results))
        result["baseline"] = {**(base_summary or {}), "solve_seconds": round(time.monotonic() - t_b, 3),
                              "iterations": sum(r.iterations for r in results),
                              "solve_seconds_sum": round(sum(r.seconds for r in results), 3)}
        result["baseline_over_ours_seconds"] = round(result["baseline"]["solve_seconds_sum"] / max(res.seconds, 1e-9), 2)
    if evaluate:
        result["quality"] = await _evaluate(ctx, tr, content, none, x, base_res, T, s, region, eval_frames, name,
                                            settle_s=topts.settle_s)
    d = _dir(rig)
    result["wall_s"] = round(time.monotonic() - t0, 3)
    atomic_write_json(d / "result.json", {**result, "finished_at": time.time()})
    if params.get("persist", True):
        ctx.coordinator.show(Content(np.ascontiguousarray(x), name=f"compensated {name}"), persist=True)
        result["content"] = "shown on every projector and stored as the rig's content"
    return result


async def _evaluate(ctx, tr: _Transport, content: np.ndarray, none: np.ndarray, ours: np.ndarray,
                    base_res: dict | None, T: np.ndarray, s: float, region: tuple[slice, slice], frames: int,
                    name: str, *, settle_s: float) -> dict:
    """Capture none / baseline / ours; PSNR, SSIM and the side-by-side picture."""
    rig = ctx.rig
    camera = int(tr.meta["camera"])
    shots = _Shots(ctx, camera=camera, settle_s=settle_s, frames=frames)
    ctx.progress("evaluate", "", 0, 3 if base_res else 2, "without compensation")
    black = await shots.content(np.zeros(content.shape[:2], np.float32))
    scores: dict[str, dict] = {}
    tiles: dict[str, np.ndarray] = {}
    scores["none"], tiles["none"] = _score(T, await shots.content(none), black, s, region)
    if base_res is not None:
        ctx.progress("evaluate", "", 1, 3, "baseline")
        frames_by_slot = {}
        for k, r in base_res.items():
            st = rig.slot(k)
            frames_by_slot[k] = projector_frame(np.asarray(r.x, np.float32).reshape(content.shape[0], content.shape[1], -1),
                                                st.pose.matrix, (st.width, st.height), lut=st.lut, gain=st.gain)
        scores["baseline"], tiles["baseline"] = _score(T, await shots.projector(frames_by_slot, require=list(frames_by_slot)),
                                                       black, s, region)
    ctx.progress("evaluate", "", 2 if base_res else 1, 3 if base_res else 2, "ours")
    scores["ours"], tiles["ours"] = _score(T, await shots.content(ours), black, s, region)
    ctx.progress("evaluate", "", 3 if base_res else 2, 3 if base_res else 2, "scored")

    # predictions through the measured L (what the solver believed), for comparison with the captures
    def predicted(x: np.ndarray) -> dict:
        c = (tr.L @ x.reshape(-1, x.shape[2])).reshape(*tr.camera_shape, -1) / np.float32(s)
        return quality(T[region], c[region]).as_dict()

    order = ["target", "none"] + (["baseline"] if base_res else []) + ["ours"]
    images = [T[region]] + [tiles[k] for k in order[1:]]
    labels = ["target"] + [f"{k} {scores[k]['psnr']:.2f} dB / {scores[k]['ssim']:.3f}" for k in order[1:]]
    pic = side_by_side(images, labels)
    ok, png = cv2.imencode(".png", cv2.cvtColor(pic, cv2.COLOR_RGB2BGR))
    if not ok:
        raise JobError("could not encode the side-by-side picture")
    d = _dir(rig)
    atomic_write_bytes(d / "quality.png", png.tobytes())
    out = {**scores, "predicted": {"none": await ctx.compute(predicted, none), "ours": await ctx.compute(predicted, ours)},
           "region": {"x": [region[1].start, region[1].stop], "y": [region[0].start, region[0].stop]},
           "captures_averaged": frames, "picture": f"{SUBDIR}/quality.png", "image": name}
    out["ordering"] = {
        "ours_minus_none_db": round(scores["ours"]["psnr"] - scores["none"]["psnr"], 3),
        **({"ours_minus_baseline_db": round(scores["ours"]["psnr"] - scores["baseline"]["psnr"], 3),
            "baseline_minus_none_db": round(scores["baseline"]["psnr"] - scores["none"]["psnr"], 3)} if base_res else {}),
    }
    atomic_write_json(d / "quality.json", {**out, "finished_at": time.time()})
    return out


# ====================================================================== sequence
_SEQUENCE_KEYS = {"frames", "fps", "loops", "iterations", "first_iterations", "level", "srgb", "measure", "camera",
                  "play", "latency_ms", "regularization"}


async def compensate_sequence(ctx, params: dict) -> dict:
    """The ``compensate_sequence`` job: compensate frames one after the other (warm starts), then play them.

    Parameters (JSON)::

        frames            list of images ({"name", "data"} each, see :func:`encode_image_param`)
        iterations        APG iterations per frame after the first (default 4); first_iterations (60)
        level, srgb, regularization   as `compensate`
        fps, loops        playback (30 fps, 0 extra loops); play: false only compensates
        measure           measure L when no valid one is stored (default false: run `shadowless transport`)
    """
    t0 = time.monotonic()
    params = dict(params)
    _check_known(params, _SEQUENCE_KEYS, "sequence")
    frames = params.get("frames")
    if not isinstance(frames, list) or not frames:
        raise JobError("frames must be a non-empty list of images")
    iterations = _int(params, "iterations", 4, 1, 10_000)
    first = _int(params, "first_iterations", 60, 1, 100_000)
    level = _float(params, "level", 0.9, 0.01, 1.0)
    fps = _float(params, "fps", 30.0, 0.1, 1000.0)
    loops = _int(params, "loops", 0, 0, 10_000)
    camera = _int(params, "camera", 0, 0, 64)
    topts = _TransportOptions.parse({"camera": camera})
    slots = _slots_param(ctx, {}, need_pose=True)
    tr = await _ensure_transport(ctx, topts, slots, measure=bool(params.get("measure", False)))
    rig = ctx.rig
    cw, ch = rig.config.content_width, rig.config.content_height
    region = inscribed_region(tr.H, (cw, ch), tr.camera_shape, margin=int(tr.meta["radius"]) + 2)
    s = _target_level(row_white(tr.L, tr.camera_shape), region, level)
    mu = _float(params, "regularization", DEFAULT_REGULARIZATION, 0.0, 100.0)
    problem = await ctx.compute(RidgeProblem, tr.L, mu)
    comp = ContentWarmStart(problem, iterations=iterations, first_iterations=first, content_shape=(ch, cw))
    srgb = bool(params.get("srgb", False))
    times: list[float] = []
    objectives: list[float] = []
    contents: list[Content] = []
    for k, item in enumerate(frames):
        try:
            image, name = decode_image_param(item)
        except CompensationError as exc:
            raise JobError(f"frame {k}: {exc}") from exc
        content = prepare_image(image, (cw, ch), srgb=srgb)
        target = camera_target(content, tr.H, tr.camera_shape) * np.float32(s)
        t = time.perf_counter()
        res = await ctx.compute(comp, target, content)
        times.append(time.perf_counter() - t)
        objectives.append(problem.data_objective(res.x, target))
        x = np.clip(res.x, 0, 1).reshape(ch, cw, -1)
        contents.append(Content(np.rint(x * 65535).astype(np.uint16), name=f"compensated {name}"))
        ctx.progress("compensate", "", k + 1, len(frames), f"{1000 * times[-1]:.0f} ms", res.objective)
    warm = times[1:] or times
    summary: dict[str, Any] = {
        "frames": len(frames), "iterations_per_frame": iterations, "first_iterations": first,
        "target_level": round(s, 6), "ms_first_frame": round(1000 * times[0], 2),
        "ms_per_frame_mean": round(1000 * float(np.mean(warm)), 2),
        "ms_per_frame_median": round(1000 * float(np.median(warm)), 2),
        "ms_per_frame_max": round(1000 * float(np.max(warm)), 2),
        "objective_mean": float(np.mean(objectives)), "scale": comp.scale, "transport": _transport_summary(tr),
    }
    if params.get("play", True):
        from coordinator.operator import play_dict
        from protos import control_pb2

        settings = control_pb2.PlaySettings(fps=fps, loops=loops, wait=True)
        if params.get("latency_ms"):
            settings.latency_ms = _float(params, "latency_ms", 50.0, 1.0, 5000.0)
        ctx.progress("play", "", 0, len(contents) * (loops + 1), f"{fps:g} fps")
        reply = await ctx.coordinator.play(contents, settings)
        summary["play"] = play_dict(reply)
    summary["wall_s"] = round(time.monotonic() - t0, 3)
    atomic_write_json(_dir(rig) / "sequence.json", {**summary, "finished_at": time.time()})
    return summary
