"""Images as job parameters, and images as the rig's linear content.

A job request travels as JSON, so an image goes as ``{"name", "data"}``: the file's bytes
(PNG, TIFF, JPEG or ``.npy``), zlib-compressed and base64-encoded. The operator's client
encodes (:func:`encode_image_param` for a file, :func:`encode_image_array` for an array);
the coordinator decodes (:func:`decode_image_param`) and scales the picture to the rig's
content (:func:`prepare_image`).

The encoders need only the standard library and numpy, so the commands that send images stay
quick to start; OpenCV and scikit-image are imported by the coordinator-side functions that
need them.
"""
from __future__ import annotations

import base64
import io
import zlib
from pathlib import Path

import numpy as np

from imaging.compensation.errors import CompensationError
from protos.spaces import as_linear

__all__ = ["encode_image_param", "encode_image_array", "decode_image_param", "decode_image_bytes", "load_image_param",
           "prepare_image"]


def _param(name: str, raw: bytes) -> dict:
    return {"name": name, "data": base64.b64encode(zlib.compress(raw, 6)).decode("ascii")}


def encode_image_param(path: str | Path) -> dict:
    """An image file as a job parameter: ``{"name", "data"}`` with the file's bytes, compressed and base64.

    Raises ``OSError`` when the file cannot be read.
    """
    p = Path(path)
    return _param(p.name, p.read_bytes())


def encode_image_array(image: np.ndarray, name: str = "image.png") -> dict:
    """An in-memory image as a job parameter: float32 as ``.npy`` (values kept exactly), integers as PNG.

    ``image``: (H, W) or (H, W, C) RGB; uint8/uint16 or float32 linear values in [0, 1].
    """
    a = np.asarray(image)
    if a.dtype == np.float32:
        buf = io.BytesIO()
        np.save(buf, a, allow_pickle=False)
        return _param(name.rsplit(".", 1)[0] + ".npy", buf.getvalue())
    import cv2  # lazy: OpenCV is heavy and only PNG encoding of an array needs it on the client

    ok, png = cv2.imencode(".png", cv2.cvtColor(a, cv2.COLOR_RGB2BGR) if a.ndim == 3 else a)
    if not ok:
        raise ValueError("cannot encode the image")
    return _param(name, png.tobytes())


def decode_image_param(value: dict) -> tuple[np.ndarray, str]:
    """Inverse of :func:`encode_image_param`: ``(image, name)``; image (H, W, C) uint8/uint16/float32, RGB.

    Raises
    ------
    CompensationError
        If the bytes are not an image the decoder or numpy reads (see :func:`decode_image_bytes`).
    """
    if not isinstance(value, dict) or not isinstance(value.get("data"), str):
        raise CompensationError("image parameter must be {\"name\": ..., \"data\": base64}")
    name = str(value.get("name", "image"))
    try:
        raw = zlib.decompress(base64.b64decode(value["data"], validate=True))
    except (ValueError, zlib.error) as exc:
        raise CompensationError(f"image {name}: corrupt image parameter ({exc})") from exc
    return decode_image_bytes(raw, name)


def decode_image_bytes(raw: bytes, name: str) -> tuple[np.ndarray, str]:
    """An image file's bytes as ``(image, name)``; image (H, W, C) uint8/uint16/float32, RGB, C 1 or 3.

    ``name`` says what the bytes are (``.npy``, else any format of
    :func:`coordinator.image_decode.decode_image`: PNG, TIFF, JPEG, ..., its declared size
    checked before decoding).

    Raises
    ------
    CompensationError
        If the bytes are not an image the decoder or numpy reads, or hold float values outside
        0..1 (the solver's target is linear light from 0 to 1).
    """
    if name.lower().endswith(".npy") or raw[:6] == b"\x93NUMPY":
        from coordinator.npy_header import check_npy_fits

        try:
            check_npy_fits(io.BytesIO(raw), len(raw))
            img = np.load(io.BytesIO(raw), allow_pickle=False)
        except ValueError as exc:
            raise CompensationError(f"image {name}: not a numpy array file ({exc})") from exc
    else:
        from coordinator.image_decode import ImageRefused, decode_image, drop_alpha  # lazy: the client only encodes

        try:
            img = decode_image(raw, name)
        except ImageRefused as exc:
            raise CompensationError(f"cannot read image {exc}") from None
        img = drop_alpha(img)
    img = np.asarray(img)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.ndim != 3 or img.shape[2] not in (1, 3, 4) or min(img.shape[:2]) < 2:
        raise CompensationError(f"image {name}: shape {img.shape} is not an (H, W) or (H, W, C) picture")
    if img.dtype not in (np.uint8, np.uint16, np.float32):
        img = img.astype(np.float32)
    if img.dtype == np.float32 and not np.all(np.isfinite(img)):
        raise CompensationError(f"image {name}: contains NaN or infinity")
    from coordinator.float_range import check_float_range

    try:      # the solver's target is linear light from 0 to 1: other floats were clipped without a word
        check_float_range(img, f"image {name}", hint="clip it to 0..1 first")
    except ValueError as exc:
        raise CompensationError(str(exc)) from None
    return img[:, :, :3], name


def load_image_param(image: dict | None, image_path: str | None = None) -> tuple[np.ndarray, str]:
    """The image of a job: the ``image`` parameter, else the file ``image_path`` on the coordinator's machine."""
    if image is not None:
        return decode_image_param(image)
    if image_path:
        p = Path(image_path)
        try:
            return decode_image_param(encode_image_param(p))
        except OSError as exc:
            raise CompensationError(f"cannot read image {p} on the coordinator: {exc.strerror or exc}") from exc
    raise CompensationError("give an image (the `image` parameter, or `image_path` on the coordinator's machine)")


def prepare_image(image: np.ndarray, content_size: tuple[int, int], *, srgb: bool = False) -> np.ndarray:
    """An image as linear content at the rig's content size: ``(H, W, C) float32`` in [0, 1].

    Integers are normalised by their maximum (the rig treats content values as linear
    luminance, like `shadowless show`); ``srgb`` decodes sRGB-encoded values first.
    """
    import cv2  # lazy: OpenCV is heavy; only the coordinator prepares content

    from imaging.compensation.quality import srgb_to_linear  # lazy: imports scikit-image

    img = as_linear(image)
    if img.ndim == 2:
        img = img[:, :, None]
    w, h = content_size
    if img.shape[:2] != (h, w):
        interp = cv2.INTER_AREA if img.shape[1] > w else cv2.INTER_LINEAR
        img = cv2.resize(img, (w, h), interpolation=interp)
        if img.ndim == 2:
            img = img[:, :, None]
    img = np.clip(img, 0.0, 1.0)
    if srgb:
        img = srgb_to_linear(img)
    return np.ascontiguousarray(img, dtype=np.float32)
