"""The largest image any process of the rig decodes, shared by the coordinator (every image file
an operator hands it, :mod:`coordinator.image_decode`) and the nodes (the PNGs of their assets,
:mod:`node.image_files`): a small file can declare a huge image (64 Mpx of RGBA float is already
1 GiB), so each decoder reads the declared size from the header and refuses above these before
allocating anything."""
from __future__ import annotations

__all__ = ["MAX_PIXELS", "MAX_IMAGE_SIDE", "within_limits"]

#: pixels (width x height) of the largest image decoded
MAX_PIXELS = 64 * 2**20
#: the longest side decoded (the rig's own largest side, coordinator.schema.MAX_SIDE)
MAX_IMAGE_SIDE = 16384


def within_limits(width: int, height: int) -> bool:
    """True for a declared size of 1..MAX_IMAGE_SIDE a side and at most MAX_PIXELS pixels."""
    return 1 <= width <= MAX_IMAGE_SIDE and 1 <= height <= MAX_IMAGE_SIDE and width * height <= MAX_PIXELS
