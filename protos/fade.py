"""A crossfade's schedule on the rig clock, defined once for the coordinator and the nodes.

A frame may carry a fade (``fade_ns`` > 0): from its presentation time ``pts`` on, the node
mixes what was on its screen before into the frame's own content over ``fade_ns``. The fade is
shown as ``K + 1`` steps, step ``k`` (0..K) swapped in at :func:`step_pts` and mixing
:func:`step_mix` of the new picture (0 at the frame's pts: the old picture; exactly 1 at the
last step: the new one). Every node computes the same instants and factors from the frame
alone, so every node shows step ``k`` at the same rig instant with the same mix: they agree
to the frame. Step ``k`` is reported as frame ``frame_id + k`` (the coordinator reserves those
ids and expects them, so the sync tracker measures the fade's skew like any frame's).

The mix itself is done in the node's shader on the linear content values, before the gain,
blend maps and LUT: ``value = before * (1 - m) + after * m`` (GLSL ``mix``);
:func:`mix_reference` is its numpy reference.
"""
from __future__ import annotations

import math

import numpy as np

#: the fade's default step: 30 steps a second
DEFAULT_STEP_NS = 33_333_334
#: the shortest step (a fade is never shown faster than 240 steps a second)
MIN_STEP_NS = 4_166_666
#: at most this many steps in one fade (a long fade takes longer steps)
MAX_STEPS = 3600


def step_count(fade_ns: int, step_ns: int = DEFAULT_STEP_NS) -> int:
    """K: the number of steps after the first (at least 1) for a fade of ``fade_ns``."""
    if fade_ns <= 0:
        return 0
    step = max(int(step_ns), MIN_STEP_NS)
    return max(1, min(MAX_STEPS, math.ceil(int(fade_ns) / step)))


def step_pts(pts_ns: int, fade_ns: int, k: int, steps: int) -> int:
    """The rig instant of step ``k`` of ``steps`` (0: the frame's own pts; ``steps``: pts + fade)."""
    return int(pts_ns) + (int(fade_ns) * int(k)) // int(steps)


def step_mix(k: int, steps: int) -> float:
    """How much of the new picture step ``k`` of ``steps`` shows (0..1; 1 at the last step)."""
    return 1.0 if k >= steps else max(0.0, k / steps)


def mix_reference(before: np.ndarray, after: np.ndarray, m: float) -> np.ndarray:
    """The shader's mix of two linear pictures: ``before * (1 - m) + after * m``.

    Parameters
    ----------
    before, after : (H, W, 3) float
        Linear content values in 0..1 (what each picture's warp gives at every output pixel).
    m : float
        The new picture's share, 0..1.

    Returns
    -------
    (H, W, 3) float64
    """
    a = np.asarray(before, dtype=np.float64)
    b = np.asarray(after, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 3:
        raise ValueError(f"before and after must be (H, W, 3) of one shape, got {a.shape} and {b.shape}")
    if not 0.0 <= m <= 1.0:
        raise ValueError(f"the mix must be in 0..1, got {m}")
    return a * (1.0 - m) + b * m
