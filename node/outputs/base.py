"""What every output shares: the :class:`Output` contract, :class:`SwapInfo`, errors,
slot and spec checks, snapshots, and the headless GL context.

An :class:`Output` owns the GL context the node renders with (one thread owns
both). The presenter calls, for every frame, in this order and from that thread:

1. ``renderer.render(...)`` into the renderer's framebuffer (early, as soon as the frame arrives),
2. :meth:`Output.prepare` (still before the presentation time: e.g. blit to the window's back buffer),
3. :meth:`Output.swap` exactly at the presentation time (must be fast: this instant is the swap),
4. :meth:`Output.after_swap` (read-back, PNG snapshots, sending to the room: off the critical instant).

This module knows no concrete output (they import it, never the reverse).
"""
from __future__ import annotations

import abc
import json
import logging
import re
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from node.errors import NodeError
from node.output_spec import SPEC_FORMS, parse_room_address  # noqa: F401 (SPEC_FORMS: re-exported)
from node.image_files import atomic_write_bytes, encode_png

if TYPE_CHECKING:  # pragma: no cover
    import moderngl

    from node.render.renderer import Renderer

log = logging.getLogger(__name__)

_SLOT_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


class OutputError(NodeError, RuntimeError):
    """An output cannot be opened or used; the message says what to do."""


@dataclass(frozen=True)
class SwapInfo:
    """What was just swapped in."""

    slot: str
    frame_id: int
    tag: str
    pts_ns: int
    swap_rig_ns: int
    host_monotonic_ns: int


class Output(abc.ABC):
    kind: str = "abstract"

    @abc.abstractmethod
    def make_context(self) -> "moderngl.Context":
        """Create (once) and return the GL context the renderer must use."""

    def native_size(self) -> tuple[int, int] | None:
        """(width, height) the display wants, or None if any size will do."""
        return None

    def prepare(self, renderer: "Renderer") -> None:
        """Called after rendering, before the presentation time."""

    def swap(self) -> None:
        """Called at the presentation time. Must return quickly."""

    def after_swap(self, renderer: "Renderer", info: SwapInfo) -> None:
        """Called right after :meth:`swap`; may read back and ship the frame."""

    def poll(self) -> None:
        """Called when the presenter is idle (no frame for a while): keep a window responsive."""

    def close(self) -> None:
        """Release the context and any connection."""


# ------------------------------------------------------------------------- names


def check_slot(slot: str) -> str:
    """``slot`` if it can name snapshot files; OutputError otherwise."""
    if not isinstance(slot, str) or not _SLOT_NAME.fullmatch(slot):
        raise OutputError(
            f"slot name {slot!r} is not usable (letters, digits, '_', '.', '-'; e.g. r0c0): it names snapshot files"
        )
    return slot


def parse_room_spec(spec: str) -> str:
    """``room://HOST:PORT`` (or ``HOST:PORT``) -> ``HOST:PORT``; OutputError if malformed."""
    try:
        return parse_room_address(spec)
    except ValueError as exc:
        raise OutputError(str(exc)) from None


# ------------------------------------------------------------------------- snapshots


def wants_snapshot(info: SwapInfo) -> bool:
    """Whether a swapped frame is one to keep for inspection (its tag starts with ``show``)."""
    return info.tag.startswith("show")


def write_snapshot(snapshot_dir: Path, image: np.ndarray, info: SwapInfo) -> Path:
    """Write what a node shows to ``snapshot_dir/<slot>.png`` and ``<slot>.json``, each atomically.

    Parameters
    ----------
    snapshot_dir : Path
        Created if missing.
    image : (H, W, 3) uint8
        What the projector receives (e.g. ``renderer.read()``), row 0 at the top, RGB.
    info : SwapInfo
        Written to the JSON file (frame_id, tag, pts and swap instants) and into the PNG's
        ``tEXt`` chunks, so a reader can check that the two files belong to the same frame.

    Returns
    -------
    Path
        The PNG written.
    """
    folder = Path(snapshot_dir)
    folder.mkdir(parents=True, exist_ok=True)
    png = folder / f"{info.slot}.png"
    meta = {**asdict(info), "width": int(image.shape[1]), "height": int(image.shape[0]), "png": png.name}
    text = {"Software": "shadowless node", **{k: str(v) for k, v in asdict(info).items()}}
    atomic_write_bytes(png, encode_png(image, compress_level=1, filter="up", text=text))
    atomic_write_bytes(folder / f"{info.slot}.json", (json.dumps(meta, indent=1) + "\n").encode())
    return png


class Snapshots:
    """Shared by the offscreen and window outputs: read back only when someone wants the image."""

    def __init__(self, slot: str, snapshot_dir: Path | None, keep_last: bool):
        self.slot = slot
        self.snapshot_dir = Path(snapshot_dir) if snapshot_dir is not None else None
        self.keep_last = keep_last
        #: (H, W, 3) uint8 copy of the last frame read back (None until one was), and its SwapInfo
        self.last_image: np.ndarray | None = None
        self.last_info: SwapInfo | None = None
        self.snapshots_written = 0
        self.snapshot_failures = 0

    def handle(self, renderer: "Renderer", info: SwapInfo) -> None:
        snapshot = self.snapshot_dir is not None and wants_snapshot(info)
        if not (snapshot or self.keep_last):
            return
        image = renderer.read()
        self.last_image = image.copy()
        self.last_info = info
        if snapshot:
            try:
                write_snapshot(self.snapshot_dir, image, info)
            except OSError as exc:  # inspection aid: never take the projector down over it
                self.snapshot_failures += 1
                log.warning("cannot write the snapshot of frame %d to %s: %s", info.frame_id, self.snapshot_dir, exc)
            else:
                self.snapshots_written += 1


# ------------------------------------------------------------------------- GL


def headless_context() -> "moderngl.Context":
    """A standalone context through EGL (Mesa's llvmpipe where there is no GPU): desktop OpenGL
    3.1+, else OpenGL ES 3.0+ where the driver offers only that (``shadowless node --gl`` or
    ``$SHADOWLESS_GL`` force one; see :mod:`node.render.context`)."""
    # Lazy: moderngl (and its GL libraries) is only needed in the presenter process; the node
    # process imports the outputs package (for open_output's names) but never opens a context.
    from node.render.context import ContextUnavailable, create_headless_context

    try:
        return create_headless_context()
    except ContextUnavailable as exc:
        raise OutputError(
            f"cannot create a headless OpenGL 3.1+ or OpenGL ES 3.0+ context through EGL ({exc}); install Mesa's "
            "EGL and DRI drivers (e.g. apt-get install libegl1 libgl1 libgl1-mesa-dri) or the GPU vendor's EGL"
        ) from exc
