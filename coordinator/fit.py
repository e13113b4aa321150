"""Fitting an image to the rig's content area, as the operator chose.

An image whose aspect differs from the content area's is never silently stretched: with no
choice it is refused with a message naming both sizes and the choices. ``stretch`` scales each
axis on its own, ``contain`` scales it whole to fit inside and pads with black (letterbox or
pillarbox), ``cover`` scales it whole to fill and crops the overflow evenly from both sides.
"""
from __future__ import annotations

import numpy as np

#: the operator's choices (``""``: refuse an image of another aspect)
FIT_MODES = ("stretch", "contain", "cover")

#: aspects closer than this (relative) count as equal: a 1920x1080 image fits 1280x720 either way
ASPECT_TOLERANCE = 0.01


def _resize(img: np.ndarray, w: int, h: int) -> np.ndarray:
    """``img`` (H, W, C) scaled to (h, w, C), same dtype: area averaging when shrinking."""
    if img.shape[1] == w and img.shape[0] == h:
        return img
    import cv2  # the coordinator's stack; only needed when content arrives at another size

    interp = cv2.INTER_AREA if img.shape[1] > w else cv2.INTER_LINEAR
    out = cv2.resize(img, (w, h), interpolation=interp)
    return out[:, :, None] if out.ndim == 2 else out


def check_fit(fit: str) -> None:
    """Refuse an unknown fit mode (ValueError naming the choices)."""
    if fit not in ("", *FIT_MODES):
        raise ValueError(f"unknown fit {fit!r}: choose one of {', '.join(FIT_MODES)}")


def fit_image(img: np.ndarray, size: tuple[int, int], fit: str = "") -> np.ndarray:
    """``img`` of shape (H, W, C), any dtype, fitted to ``size = (w, h)``: an (h, w, C) array of
    the same dtype.

    Raises ValueError for an unknown ``fit`` and, with ``fit == ""``, for an image whose aspect
    differs from ``w / h`` by more than :data:`ASPECT_TOLERANCE`.
    """
    check_fit(fit)
    w, h = size
    ih, iw = img.shape[:2]
    same_aspect = abs((iw / ih) / (w / h) - 1.0) <= ASPECT_TOLERANCE
    if same_aspect or fit == "stretch":
        return _resize(img, w, h)
    if fit == "":
        raise ValueError(f"the image is {iw}x{ih} (aspect {iw / ih:.3f}) but the rig's content area is {w}x{h} "
                         f"({w / h:.3f}): choose how to fit it: contain (whole image, black bars), cover (fill, "
                         f"cropped) or stretch (distorted)")
    scale = min(w / iw, h / ih) if fit == "contain" else max(w / iw, h / ih)
    sw, sh = max(1, round(iw * scale)), max(1, round(ih * scale))
    scaled = _resize(img, sw, sh)
    if fit == "cover":
        x0, y0 = (sw - w) // 2, (sh - h) // 2
        return np.ascontiguousarray(scaled[y0:y0 + h, x0:x0 + w])
    out = np.zeros((h, w, img.shape[2]), img.dtype)
    x0, y0 = (w - sw) // 2, (h - sh) // 2
    out[y0:y0 + sh, x0:x0 + sw] = scaled
    return out
