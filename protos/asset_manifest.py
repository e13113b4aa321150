"""What an asset is, for every process: its manifest.

An **asset** is content distributed ahead of use (a still, an image sequence, a video). Its
bytes live in **blobs**, each named by the SHA-256 of its bytes. Its **manifest** lists the
blobs in order and says how to read them (kind, frame count, frame rate, size, bit depth);
the manifest's canonical JSON (sorted keys, no spaces, UTF-8) has a SHA-256 too, and that is
the **asset id**. So an asset id fixes every byte a node will show, a node verifies what it
fetched by hashing, and the same content added twice is the same asset.

* ``still``: one blob, an image file (PNG 8/16-bit, TIFF, JPEG, or ``.npy`` float32).
* ``sequence``: one blob per frame, in order, each an image file as above.
* ``video``: one blob, a container file (MP4/MOV/MKV) decoded with PyAV.

Only the standard library: every install reads manifests, the edge node's included.
"""
from __future__ import annotations

import hashlib
import json
import math
import re
from dataclasses import dataclass, field
from typing import Any

__all__ = ["Blob", "Manifest", "ManifestError", "KINDS", "sha256_hex", "is_sha256"]

KINDS = ("still", "sequence", "video")
_HEX64 = re.compile(r"^[0-9a-f]{64}$")


class ManifestError(ValueError):
    """A manifest (or a blob named in it) is malformed; the message says what is wrong."""


def sha256_hex(data: bytes) -> str:
    """The SHA-256 of ``data`` as 64 lowercase hex digits."""
    return hashlib.sha256(data).hexdigest()


def is_sha256(text: str) -> bool:
    """Whether ``text`` looks like a SHA-256 in lowercase hex."""
    return isinstance(text, str) and bool(_HEX64.match(text))


@dataclass(frozen=True)
class Blob:
    """One file of an asset: its SHA-256, its size in bytes and the file name it came from
    (its suffix says how to decode it: ``.png``, ``.tif``, ``.jpg``, ``.npy``, ``.mp4``, ...)."""

    sha256: str
    size: int
    name: str

    def to_json(self) -> dict[str, Any]:
        return {"sha256": self.sha256, "size": self.size, "name": self.name}


@dataclass(frozen=True)
class Manifest:
    """An asset's description (see the module docstring).

    ``width``/``height`` are the frames' size in pixels, ``channels`` 1, 3 or 4, ``bit_depth``
    8, 10, 12, 16 (integers) or 32 (float); ``frames`` the frame count (1 for a still) and
    ``fps`` the frame rate the asset was made for (0 for a still). ``extra`` carries
    kind-specific facts (e.g. a video's codec and pixel format) and is part of the id.
    """

    kind: str
    name: str
    blobs: tuple[Blob, ...]
    width: int
    height: int
    channels: int
    bit_depth: int
    frames: int
    fps: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        problems = []
        if self.kind not in KINDS:
            problems.append(f"kind must be one of {', '.join(KINDS)}, not {self.kind!r}")
        if not self.blobs:
            problems.append("an asset has at least one blob")
        for b in self.blobs:
            if not is_sha256(b.sha256):
                problems.append(f"blob {b.name!r}: sha256 must be 64 lowercase hex digits")
            if not isinstance(b.size, int) or b.size < 0:
                problems.append(f"blob {b.name!r}: size must be a non-negative integer")
        if self.kind in ("still", "video") and len(self.blobs) != 1:
            problems.append(f"a {self.kind} has exactly one blob, not {len(self.blobs)}")
        if self.kind == "sequence" and len(self.blobs) != self.frames:
            problems.append(f"a sequence has one blob per frame: {len(self.blobs)} blobs for {self.frames} frames")
        if self.kind == "still" and self.frames != 1:
            problems.append("a still has exactly one frame")
        if not (isinstance(self.width, int) and isinstance(self.height, int) and self.width > 0 and self.height > 0):
            problems.append(f"size must be positive integers, got {self.width}x{self.height}")
        if self.channels not in (1, 2, 3, 4):
            problems.append(f"channels must be 1..4, got {self.channels}")
        if self.bit_depth not in (8, 10, 12, 16, 32):
            problems.append(f"bit_depth must be 8, 10, 12, 16 or 32, got {self.bit_depth}")
        if not isinstance(self.frames, int) or self.frames < 1:
            problems.append(f"frames must be a positive integer, got {self.frames}")
        if not (isinstance(self.fps, (int, float)) and math.isfinite(self.fps) and self.fps >= 0):
            problems.append(f"fps must be a finite number >= 0, got {self.fps}")
        if self.kind != "still" and self.fps <= 0:
            problems.append(f"a {self.kind} needs its frame rate (fps > 0)")
        if problems:
            raise ManifestError("bad asset manifest: " + "; ".join(problems))

    @property
    def total_bytes(self) -> int:
        """Bytes a node fetches for this asset."""
        return sum(b.size for b in self.blobs)

    @property
    def duration_s(self) -> float:
        """Length at its frame rate (0 for a still)."""
        return self.frames / self.fps if self.fps > 0 else 0.0

    def to_json(self) -> dict[str, Any]:
        return {"kind": self.kind, "name": self.name, "blobs": [b.to_json() for b in self.blobs],
                "width": self.width, "height": self.height, "channels": self.channels,
                "bit_depth": self.bit_depth, "frames": self.frames, "fps": float(self.fps), "extra": self.extra}

    def canonical(self) -> bytes:
        """The canonical bytes whose SHA-256 is the asset id."""
        return json.dumps(self.to_json(), sort_keys=True, separators=(",", ":"), ensure_ascii=False).encode()

    @property
    def asset_id(self) -> str:
        return sha256_hex(self.canonical())

    @classmethod
    def from_json(cls, doc: Any) -> "Manifest":
        """Parse (and validate) a manifest document; :class:`ManifestError` says what is wrong."""
        if not isinstance(doc, dict):
            raise ManifestError("bad asset manifest: not a JSON object")
        try:
            blobs = tuple(Blob(sha256=str(b["sha256"]), size=int(b["size"]), name=str(b["name"]))
                          for b in doc["blobs"])
            return cls(kind=str(doc["kind"]), name=str(doc.get("name", "")), blobs=blobs, width=int(doc["width"]),
                       height=int(doc["height"]), channels=int(doc["channels"]), bit_depth=int(doc["bit_depth"]),
                       frames=int(doc["frames"]), fps=float(doc.get("fps", 0.0)), extra=dict(doc.get("extra", {})))
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, ManifestError):
                raise
            raise ManifestError(f"bad asset manifest: missing or malformed field ({exc})") from exc

    @classmethod
    def from_bytes(cls, data: bytes, *, asset_id: str | None = None) -> "Manifest":
        """Parse manifest bytes; with ``asset_id``, refuse bytes whose hash is not that id."""
        if asset_id is not None and sha256_hex(data) != asset_id:
            raise ManifestError(f"manifest bytes do not hash to asset {asset_id[:12]}…: corrupted or wrong asset")
        try:
            doc = json.loads(data.decode())
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ManifestError(f"bad asset manifest: not JSON ({exc})") from exc
        m = cls.from_json(doc)
        if asset_id is not None and m.asset_id != asset_id:
            raise ManifestError("manifest is not in canonical form: its id differs from its hash")
        return m
