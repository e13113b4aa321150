"""The headless output: renders into an EGL context; nothing is displayed."""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from node.outputs.base import Output, Snapshots, SwapInfo, check_slot, headless_context

if TYPE_CHECKING:  # pragma: no cover
    import moderngl

    from node.render.renderer import Renderer


class OffscreenOutput(Output):
    """Headless output: renders into an EGL context; nothing is displayed.

    Parameters
    ----------
    slot : str
        The node's slot (names the snapshot files).
    snapshot_dir : Path, optional
        If given, every frame whose tag starts with ``show`` is written to
        ``snapshot_dir/<slot>.png`` (+ ``.json``) atomically, after the swap.
    keep_last : bool
        Also read back every other swapped frame into :attr:`last_image` (tests).
        Otherwise frames are read back only for snapshots.
    """

    kind = "offscreen"

    def __init__(self, *, slot: str, snapshot_dir: Path | None = None, keep_last: bool = False):
        self.slot = check_slot(slot)
        self._snap = Snapshots(slot, snapshot_dir, keep_last)
        self._ctx: Any = None

    @property
    def last_image(self) -> np.ndarray | None:
        """(H, W, 3) uint8: the last frame read back after a swap (a copy), or None."""
        return self._snap.last_image

    @property
    def last_info(self) -> SwapInfo | None:
        return self._snap.last_info

    @property
    def snapshots_written(self) -> int:
        return self._snap.snapshots_written

    def make_context(self) -> "moderngl.Context":
        if self._ctx is None:
            self._ctx = headless_context()
        return self._ctx

    def after_swap(self, renderer: "Renderer", info: SwapInfo) -> None:
        self._snap.handle(renderer, info)

    def close(self) -> None:
        if self._ctx is not None:
            self._ctx.release()
            self._ctx = None
