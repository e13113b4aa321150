"""The stored blend as the console shows it: its figures and its before/after picture.

The blend job leaves its result in the rig's ``blend/`` folder (:mod:`coordinator.blend_store`):
the maps, ``info`` (headroom, brightness cost, uniformity before and after, captures, when) and
the ratio pictures ``before`` / ``after``. :class:`BlendView` reads it again only when the
store's pointer file changed (a new blend, or the blend cleared), draws the picture once per
blend (:mod:`coordinator.console.blend_figure`) and keeps both; a store that cannot be read is
reported in one line (``problem``) and read again at the next ask.
"""
from __future__ import annotations

import logging
import math
import os
import threading
from pathlib import Path
from typing import Any

from coordinator.blend_store import BLEND_DIR, POINTER, BlendStoreError, load_blend
from coordinator.console.blend_figure import PANEL_TITLES, figure_png

log = logging.getLogger(__name__)

#: the figures of the blend's info the page shows (the rest is for scripts)
INFO_KEYS = ("created_at", "headroom", "brightness_cost", "uniformity_before", "uniformity_after", "captures",
             "colour_after", "map_scale")
#: what the page says where there is no blend
NO_BLEND = ("no blend in this rig yet: run the blend job (Jobs: blend here, or `shadowless blend RIG`) "
            "once the projectors are calibrated")


def _plain(v: Any) -> Any:
    """A figure for the page: numbers (finite), strings and booleans; anything else None."""
    if isinstance(v, bool) or isinstance(v, str):
        return v
    if isinstance(v, (int, float)):
        return v if math.isfinite(v) else None
    return None


class BlendView:
    """What the console shows of the stored blend, read once per stored blend (thread-safe)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._key: tuple | None = None
        self._doc: dict | None = None
        self._png: bytes | None = None
        self.loads = 0                   # stored blends read (tests: a blend is read once, not per ask)

    @staticmethod
    def _pointer_key(rig_dir: Path) -> tuple | None:
        """The store's pointer as it is now: its text and change time (None: nothing stored)."""
        f = Path(rig_dir) / BLEND_DIR / POINTER
        try:
            st = os.stat(f)
            return f.read_text()[:64], st.st_mtime_ns, st.st_ino
        except (FileNotFoundError, NotADirectoryError):
            return None
        except OSError as exc:
            return ("unreadable", str(exc))

    def _refresh(self, rig_dir: Path) -> None:
        key = self._pointer_key(rig_dir)
        if key == self._key and key is not None:
            return
        self._key, self._doc, self._png = key, None, None
        if key is None:
            return
        self.loads += 1
        try:
            stored = load_blend(rig_dir)
        except (BlendStoreError, OSError) as exc:
            self._key = None                # asked again next time: the store may be mid-write
            self._doc = {"problem": f"the stored blend cannot be read: {exc}"}
            return
        if stored is None:
            return
        info = stored.info if isinstance(stored.info, dict) else {}
        doc: dict[str, Any] = {k: _plain(info.get(k)) for k in INFO_KEYS}
        generation = str(key[0]).strip() or "x"
        doc.update(blend_id=stored.blend_id, slots=sorted(stored.maps), pictures=sorted(stored.pictures),
                   url=None, span=None, range=None, layout=None, problem=None)
        shown = {n: stored.pictures[n] for n in PANEL_TITLES if n in stored.pictures}
        if shown:
            try:
                self._png, layout = figure_png(shown)
            except ValueError as exc:
                doc["problem"] = f"the blend's pictures cannot be drawn: {exc}"
            else:
                doc.update(url=f"/api/pictures/blend.png?v={generation}-{stored.blend_id}", span=layout["span"],
                           range=layout["range"], layout=layout)
        self._doc = doc

    def describe(self, rig_dir: Path) -> dict | None:
        """The stored blend's figures for ``/api/pictures`` (None: no blend stored). Blocking."""
        with self._lock:
            self._refresh(Path(rig_dir))
            return None if self._doc is None else dict(self._doc)

    def png(self, rig_dir: Path) -> bytes | None:
        """The before/after picture as PNG, None when there is none. Blocking."""
        with self._lock:
            self._refresh(Path(rig_dir))
            return self._png
