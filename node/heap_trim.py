"""Give the C heap's free pages back to the system (glibc's ``malloc_trim``).

Why: a video's decoder frees its pictures (FFmpeg's frame pool, 3.1 MB each at 1080p 4:2:0) and
its context when it closes, but glibc keeps freed memory in its arenas for the next allocation,
and the decode thread's arena is not shrunk by ``free`` alone: a presenter that played a 1080p
video kept 20 MB resident after the decoder closed (196.8 MB playing, 196.9 closed, 177.2 after
``malloc_trim(0)``; bench/node_video_memory.py's process, 2026-12-07, load ~15). The trim walks
every arena and takes a few ms (6 ms there), so the presenter has it run on the decode thread,
after that thread closed its decoder (:meth:`node.asset_frames.DecodeAhead.close` with
``wait=False``): the presenter's thread never waits for it, except on a malloc of its own for the
moments an arena is locked.

Only where nothing is about to take the memory back: after a show stops, not between two videos
(the next decoder would fault the same pages in again). Where glibc is not the C library (musl,
macOS) this does nothing.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import threading

_trim = None
_looked_up = False
_lock = threading.Lock()


def _malloc_trim():
    """glibc's ``int malloc_trim(size_t pad)``, or None where there is none."""
    global _trim, _looked_up
    with _lock:
        if not _looked_up:
            _looked_up = True
            try:
                libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
                fn = libc.malloc_trim
                fn.argtypes, fn.restype = [ctypes.c_size_t], ctypes.c_int
                _trim = fn
            except (OSError, AttributeError):
                _trim = None
        return _trim


def trim_now() -> bool:
    """Trim on this thread; True if glibc's trim ran (whether or not it freed anything)."""
    fn = _malloc_trim()
    if fn is None:
        return False
    fn(0)
    return True
