"""Per-pixel blend maps: the record a coordinator sends and a node applies, defined once.

A projector's blend is two maps over its own output frame, at a reduced resolution:

* ``alpha`` (h, w, 3) float32 in [0, 1]: a gain per channel on the linear content;
* ``beta`` (h, w) float32 in [0, 1]: a black offset added in linear luminance.

The node's luminance pipeline becomes ``LUT(clamp(gain * (alpha * value + beta)))``. The maps
are a downscaled image of the frame: texel (i, j) has its centre at projector pixel
``((j + 0.5) * W / w - 0.5, (i + 0.5) * H / h - 0.5)`` for an output of W x H pixels, row 0 is
the top row (OpenCV's convention), and between texel centres the maps are interpolated
bilinearly, clamped at the edges.

Only numpy: a node installs no OpenCV.
"""
from __future__ import annotations

import hashlib
import zlib
from dataclasses import dataclass

import numpy as np

__all__ = ["BlendMapError", "BlendMaps", "MAX_MAP_SIDE"]

#: the largest map side a node accepts (a quarter of 16k)
MAX_MAP_SIDE = 4096


class BlendMapError(ValueError):
    """Blend maps of the wrong shape, type or range; the message is one line for an operator."""


def _digest(alpha: np.ndarray, beta: np.ndarray) -> str:
    return _digest_wire(alpha.shape[1], alpha.shape[0], alpha.astype("<f2").tobytes(), beta.astype("<f2").tobytes())


def _digest_wire(width: int, height: int, alpha: bytes, beta: bytes) -> str:
    """The blend id of maps from their float16 encoding (the same as of the arrays they decode to)."""
    h = hashlib.blake2b(digest_size=8)
    h.update(np.asarray((height, width, 3), np.int64).tobytes())
    h.update(alpha)
    h.update(beta)
    return h.hexdigest()


def _wire_ok(data: bytes) -> bool:
    """Whether little-endian float16 values all lie in 0..1 (finite), read from their bits: a
    non-negative half orders as its bits do, from +0 (0x0000) to 1.0 (0x3C00); -0 (0x8000) is 0 too.
    (numpy's float16 arithmetic is slow; this is one pass over integers.)"""
    u = np.frombuffer(data, "<u2")
    return bool(np.all((u <= 0x3C00) | (u == 0x8000)))


