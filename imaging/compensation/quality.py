"""Quality of a compensation: PSNR / SSIM against the target, and a side-by-side picture."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
# structural_similarity alone: scikit-image's peak_signal_noise_ratio lives beside its mutual information,
# whose module imports scipy.stats (0.6 s of CPU for every process that imports this one); PSNR is below
from skimage.metrics import structural_similarity

__all__ = ["Quality", "quality", "side_by_side", "enlargement", "srgb_to_linear", "linear_to_srgb"]


@dataclass(frozen=True)
class Quality:
    """PSNR (dB) and SSIM of a captured result against its target (both linear, data range 1)."""

    psnr: float
    ssim: float

    def as_dict(self) -> dict[str, float]:
        return {"psnr": round(self.psnr, 3), "ssim": round(self.ssim, 4)}


def quality(target: np.ndarray, captured: np.ndarray) -> Quality:
    """PSNR and SSIM of ``captured`` against ``target`` (``data_range=1``; SSIM is scikit-image's).

    Parameters
    ----------
    target, captured : (H, W) or (H, W, C) float
        Linear luminance images of the same shape; ``captured`` is clipped to [0, 1] first
        (a camera cannot report more than full scale).
    """
    t = np.asarray(target, dtype=np.float64)
    c = np.asarray(captured, dtype=np.float64)
    if t.shape != c.shape:
        raise ValueError(f"target {t.shape} and captured {c.shape} differ in shape")
    if t.ndim not in (2, 3) or min(t.shape[:2]) < 7:
        raise ValueError(f"images must be (H, W) or (H, W, C) with H, W >= 7, got {t.shape}")
    c = np.clip(c, 0.0, 1.0)
    # PSNR with data range 1 as scikit-image computes it: 10 log10(1 / mean squared error), the mean in float64
    with np.errstate(divide="ignore"):  # identical images: PSNR is +inf
        psnr = float(10 * np.log10(1.0 / np.mean((t - c) ** 2, dtype=np.float64)))
    ssim = float(structural_similarity(t, c, data_range=1.0, channel_axis=2 if t.ndim == 3 else None))
    return Quality(psnr=psnr, ssim=ssim)


def srgb_to_linear(img: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] (or uint8) -> linear luminance, float32 of the same shape."""
    v = np.asarray(img)
    v = v.astype(np.float32) / 255.0 if v.dtype == np.uint8 else v.astype(np.float32)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(img: np.ndarray) -> np.ndarray:
    """Linear luminance -> sRGB-encoded float32 in [0, 1] (clipped)."""
    v = np.clip(np.asarray(img, dtype=np.float32), 0.0, 1.0)
    return np.where(v <= 0.0031308, v * 12.92, 1.055 * np.power(v, 1 / 2.4) - 0.055).astype(np.float32)


#: pictures smaller than this (px high) are enlarged by a whole factor, pixels kept square and sharp
MIN_PICTURE_HEIGHT = 240
#: at most this enlargement
MAX_ENLARGEMENT = 4
_FONT, _FONT_SCALE = cv2.FONT_HERSHEY_SIMPLEX, 0.6


def enlargement(height: int) -> int:
    """The whole factor a picture ``height`` px high is shown enlarged by: up to :data:`MIN_PICTURE_HEIGHT`
    px high, at most :data:`MAX_ENLARGEMENT` (1: tall enough already)."""
    return min(MAX_ENLARGEMENT, max(1, -(-MIN_PICTURE_HEIGHT // max(int(height), 1))))


def side_by_side(
    images: Sequence[np.ndarray],
    labels: Sequence[str] | None = None,
    *,
    linear: bool = True,
    gap: int = 8,
    label_height: int = 28,
) -> np.ndarray:
    """Place images left to right with a caption above each: ``(H', W', 3) uint8`` (BGR = RGB order kept).

    Images of different heights are scaled to the first one's height; when that is below
    :data:`MIN_PICTURE_HEIGHT` every image is enlarged by the same whole factor (nearest
    neighbour, at most :data:`MAX_ENLARGEMENT`), so a small camera view stays readable. Each column
    is as wide as the wider of its image (centred in it) and its caption, so captions never run
    into each other.

    Parameters
    ----------
    images : sequence of (H, W) or (H, W, C) arrays
        Float images in [0, 1] (linear luminance when ``linear``, shown sRGB-encoded) or uint8.
    labels : sequence of str, optional
        One caption per image.
    """
    if not images:
        raise ValueError("no images")
    if labels is not None and len(labels) != len(images):
        raise ValueError(f"{len(images)} images but {len(labels)} labels")
    height = int(np.asarray(images[0]).shape[0])
    tiles = []
    for img in images:
        a = np.asarray(img)
        if a.ndim == 2:
            a = a[:, :, None]
        if a.ndim != 3 or a.shape[2] not in (1, 3):
            raise ValueError(f"images must be (H, W), (H, W, 1) or (H, W, 3), got {np.asarray(img).shape}")
        if a.dtype != np.uint8:
            f = linear_to_srgb(a) if linear else np.clip(a.astype(np.float32), 0, 1)
            a = np.rint(f * 255).astype(np.uint8)
        if a.shape[2] == 1:
            a = np.repeat(a, 3, axis=2)
        if a.shape[0] != height:
            w = max(1, round(a.shape[1] * height / a.shape[0]))
            a = cv2.resize(a, (w, height), interpolation=cv2.INTER_AREA)
        tiles.append(a)
    k = enlargement(height)
    if k > 1:
        tiles = [cv2.resize(t, (t.shape[1] * k, t.shape[0] * k), interpolation=cv2.INTER_NEAREST) for t in tiles]
        height *= k
    texts = [str(x) for x in labels] if labels is not None else [""] * len(tiles)
    columns = [max(t.shape[1], cv2.getTextSize(x, _FONT, _FONT_SCALE, 1)[0][0] + 2 if x else 0)
               for t, x in zip(tiles, texts)]
    width = sum(columns) + gap * (len(tiles) + 1)
    top = label_height if labels is not None else 0
    canvas = np.full((height + top + 2 * gap, width, 3), 32, dtype=np.uint8)
    x = gap
    for t, text, col in zip(tiles, texts, columns):
        left = x + (col - t.shape[1]) // 2
        canvas[top + gap : top + gap + height, left : left + t.shape[1]] = t
        if text:
            cv2.putText(canvas, text, (x, gap + label_height - 10), _FONT, _FONT_SCALE, (235, 235, 235), 1, cv2.LINE_AA)
        x += col + gap
    return canvas
