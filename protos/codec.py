"""Lossless image packing for the wire, shared by coordinator, node and room.

Images are numpy arrays shaped ``(H, W)`` or ``(H, W, C)`` with dtype uint8,
uint16, float16 or float32. :func:`encode_image` packs one into a
``common_pb2.Image``; :func:`decode_image` unpacks it and always returns
``(H, W, C)``. Encoding is done once per image; callers that fan an image out
to many peers serialize the message once and send the same bytes.
"""
from __future__ import annotations

import zlib

import numpy as np

from protos import common_pb2

_DTYPES = {
    np.dtype(np.uint8): common_pb2.DTYPE_UINT8,
    np.dtype(np.uint16): common_pb2.DTYPE_UINT16,
    np.dtype(np.float16): common_pb2.DTYPE_FLOAT16,
    np.dtype(np.float32): common_pb2.DTYPE_FLOAT32,
}
_NUMPY = {v: k.newbyteorder("<") for k, v in _DTYPES.items()}

#: Hard limits on a decoded image, so a malformed message cannot exhaust memory.
MAX_SIDE = 16384
MAX_CHANNELS = 4


class ImageCodecError(ValueError):
    """An image message is malformed; the message says what is wrong."""


def encode_image(image: np.ndarray, *, compress: bool = False, level: int = 1) -> common_pb2.Image:
    """Pack ``image`` ((H, W) or (H, W, C), C <= 4) losslessly into an Image message."""
    arr = np.asarray(image)
    if arr.ndim == 2:
        arr = arr[:, :, None]
    if arr.ndim != 3 or not 1 <= arr.shape[2] <= MAX_CHANNELS:
        raise ValueError(f"image must be (H, W) or (H, W, C<={MAX_CHANNELS}), got shape {arr.shape}")
    if arr.dtype not in _DTYPES:
        raise ValueError(f"image dtype must be uint8, uint16, float16 or float32, got {arr.dtype}")
    h, w, c = arr.shape
    raw = np.ascontiguousarray(arr, dtype=arr.dtype.newbyteorder("<")).tobytes()
    if compress:
        data, encoding = zlib.compress(raw, level), common_pb2.ENCODING_ZLIB
    else:
        data, encoding = raw, common_pb2.ENCODING_RAW
    return common_pb2.Image(
        width=w, height=h, channels=c, dtype=_DTYPES[arr.dtype], encoding=encoding, data=data
    )


def decode_image(msg: common_pb2.Image) -> np.ndarray:
    """Unpack an Image message into an ``(H, W, C)`` array (a fresh, writable copy)."""
    if msg.dtype not in _NUMPY:
        raise ImageCodecError(f"image has unknown dtype {msg.dtype}")
    if not (0 < msg.width <= MAX_SIDE and 0 < msg.height <= MAX_SIDE and 0 < msg.channels <= MAX_CHANNELS):
        raise ImageCodecError(
            f"image size {msg.width}x{msg.height}x{msg.channels} is outside 1..{MAX_SIDE} px, 1..{MAX_CHANNELS} channels"
        )
    dtype = _NUMPY[msg.dtype]
    expected = msg.width * msg.height * msg.channels * dtype.itemsize
    if msg.encoding == common_pb2.ENCODING_RAW:
        raw = msg.data
    elif msg.encoding == common_pb2.ENCODING_ZLIB:
        try:
            d = zlib.decompressobj()
            raw = d.decompress(msg.data, expected + 1)
        except zlib.error as exc:
            raise ImageCodecError(f"image data is not valid zlib: {exc}") from exc
    else:
        raise ImageCodecError(f"image has unknown encoding {msg.encoding}")
    if len(raw) != expected:
        raise ImageCodecError(
            f"image data holds {len(raw)} bytes, {msg.width}x{msg.height}x{msg.channels} {dtype.name} needs {expected}"
        )
    arr = np.frombuffer(raw, dtype=dtype).reshape(msg.height, msg.width, msg.channels)
    return arr.astype(dtype.newbyteorder("="), copy=True)


def to_unit_float(image: np.ndarray) -> np.ndarray:
    """Map an integer image to float32 in [0, 1] (uint8 /255, uint16 /65535); floats pass through."""
    arr = np.asarray(image)
    if arr.dtype == np.uint8:
        return arr.astype(np.float32) / 255.0
    if arr.dtype == np.uint16:
        return arr.astype(np.float32) / 65535.0
    return arr.astype(np.float32, copy=False)
