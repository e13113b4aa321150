"""Float content must lie in 0..1: the nodes show float pixels as linear light from black (0) to
the projector's white (1), so a float image in other units (an HDR photograph, a depth map, a
0..255 array saved as float) would be shown clipped, or black, without a word. Here it is refused
in one line naming the file and the range found, or clipped when the operator asked for it
(``--clip``)."""
from __future__ import annotations

import numpy as np

__all__ = ["check_float_range"]


def check_float_range(image: np.ndarray, name: str, *, clip: bool = False,
                      hint: str = "pass --clip to clip it to 0..1") -> np.ndarray:
    """``image`` if it is not float or all its values are finite and within [0, 1]; clipped to
    [0, 1] (a new array, same shape and dtype) when ``clip`` and its values are finite.

    ``image``: any shape; uint8/uint16 (any integer) pass unchanged, float16/32/64 are checked.

    Raises
    ------
    ValueError
        One line naming ``name``: NaN or infinite values (refused even with ``clip``), or values
        outside [0, 1] without ``clip`` (the range found and ``hint``, what the operator can do).
    """
    img = np.asarray(image)
    if img.dtype.kind != "f" or img.size == 0:
        return image
    lo, hi = float(np.min(img)), float(np.max(img))    # NaN propagates through min/max
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise ValueError(f"{name} holds NaN or infinite values: float content must be finite numbers in 0..1")
    if lo >= 0.0 and hi <= 1.0:
        return image
    if clip:
        return np.clip(img, 0.0, 1.0).astype(img.dtype, copy=False)
    raise ValueError(f"{name} holds values from {lo:.6g} to {hi:.6g}, but float content must lie in 0..1 "
                     f"(0 black, 1 the projector's white): rescale it, or {hint}")
