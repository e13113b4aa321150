"""Reading a blob capture: each lit site's light above black, per projector.

A site's value is the per-channel trimmed mean (the middle 80 %) of ``capture - black`` over the
camera pixels within 0.6 of the disc's radius of its centre (at least 1.5 px): the disc's blurred
rim and a neighbour's tail stay outside the window, and the trimming shrugs off a hot pixel or a
speck on the surface while keeping most of a mean's noise reduction.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imaging.blending.sample_plan import SamplePlan

__all__ = ["Samples", "read_capture"]


@dataclass
class Samples:
    """Samples gathered so far: per slot the sites (indices into the plan's) and their (n, 3) values."""

    sites: dict[str, list[int]] = field(default_factory=dict)
    values: dict[str, list[np.ndarray]] = field(default_factory=dict)

    def add(self, slot: str, site: int, value: np.ndarray) -> None:
        self.sites.setdefault(slot, []).append(int(site))
        self.values.setdefault(slot, []).append(np.asarray(value, np.float64))

    def arrays(self, slot: str) -> tuple[np.ndarray, np.ndarray]:
        """``(sites (n,) int64, values (n, 3) float64)`` of ``slot``."""
        if slot not in self.sites:
            return np.zeros(0, np.int64), np.zeros((0, 3))
        return np.asarray(self.sites[slot], np.int64), np.stack(self.values[slot])

    def count(self, slot: str) -> int:
        return len(self.sites.get(slot, ()))


def _trimmed_mean(values: np.ndarray, cut: float = 0.1) -> np.ndarray:
    """Per-column mean of ``values`` ((n, C)) without the lowest and highest ``cut`` of each column."""
    v = np.sort(values, axis=0)
    k = int(len(v) * cut)
    return v[k:len(v) - k].mean(axis=0) if len(v) > 2 * k else v.mean(axis=0)


def read_capture(capture: np.ndarray, black: np.ndarray, plan: SamplePlan, k: int, samples: Samples) -> int:
    """Add capture ``k``'s site values to ``samples``; returns how many sites it read.

    Parameters
    ----------
    capture, black : (H, W, 3) float32
        The blob capture ``k`` of ``plan`` and the black capture.
    """
    img = np.asarray(capture, np.float32) - np.asarray(black, np.float32)
    H, W = img.shape[:2]
    win = max(1.5, 0.6 * plan.radius)
    n = int(np.ceil(win))
    oy, ox = np.mgrid[-n:n + 1, -n:n + 1]
    owner = plan.owner[k]
    read = 0
    for j in np.flatnonzero(owner >= 0):
        cx, cy = plan.sites[j]
        xs = np.rint(cx).astype(np.int64) + ox
        ys = np.rint(cy).astype(np.int64) + oy
        keep = ((xs - cx) ** 2 + (ys - cy) ** 2 <= win * win) & (xs >= 0) & (xs < W) & (ys >= 0) & (ys < H)
        if not keep.any():
            continue
        samples.add(plan.slots[owner[j]], j, _trimmed_mean(img[ys[keep], xs[keep]]))
        read += 1
    return read


def blob_exposure(white: np.ndarray, plan: SamplePlan, *, level: float = 0.6, longest: float = 16.0) -> float:
    """The exposure (relative to ``white``'s) at which the brightest blob should read about ``level`` of full
    scale: ``white`` ((H, W, 3), every projector at full white) shared by the projectors that can light each
    site gives each one's share; the brightest share sets it. Between 1 and ``longest``."""
    img = np.asarray(white, np.float32)
    H, W = img.shape[:2]
    xs = np.clip(np.rint(plan.sites[:, 0]).astype(np.int64), 0, W - 1)
    ys = np.clip(np.rint(plan.sites[:, 1]).astype(np.int64), 0, H - 1)
    share = img[ys, xs].max(axis=1) / np.maximum(plan.candidates, 1)
    top = float(np.percentile(share, 90)) if len(share) else 0.0
    if not top > 0:
        return 1.0
    return float(np.clip(level / (1.5 * top), 1.0, longest))
