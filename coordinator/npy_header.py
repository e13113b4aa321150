"""A .npy file's header, read before its array: the shape and dtype it declares must fit in the
bytes that follow it, or loading would allocate what the header says (a 200-byte file declaring
(100000, 100000, 3) float32 asked numpy for 112 GiB and ended in a MemoryError traceback)."""
from __future__ import annotations

import math
from typing import BinaryIO

import numpy as np
from numpy.lib import format as npy_format

__all__ = ["check_npy_fits"]


def check_npy_fits(fp: BinaryIO, size: int) -> None:
    """Read the header of the .npy at ``fp``'s start (``size`` bytes in all) and raise ValueError
    (one line, for the caller to prefix with the file's name) when the array it declares needs more bytes than the file holds;
    headers numpy cannot parse are left to ``np.load`` to refuse. ``fp`` is rewound to its start."""
    start = fp.tell()
    try:
        major, _ = npy_format.read_magic(fp)
        read = npy_format.read_array_header_1_0 if major == 1 else npy_format.read_array_header_2_0
        shape, _, dtype = read(fp)
        header_end = fp.tell()
    except (ValueError, OSError, EOFError, SyntaxError, TypeError):
        return
    finally:
        fp.seek(start)
    if dtype.hasobject:
        return                                   # np.load refuses pickles itself
    need = math.prod(shape) * dtype.itemsize
    have = size - (header_end - start)
    if need > have:
        raise ValueError(f"its header declares an array of shape {tuple(shape)} {np.dtype(dtype).name} "
                         f"({need:,} bytes) but the file holds {max(have, 0):,}: truncated or not a real array")