@dataclass(frozen=True, eq=False)
class BlendMaps:
    """One projector's blend maps (see the module docstring for the grid).

    Attributes
    ----------
    alpha : (h, w, 3) float32 in [0, 1]
    beta : (h, w) float32 in [0, 1]
    blend_id : str
        A digest of the maps as sent (float16); computed when empty.
    """

    alpha: np.ndarray
    beta: np.ndarray
    blend_id: str = ""

    def __post_init__(self) -> None:
        a = np.asarray(self.alpha)
        b = np.asarray(self.beta)
        if a.ndim != 3 or a.shape[2] != 3:
            raise BlendMapError(f"alpha map must be (h, w, 3), got shape {a.shape}")
        if b.shape != a.shape[:2]:
            raise BlendMapError(f"beta map must be (h, w) = {a.shape[:2]} like alpha, got {b.shape}")
        h, w = b.shape
        if not (1 <= h <= MAX_MAP_SIDE and 1 <= w <= MAX_MAP_SIDE):
            raise BlendMapError(f"blend maps must be 1..{MAX_MAP_SIDE} texels per side, got {w}x{h}")
        a = a.astype(np.float32, copy=False)
        b = b.astype(np.float32, copy=False)
        for name, arr in (("alpha", a), ("beta", b)):
            if not np.all(np.isfinite(arr)):
                raise BlendMapError(f"{name} map holds NaN or infinite values")
            lo, hi = float(arr.min()), float(arr.max())
            if lo < 0.0 or hi > 1.0:
                raise BlendMapError(f"{name} map must lie in 0..1, got {lo:.4g}..{hi:.4g}")
        a = np.ascontiguousarray(a)
        b = np.ascontiguousarray(b)
        a.setflags(write=False)
        b.setflags(write=False)
        object.__setattr__(self, "alpha", a)
        object.__setattr__(self, "beta", b)
        if not self.blend_id:
            object.__setattr__(self, "blend_id", _digest(a, b))

    # ---------------------------------------------------------------- packed maps
    # A packed instance holds only its wire encoding (``_packed``: w, h, alpha bytes, beta bytes,
    # compressed or not): ``alpha`` and ``beta`` are decoded from it on each access (see __getattr__).

    def packed(self, *, compress: bool = False) -> "BlendMaps":
        """The same maps (same ``blend_id``, same values on the wire) held only as their float16
        encoding: half the memory of the float32 arrays, or with ``compress`` about a seventh
        (zlib over the float16 bytes split into high and low bytes; smooth maps compress well), at
        the cost of inflating them before use (:meth:`inflated`). The arrays read back from a
        packed instance are the float16 values, as a node sees them."""
        p = self.__dict__.get("_packed")
        if p is not None and p[4] == compress:
            return self
        alpha, beta = self.encode()
        w, h = self.size
        if compress:
            alpha, beta = zlib.compress(_shuffle(alpha), 6), zlib.compress(_shuffle(beta), 6)
        out = object.__new__(type(self))
        object.__setattr__(out, "blend_id", self.blend_id)
        object.__setattr__(out, "_packed", (w, h, alpha, beta, compress))
        return out

    def inflated(self) -> "BlendMaps":
        """A compressed packed instance as a packed one ready for the wire (itself otherwise)."""
        p = self.__dict__.get("_packed")
        return self.packed() if p is not None and p[4] else self

    @property
    def compressed(self) -> bool:
        p = self.__dict__.get("_packed")
        return p is not None and p[4]

    @property
    def nbytes(self) -> int:
        """What the maps hold in memory (bytes): the arrays, or a packed instance's encoding."""
        p = self.__dict__.get("_packed")
        if p is not None:
            return len(p[2]) + len(p[3])
        return int(self.alpha.nbytes + self.beta.nbytes)

    def __getattr__(self, name: str):
        p = self.__dict__.get("_packed")
        if p is None or name not in ("alpha", "beta"):
            raise AttributeError(name)
        w, h, alpha, beta, compressed = p
        raw = _unshuffle(zlib.decompress(alpha if name == "alpha" else beta)) if compressed else \
            (alpha if name == "alpha" else beta)
        shape = (h, w, 3) if name == "alpha" else (h, w)
        a = np.frombuffer(raw, "<f2").reshape(shape).astype(np.float32)
        a.setflags(write=False)
        return a

    def __repr__(self) -> str:
        w, h = self.size
        return f"BlendMaps({w}x{h}, blend_id={self.blend_id!r}{', packed' if '_packed' in self.__dict__ else ''})"

    @property
    def size(self) -> tuple[int, int]:
        """(w, h) texels."""
        p = self.__dict__.get("_packed")
        if p is not None:
            return int(p[0]), int(p[1])
        return int(self.beta.shape[1]), int(self.beta.shape[0])

    def encode(self) -> tuple[bytes, bytes]:
        """(alpha, beta) as little-endian float16 bytes, row-major, for the wire (a packed instance's
        own bytes, inflated first when compressed)."""
        p = self.__dict__.get("_packed")
        if p is not None:
            if p[4]:
                return _unshuffle(zlib.decompress(p[2])), _unshuffle(zlib.decompress(p[3]))
            return p[2], p[3]
        return self.alpha.astype("<f2").tobytes(), self.beta.astype("<f2").tobytes()

    @classmethod
    def decode(cls, width: int, height: int, alpha: bytes, beta: bytes, blend_id: str = "") -> "BlendMaps":
        """The inverse of :meth:`encode`; :class:`BlendMapError` when the sizes disagree or a value is
        not finite or outside 0..1. The maps are held as the float16 bytes received (a packed instance,
        see :meth:`packed`): checked on their bits, with no float32 copy (at 1080p map sizes a node
        takes a failover's maps in a fraction of a millisecond instead of several, and the renderer
        uploads the same bytes)."""
        if not (1 <= width <= MAX_MAP_SIDE and 1 <= height <= MAX_MAP_SIDE):
            raise BlendMapError(f"blend maps must be 1..{MAX_MAP_SIDE} texels per side, got {width}x{height}")
        if len(alpha) != width * height * 3 * 2 or len(beta) != width * height * 2:
            raise BlendMapError(f"blend maps of {width}x{height} need {width * height * 6} + {width * height * 2} bytes, "
                                f"got {len(alpha)} + {len(beta)}")
        if _wire_ok(alpha) and _wire_ok(beta):
            alpha, beta = bytes(alpha), bytes(beta)
            out = object.__new__(cls)
            object.__setattr__(out, "blend_id", blend_id or _digest_wire(width, height, alpha, beta))
            object.__setattr__(out, "_packed", (width, height, alpha, beta, False))
            return out
        # a value out of range: the arrays' own checks say which, in one line
        a = np.frombuffer(alpha, "<f2").reshape(height, width, 3).astype(np.float32)
        b = np.frombuffer(beta, "<f2").reshape(height, width).astype(np.float32)
        return cls(a, b, blend_id)


def _shuffle(f16: bytes) -> bytes:
    """float16 bytes as all low bytes, then all high bytes (the high bytes of a smooth map repeat)."""
    return np.frombuffer(f16, np.uint8).reshape(-1, 2).T.tobytes()


def _unshuffle(data: bytes) -> bytes:
    lo, hi = np.frombuffer(data, np.uint8).reshape(2, -1).astype("<u2")
    hi <<= 8
    hi |= lo
    return hi.tobytes()
