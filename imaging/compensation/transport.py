"""Light transport L: measured from dot-grid captures, stored in the rig directory.

``L`` maps ``content`` pixels to ``camera`` pixels: a ``scipy.sparse`` CSR matrix of shape
``(n_camera, n_content)``, ``float32``, where content pixel ``(x, y)`` is column
``y * W + x`` and camera pixel ``(X, Y)`` is row ``Y * Wc + X`` (row-major, OpenCV pixel
centres). Column ``j`` holds content pixel ``j``'s camera-space point-spread function (PSF),
recovered within a ``(2R+1) x (2R+1)`` camera window centred on the rounded camera position
of that pixel (the *window structure*, :func:`transport_windows`). The same structure is
used for the rig's summed ``L`` and for each projector's ``L_i``.

Measurement (:func:`transport_from_captures`): every projector shows the same dot-grid pattern at
the same time; a dot grid with spacing ``S`` needs ``S*S`` shifted patterns (plus one black
capture), whatever the number of projectors. Dots of one pattern are ``S`` content pixels
apart, so their camera windows never overlap as long as ``S * pitch >= 2R+1``.
"""
from __future__ import annotations

import json
import os
import zipfile
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from imaging.calibration.planar import apply_homography
from imaging.channel_mean import channel_mean
from imaging.compensation.errors import TransportFileError
from protos.store import atomic_file

__all__ = [
    "DotGrid",
    "transport_windows",
    "dot_gap",
    "transport_from_captures",
    "transports_per_projector",
    "transport_error",
    "save_transport",
    "load_transport",
]

TRANSPORT_FORMAT = "shadowless.transport/1"


