"""Portable float maps (PFM), the format of MPCDI's geometry warp files.

A PFM is a text header (``PF`` for 3 channels, ``Pf`` for 1; ``width height``; a scale whose
sign gives the byte order, negative for little-endian) followed by float32 samples, the rows
from the BOTTOM of the image to the top. Arrays here are (H, W, C) float32 with row 0 at the top.
"""
from __future__ import annotations

import re

import numpy as np

_HEADER = re.compile(rb"(P[Ff])\s+(\d+)\s+(\d+)\s+(\S+)\s")


def encode_pfm(image: np.ndarray) -> bytes:
    """``image`` (H, W) or (H, W, 1|3), float32-convertible, row 0 at the top -> PFM bytes
    (little-endian, rows bottom-up)."""
    a = np.asarray(image, np.float32)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in (1, 3) or 0 in a.shape:
        raise ValueError(f"a PFM holds (H, W) or (H, W, 1|3) samples, got shape {a.shape}")
    h, w, c = a.shape
    header = f"{'PF' if c == 3 else 'Pf'}\n{w} {h}\n-1.0\n".encode()
    return header + np.ascontiguousarray(a[::-1]).astype("<f4").tobytes()


def decode_pfm(data: bytes, *, name: str = "PFM") -> np.ndarray:
    """PFM bytes -> (H, W, C) float32, row 0 at the top (C = 1 or 3). ValueError names ``name``
    and what is wrong."""
    m = _HEADER.match(data)
    if m is None:
        raise ValueError(f"{name}: not a PFM file (no 'PF'/'Pf' header)")
    kind, w, h, scale = m.group(1), int(m.group(2)), int(m.group(3)), m.group(4)
    try:
        s = float(scale)
    except ValueError:
        raise ValueError(f"{name}: bad PFM scale {scale!r}") from None
    if s == 0 or not np.isfinite(s) or w <= 0 or h <= 0:
        raise ValueError(f"{name}: bad PFM header ({w}x{h}, scale {s})")
    c = 3 if kind == b"PF" else 1
    need = w * h * c * 4
    body = data[m.end():]
    if len(body) < need:
        raise ValueError(f"{name}: PFM of {w}x{h}x{c} is cut short ({len(body)} of {need} bytes)")
    a = np.frombuffer(body[:need], "<f4" if s < 0 else ">f4").reshape(h, w, c)
    return a[::-1].astype(np.float32)
