"""The value types of `shadowless bench compensation`'s options (sizes that may be 'none', lists of
whole numbers, weight storages, the target's range), each an ``argparse`` type that names what
it expected."""
from __future__ import annotations

import argparse

from imaging.compensation.stencil import STORAGES
from protos import cli_types

__all__ = ["ints", "size", "sizes", "storages", "unit_range"]


def size(text: str) -> tuple[int, int] | bool:
    """A size WxH of at least 16x16 (:func:`protos.cli_types.size`), or False for 'none', 'off', '0' or
    nothing: that part of the bench is skipped (None means not given: its default)."""
    if text.lower() in ("", "none", "0", "off"):
        return False
    w, h = cli_types.size(text)
    if w < 16 or h < 16:
        raise argparse.ArgumentTypeError(f"size must be at least 16x16, got {text!r}")
    return w, h


def ints(text: str) -> list[int]:
    """Whole numbers of at least 1 joined by commas (:func:`protos.cli_types.int_list`); an empty list
    skips that part of the bench."""
    return cli_types.int_list(1)(text) if text.strip() else []


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
