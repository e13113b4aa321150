"""argparse types shared by every shadowless command, each defined once.

Each is a callable for ``add_argument(type=...)``: it returns the parsed value or raises
:class:`argparse.ArgumentTypeError` with a message that says what was expected and gives an
example, so a mistake costs one line and exit status 2, never a traceback. It lives beside
the wire definitions because the node (which does not import the coordinator) uses it too.
"""
from __future__ import annotations

import argparse
import math
import re
from pathlib import Path
from typing import Callable

__all__ = ["size", "grid", "pair", "points_path", "byte_size", "int_range", "number", "names", "int_list",
           "existing_dir", "existing_file", "MAX_SIDE"]

#: the largest output, content or camera side accepted (pixels)
MAX_SIDE = 16384

_SIZE = re.compile(r"^\s*(\d+)\s*[xX×]\s*(\d+)\s*$")
_BYTES = re.compile(r"^\s*(\d+(?:\.\d*)?|\.\d+)\s*([KMGT]?)(?:I?B)?\s*$", re.IGNORECASE)
_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


def _fail(text: object, expected: str) -> argparse.ArgumentTypeError:
    return argparse.ArgumentTypeError(f"{text!r} is not {expected}")


def _wxh(text: str, what: str, example: str, hi: int) -> tuple[int, int]:
    m = _SIZE.match(str(text))
    if not m:
        raise _fail(text, f"{what}: give two whole numbers joined by x, e.g. {example}")
    a, b = int(m.group(1)), int(m.group(2))
    if not (1 <= a <= hi and 1 <= b <= hi):
        raise _fail(text, f"{what}: each side must be 1..{hi}, e.g. {example}")
    return a, b


def size(text: str) -> tuple[int, int]:
    """``"1920x1080"`` -> (1920, 1080): a width and height in pixels, each 1..MAX_SIDE."""
    return _wxh(text, "a size WxH", "1920x1080", MAX_SIDE)


def grid(text: str) -> tuple[int, int]:
    """``"5x5"`` -> (5, 5): columns x rows of a projector array, each 1..64."""
    return _wxh(text, "a grid COLSxROWS", "5x5", 64)


def _finite(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise ValueError(text) from None
    if not math.isfinite(v):
        raise ValueError(text)
    return v


def pair(text: str) -> tuple[float, float]:
    """``"600,300"`` -> (600.0, 300.0): two finite numbers joined by a comma."""
    parts = str(text).split(",")
    try:
        if len(parts) != 2:
            raise ValueError(text)
        return _finite(parts[0]), _finite(parts[1])
    except ValueError:
        raise _fail(text, "a point X,Y: two numbers joined by a comma, e.g. 600,300") from None


def points_path(text: str) -> list[tuple[float, float]]:
    """``"100,100:900,500"`` -> [(100, 100), (900, 500)]: two or more points X,Y joined by colons."""
    try:
        pts = [pair(p) for p in str(text).split(":")]
    except argparse.ArgumentTypeError:
        pts = []
    if len(pts) < 2:
        raise _fail(text, "a path: two or more points X,Y joined by colons, e.g. 100,100:900,500")
    return pts


def byte_size(text: str) -> int:
    """``"20G"`` -> 21474836480: a positive number of bytes with an optional unit K, M, G or T
    (powers of 1024; ``B``/``iB`` after it allowed, case ignored)."""
    m = _BYTES.match(str(text))
    value = float(m.group(1)) * _UNITS[m.group(2).upper()] if m else math.nan
    if not (math.isfinite(value) and value >= 1):
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a size: give a positive number of bytes with an optional unit K, M, G or T "
            "(powers of 1024), e.g. 20G or 500M")
    return int(value)


def int_range(lo: int, hi: int | None = None) -> Callable[[str], int]:
    """A whole number in ``lo..hi`` (no upper bound when ``hi`` is None)."""
    def parse(text: str) -> int:
        try:
            v = int(str(text).strip())
        except ValueError:
            v = None
        if v is None or v < lo or (hi is not None and v > hi):
            raise _fail(text, f"a whole number {lo}..{hi}" if hi is not None else f"a whole number, at least {lo}")
        return v
    parse.__name__ = "whole number"
    return parse


def number(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False) -> Callable[[str], float]:
    """A finite number in ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``; either bound may be None)."""
    if lo is not None and hi is not None:
        span = f"{'above' if lo_open else 'from'} {lo:g} {'and at most' if lo_open else 'to'} {hi:g}"
    elif lo is not None:
        span = f"{'above' if lo_open else 'at least'} {lo:g}"
    elif hi is not None:
        span = f"at most {hi:g}"
    else:
        span = ""

    def parse(text: str) -> float:
        try:
            v = _finite(str(text).strip())
        except ValueError:
            v = None
        if (v is None or (lo is not None and (v <= lo if lo_open else v < lo))
                or (hi is not None and v > hi)):
            raise _fail(text, f"a number {span}".rstrip())
        return v
    parse.__name__ = "number"
    return parse


def names(text: str) -> list[str]:
    """``"r0c0,r0c1"`` -> ["r0c0", "r0c1"]: one or more names joined by commas (blanks dropped)."""
    out = [s.strip() for s in str(text).split(",") if s.strip()]
    if not out:
        raise _fail(text, "a list of names joined by commas, e.g. r0c0,r0c1")
    return out


def int_list(lo: int = 1, hi: int | None = None) -> Callable[[str], list[int]]:
    """``"1,4,16"`` -> [1, 4, 16]: whole numbers in ``lo..hi`` joined by commas."""
    one = int_range(lo, hi)

    def parse(text: str) -> list[int]:
        try:
            out = [one(v) for v in str(text).split(",") if v.strip()]
        except argparse.ArgumentTypeError:
            out = []
        if not out:
            bound = f"{lo}..{hi}" if hi is not None else f"at least {lo}"
            raise _fail(text, f"a list of whole numbers ({bound}) joined by commas, e.g. 1,4,16")
        return out
    parse.__name__ = "list of whole numbers"
    return parse


def existing_dir(text: str) -> Path:
    """A folder that exists."""
    p = Path(text)
    if not p.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: {'not a folder' if p.exists() else 'no such folder'}")
    return p


def existing_file(text: str) -> Path:
    """A file that exists (not a folder)."""
    p = Path(text)
    if not p.is_file():
        raise argparse.ArgumentTypeError(f"{text}: {'not a file' if p.exists() else 'no such file'}")
    return p