@dataclass(frozen=True)
class DotGrid:
    """Layout of the shifted impulse (dot-grid) patterns shown in ``content`` space.

    Pattern ``k`` (``0 <= k < spacing**2``) lights every content pixel ``(x, y)`` with
    ``x % spacing == sx`` and ``y % spacing == sy``, where ``(sx, sy) = shifts[k]``
    (``k = sy * spacing + sx``). Together the patterns light every content pixel exactly once.
    """

    width: int
    height: int
    spacing: int

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ValueError(f"content size must be positive, got {self.width}x{self.height}")
        if self.spacing < 1:
            raise ValueError(f"dot spacing must be >= 1, got {self.spacing}")

    @property
    def shape(self) -> tuple[int, int]:
        """Content shape ``(H, W)``."""
        return (self.height, self.width)

    @property
    def shifts(self) -> list[tuple[int, int]]:
        """The ``spacing**2`` shifts ``(sx, sy)`` in capture order."""
        s = self.spacing
        return [(k % s, k // s) for k in range(s * s)]

    def __len__(self) -> int:
        return self.spacing * self.spacing

    def dots(self, k: int) -> np.ndarray:
        """Content pixel indices ``(D,) int64`` (``y * W + x``) lit by pattern ``k``."""
        if not 0 <= k < len(self):
            raise IndexError(f"pattern {k} out of range 0..{len(self) - 1}")
        sx, sy = k % self.spacing, k // self.spacing
        xs = np.arange(sx, self.width, self.spacing, dtype=np.int64)
        ys = np.arange(sy, self.height, self.spacing, dtype=np.int64)
        return (ys[:, None] * self.width + xs[None, :]).ravel()

    def pattern(self, k: int, *, value: float = 1.0, dtype: Any = np.float32) -> np.ndarray:
        """Pattern ``k`` as a ``(H, W)`` image of ``dtype`` (``value`` at the dots, 0 elsewhere)."""
        img = np.zeros(self.height * self.width, dtype=dtype)
        img[self.dots(k)] = value
        return img.reshape(self.height, self.width)


def _map_points(homography: np.ndarray | None, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map pixel coordinates ``(x, y)`` (any equal shapes) through a homography (None: identity).

    :func:`imaging.calibration.planar.apply_homography` on the stacked points, with the
    check that every point lies in front of the destination (``w > 0``).

    Raises
    ------
    ValueError
        If the homography is not (3, 3), finite and invertible, or maps a point behind the
        camera.
    """
    h = _check_homography(homography)
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    x, y = np.broadcast_arrays(x, y)
    if np.any(h[2, 0] * x + h[2, 1] * y + h[2, 2] <= 0):
        raise ValueError("homography maps some content pixels behind the camera (w <= 0)")
    out = apply_homography(h, np.stack([x.ravel(), y.ravel()], axis=1))
    return out[:, 0].reshape(x.shape), out[:, 1].reshape(x.shape)


def _check_homography(homography: np.ndarray | None) -> np.ndarray:
    if homography is None:
        return np.eye(3)
    h = np.asarray(homography, dtype=np.float64)
    if h.shape != (3, 3):
        raise ValueError(f"homography must be (3, 3), got {h.shape}")
    if not np.all(np.isfinite(h)) or abs(np.linalg.det(h)) < 1e-12:
        raise ValueError("homography must be finite and invertible")
    return h


def _check_shape2(shape: Sequence[int], what: str) -> tuple[int, int]:
    if len(shape) != 2 or int(shape[0]) < 1 or int(shape[1]) < 1:
        raise ValueError(f"{what} shape must be (H, W) with positive sizes, got {tuple(shape)}")
    return int(shape[0]), int(shape[1])


def transport_windows(
    homography: np.ndarray | None,
    content_shape: Sequence[int],
    camera_shape: Sequence[int],
    radius: int,
    *,
    start: int = 0,
    stop: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The window structure shared by every light-transport matrix of one rig.

    Parameters
    ----------
    homography : (3, 3) float64 or None
        Content -> camera pixel mapping (None: identity).
    content_shape, camera_shape : (H, W) and (Hc, Wc)
    radius : int
        Window radius R in camera pixels; each window has ``K = (2R+1)**2`` entries
        ordered row-major over offsets ``(dy, dx)`` in ``[-R, R]``.
    start, stop : int
        Content pixel range (default: all), so large rigs can be processed in chunks.

    Returns
    -------
    base : (n, 2) int64
        Rounded camera position ``(X, Y)`` of each content pixel ``start..stop-1``.
    rows : (n, K) int32
        Camera pixel index of each window entry (clipped into the image where invalid).
    valid : (n, K) bool
        Whether the window entry lies inside the camera image.
    """
    hc, wc = _check_shape2(camera_shape, "camera")
    h, w = _check_shape2(content_shape, "content")
    if radius < 0:
        raise ValueError(f"radius must be >= 0, got {radius}")
    stop = h * w if stop is None else stop
    idx = np.arange(start, stop, dtype=np.int64)
    cx, cy = _map_points(homography, idx % w, idx // w)
    bx = np.rint(cx).astype(np.int64)
    by = np.rint(cy).astype(np.int64)
    k = (2 * radius + 1) ** 2
    offs = np.arange(-radius, radius + 1, dtype=np.int64)
    dy = np.repeat(offs, 2 * radius + 1)
    dx = np.tile(offs, 2 * radius + 1)
    inside = (bx - radius >= 0) & (bx + radius < wc) & (by - radius >= 0) & (by + radius < hc)
    rows = np.empty((idx.size, k), dtype=np.int32)
    valid = np.ones((idx.size, k), dtype=bool)
    if inside.any():
        centre = (by[inside] * wc + bx[inside]).astype(np.int32)
        rows[inside] = centre[:, None] + (dy * wc + dx).astype(np.int32)[None, :]
    edge = ~inside
    if edge.any():
        X = bx[edge, None] + dx[None, :]
        Y = by[edge, None] + dy[None, :]
        valid[edge] = (X >= 0) & (X < wc) & (Y >= 0) & (Y < hc)
        rows[edge] = (np.clip(Y, 0, hc - 1) * wc + np.clip(X, 0, wc - 1)).astype(np.int32)
    return np.stack([bx, by], axis=1), rows, valid


def assemble_transport(
    values: np.ndarray, rows: np.ndarray, valid: np.ndarray, camera_shape: Sequence[int]
) -> sp.csr_matrix:
    """Build the ``(n_camera, n_content)`` CSR float32 matrix from per-column window values.

    ``values``, ``rows`` and ``valid`` are ``(n_content, K)``; column ``j`` gets
    ``values[j, valid[j]]`` at camera rows ``rows[j, valid[j]]``.
    """
    hc, wc = _check_shape2(camera_shape, "camera")
    if values.shape != rows.shape or valid.shape != rows.shape:
        raise ValueError(f"values {values.shape}, rows {rows.shape}, valid {valid.shape} must match")
    n = rows.shape[0]
    counts = valid.sum(axis=1, dtype=np.int64)
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(counts, out=indptr[1:])
    if indptr[-1] < np.iinfo(np.int32).max:
        indptr = indptr.astype(np.int32)
    if valid.all():
        data = np.ascontiguousarray(values, dtype=np.float32).reshape(-1)
        indices = np.ascontiguousarray(rows, dtype=np.int32).reshape(-1)
    else:
        data = np.asarray(values, dtype=np.float32)[valid]
        indices = np.asarray(rows, dtype=np.int32)[valid]
    csc = sp.csc_matrix((data, indices, indptr), shape=(hc * wc, n))
    csr = csc.tocsr()
    csr.sort_indices()
    return csr


def transport_from_captures(
    captures: Iterable[np.ndarray],
    black: np.ndarray,
    *,
    grid: DotGrid,
    homography: np.ndarray | None = None,
    radius: int = 2,
    dot_value: float = 1.0,
    channel_weights: Sequence[float] | None = None,
    clip_negative: bool = True,
    threshold: float = 0.0,
) -> sp.csr_matrix:
    """Recover the light transport L from dot-grid captures.

    Parameters
    ----------
    captures : iterable of (Hc, Wc) or (Hc, Wc, C) float32
        One linear camera capture per pattern of ``grid``, in ``grid.shifts`` order
        (may be a generator: each capture is used and dropped).
    black : (Hc, Wc) or (Hc, Wc, C) float32
        Capture with every projector showing black; subtracted from each capture.
    grid : DotGrid
        The content-space dot layout that was shown.
    homography : (3, 3) float64 or None
        Content -> camera mapping used to centre each dot's window.
    radius : int
        PSF recovery radius R in camera pixels.
    dot_value : float
        Linear content value of the dots (the PSF is divided by it).
    channel_weights : sequence of C floats, optional
        How colour captures are reduced to one luminance (default: the channel mean).
    clip_negative : bool
        Set negative (noise) values to zero: light transport is non-negative.
    threshold : float
        Drop entries below ``threshold`` times their column's peak (0 keeps the full windows).

    Returns
    -------
    L : scipy.sparse.csr_matrix, (Hc*Wc, H*W) float32

    Raises
    ------
    ValueError
        On shapes that do not match, a wrong number of captures, or a spacing too small for
        the radius (windows of one pattern's dots would overlap).
    """
    black_l = _luminance(np.asarray(black), channel_weights, "black")
    camera_shape = black_l.shape
    if dot_value <= 0:
        raise ValueError(f"dot_value must be positive, got {dot_value}")
    base, rows, valid = transport_windows(homography, grid.shape, camera_shape, radius)
    _check_separation(base, grid, radius)
    values = np.zeros(rows.shape, dtype=np.float32)
    count = 0
    for k, capture in enumerate(captures):
        if k >= len(grid):
            raise ValueError(f"got more than the {len(grid)} captures the dot grid needs")
        img = _luminance(np.asarray(capture), channel_weights, f"capture {k}")
        if img.shape != camera_shape:
            raise ValueError(f"capture {k} has shape {img.shape}, the black capture {camera_shape}")
        diff = (img - black_l).reshape(-1)
        dots = grid.dots(k)
        values[dots] = diff[rows[dots]]
        count += 1
    if count != len(grid):
        raise ValueError(f"the dot grid needs {len(grid)} captures, got {count}")
    if dot_value != 1.0:
        values /= np.float32(dot_value)
    if clip_negative:
        np.maximum(values, 0, out=values)
    values[~valid] = 0
    if threshold > 0:
        peak = np.abs(values).max(axis=1, keepdims=True)
        valid = valid & (np.abs(values) >= threshold * peak) & (values != 0)
    return assemble_transport(values, rows, valid, camera_shape)


def transports_per_projector(
    captures: Sequence[Iterable[np.ndarray]],
    black: np.ndarray | Sequence[np.ndarray],
    **options: Any,
) -> list[sp.csr_matrix]:
    """The conventional per-projector measurement: one projector lit at a time.

    ``captures[i]`` are projector ``i``'s dot-grid captures (the others black); ``black`` is
    one black capture shared by all, or one per projector. ``options`` are those of
    :func:`transport_from_captures`. Returns the list of ``L_i``, each with the same window
    structure as the rig's ``L``. Needs ``N * spacing**2`` captures in total.
    """
    blacks = list(black) if isinstance(black, (list, tuple)) else [black] * len(captures)
    if len(blacks) != len(captures):
        raise ValueError(f"{len(captures)} projectors' captures but {len(blacks)} black captures")
    return [transport_from_captures(c, b, **options) for c, b in zip(captures, blacks)]


def _luminance(img: np.ndarray, weights: Sequence[float] | None, what: str) -> np.ndarray:
    if img.ndim == 2:
        return img.astype(np.float32, copy=False)
    if img.ndim != 3:
        raise ValueError(f"{what} must be (H, W) or (H, W, C), got shape {img.shape}")
    c = img.shape[2]
    if weights is None:
        return channel_mean(img)
    w = np.asarray(weights, dtype=np.float32)
    if w.shape != (c,):
        raise ValueError(f"channel_weights must have {c} entries, got {w.shape}")
    return np.tensordot(img.astype(np.float32, copy=False), w / w.sum(), axes=([2], [0]))


def dot_gap(base: np.ndarray, content_shape: Sequence[int], spacing: int) -> float:
    """The smallest camera distance (Chebyshev, px) between two dots of one pattern of spacing ``spacing``.

    ``base``: the rounded camera position of every content pixel (:func:`transport_windows`);
    dots are ``spacing`` content pixels apart along rows, columns and both diagonals. Infinite
    when no two dots of a pattern exist.
    """
    s = int(spacing)
    h, w = int(content_shape[0]), int(content_shape[1])
    bx = base[:, 0].reshape(h, w)
    by = base[:, 1].reshape(h, w)
    gaps = [np.inf]
    if w > s:
        gaps.append(np.maximum(np.abs(bx[:, s:] - bx[:, :-s]), np.abs(by[:, s:] - by[:, :-s])).min())
    if h > s:
        gaps.append(np.maximum(np.abs(bx[s:, :] - bx[:-s, :]), np.abs(by[s:, :] - by[:-s, :])).min())
    if h > s and w > s:
        gaps.append(np.maximum(np.abs(bx[s:, s:] - bx[:-s, :-s]), np.abs(by[s:, s:] - by[:-s, :-s])).min())
        gaps.append(np.maximum(np.abs(bx[s:, :-s] - bx[:-s, s:]), np.abs(by[s:, :-s] - by[:-s, s:])).min())
    return float(min(gaps))


def _check_separation(base: np.ndarray, grid: DotGrid, radius: int) -> None:
    """Raise if two dots of one pattern would share camera pixels in their windows."""
    need = 2 * radius + 1
    gap = dot_gap(base, grid.shape, grid.spacing)
    if gap < need:
        raise ValueError(
            f"dot spacing {grid.spacing} is too small for recovery radius {radius}: neighbouring dots are "
            f"{int(gap)} camera px apart but windows need {need}; increase the spacing"
        )


def transport_error(estimate: sp.spmatrix, truth: sp.spmatrix) -> float:
    """Relative Frobenius error ``||estimate - truth||_F / ||truth||_F`` of two same-shape matrices."""
    if estimate.shape != truth.shape:
        raise ValueError(f"shapes differ: {estimate.shape} vs {truth.shape}")
    diff = (sp.csr_matrix(estimate, dtype=np.float64) - sp.csr_matrix(truth, dtype=np.float64)).data
    ref = np.asarray(truth.data, dtype=np.float64)
    den = float(np.sqrt(np.dot(ref, ref)))
    if den == 0:
        raise ValueError("the reference transport is all zero")
    return float(np.sqrt(np.dot(diff, diff))) / den


def save_transport(path: str | os.PathLike[str], L: sp.spmatrix, meta: dict[str, Any] | None = None) -> Path:
    """Store ``L`` (and a JSON-serialisable ``meta`` dict) as an uncompressed ``.npz``, atomically.

    The file is written to a temporary file in the same folder, flushed, fsync'ed and renamed
    over ``path``, so a crash leaves either the old file or the new one, never half of one.
    Returns the final path.
    """
    path = Path(path)
    L = sp.csr_matrix(L)
    if L.ndim != 2:
        raise ValueError("L must be a 2-D sparse matrix")
    meta_json = json.dumps({"format": TRANSPORT_FORMAT, **(meta or {})}, sort_keys=True)
    arrays = {
        "data": np.asarray(L.data, dtype=np.float32),
        "indices": L.indices,
        "indptr": L.indptr,
        "shape": np.asarray(L.shape, dtype=np.int64),
        "meta": np.asarray(meta_json),
    }
    with atomic_file(path) as f:
        np.savez(f, **arrays)
    return path


def load_transport(path: str | os.PathLike[str]) -> tuple[sp.csr_matrix, dict[str, Any]]:
    """Load what :func:`save_transport` stored: ``(L, meta)`` with L CSR float32.

    Raises
    ------
    TransportFileError
        If the file is missing, unreadable or inconsistent (the message says to re-measure).
    """
    path = Path(path)
    hint = "re-run the light-transport measurement to recreate it"
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = {"data", "indices", "indptr", "shape", "meta"} - set(z.files)
            if missing:
                raise TransportFileError(f"{path}: not a light-transport file (missing {sorted(missing)}); {hint}")
            data, indices, indptr = z["data"], z["indices"], z["indptr"]
            shape = tuple(int(v) for v in z["shape"])
            meta = json.loads(str(z["meta"]))
    except FileNotFoundError as exc:
        raise TransportFileError(f"{path}: no light-transport file; {hint}") from exc
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, KeyError) as exc:
        raise TransportFileError(f"{path}: unreadable light-transport file ({exc}); {hint}") from exc
    if meta.get("format") != TRANSPORT_FORMAT:
        raise TransportFileError(f"{path}: unknown format {meta.get('format')!r}; {hint}")
    if (
        len(shape) != 2
        or min(shape) < 0
        or data.dtype != np.float32
        or indices.dtype.kind != "i"
        or indptr.dtype.kind != "i"
        or data.ndim != 1
        or indices.shape != data.shape
        or indptr.shape != (shape[0] + 1,)
        or indptr[0] != 0
        or indptr[-1] != data.size
        or np.any(np.diff(indptr) < 0)
        or (indices.size and (indices.min() < 0 or indices.max() >= shape[1]))
        or not np.all(np.isfinite(data))
    ):
        raise TransportFileError(f"{path}: light-transport arrays are inconsistent; {hint}")
    meta.pop("format")
    return sp.csr_matrix((data, indices, indptr), shape=shape), meta
