"""The value types of `shadowless bench compensation`'s options (sizes that may be 'none', lists of
whole numbers, weight storages, the target's range), each an ``argparse`` type that names what
it expected."""
from __future__ import annotations

import argparse

from coordinator.compensation.stencil import STORAGES

__all__ = ["ints", "size", "sizes", "storages", "unit_range"]


def size(text: str) -> tuple[int, int] | bool:
    if text.lower() in ("", "none", "0", "off"):
        return False  # explicitly skipped (None means: not given, use the default)
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"size must look like 648x486, got {text!r}") from exc
    if w < 16 or h < 16:
        raise argparse.ArgumentTypeError(f"size must be at least 16x16, got {text!r}")
    return w, h


def ints(text: str) -> list[int]:
    try:
        vals = [int(v) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from exc
    return vals


def sizes(text: str) -> list[tuple[int, int]] | bool:
    return False if not all(sizes := [size(t) for t in text.split(",")]) else sizes


def storages(text: str) -> list[str]:
    vals = [v.strip() for v in text.split(",") if v.strip()]
    if not vals or any(v not in STORAGES for v in vals):
        raise argparse.ArgumentTypeError(f"storages are {', '.join(STORAGES)}, got {text!r}")
    return vals


def unit_range(text: str) -> tuple[float, float]:
    lo, hi = (float(v) for v in text.split(","))
    if not 0 <= lo < hi <= 1:
        raise argparse.ArgumentTypeError("target range must be lo,hi with 0 <= lo < hi <= 1")
    return lo, hi
