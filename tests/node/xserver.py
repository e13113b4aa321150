"""Test helpers for outputs that draw on an X server: a private Xvfb, and what it displays.

Loaded by path (``load()``), also inside the scripts tests run in subprocesses, since an output
that opens a display wants a process of its own.
"""
from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import importlib.util
import os
import select
import shutil
import subprocess
from pathlib import Path
from typing import Iterator

import numpy as np

HERE = Path(__file__).resolve()


def load():
    """This module, imported by its path (test modules cannot import their siblings by name)."""
    spec = importlib.util.spec_from_file_location("xserver", HERE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@contextlib.contextmanager
def xvfb(size: str = "640x480x24") -> Iterator[str]:
    """A private Xvfb on a free display number; yields its DISPLAY string (``:N``)."""
    exe = shutil.which("Xvfb") or ("/usr/bin/Xvfb" if os.access("/usr/bin/Xvfb", os.X_OK) else None)
    if exe is None:
        raise RuntimeError("Xvfb is not installed: apt-get install xvfb (or `make system-deps`)")
    read_fd, write_fd = os.pipe()
    proc = subprocess.Popen([exe, "-displayfd", str(write_fd), "-screen", "0", size, "-nolisten", "tcp"],
                            pass_fds=(write_fd,), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    os.close(write_fd)
    try:
        ready, _, _ = select.select([read_fd], [], [], 20.0)
        number = os.read(read_fd, 64).decode().strip() if ready else ""
        if not number.isdigit():
            proc.kill()
            err = proc.communicate(timeout=10)[1].decode(errors="replace")
            raise RuntimeError(f"Xvfb did not start: {err[-2000:]}")
        yield f":{number}"
    finally:
        os.close(read_fd)
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)
        if proc.stderr:
            proc.stderr.close()


class _XImage(ctypes.Structure):
    _fields_ = [("width", ctypes.c_int), ("height", ctypes.c_int), ("xoffset", ctypes.c_int),
                ("format", ctypes.c_int), ("data", ctypes.POINTER(ctypes.c_ubyte)), ("byte_order", ctypes.c_int),
                ("bitmap_unit", ctypes.c_int), ("bitmap_bit_order", ctypes.c_int), ("bitmap_pad", ctypes.c_int),
                ("depth", ctypes.c_int), ("bytes_per_line", ctypes.c_int), ("bits_per_pixel", ctypes.c_int),
                ("red_mask", ctypes.c_ulong), ("green_mask", ctypes.c_ulong), ("blue_mask", ctypes.c_ulong)]


class XScreen:
    """What the X server of ``$DISPLAY`` displays, read with XGetImage (independent of GL)."""

    def __init__(self) -> None:
        x11 = ctypes.CDLL(ctypes.util.find_library("X11") or "libX11.so.6")
        x11.XOpenDisplay.restype = ctypes.c_void_p
        x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
        x11.XDefaultRootWindow.restype = ctypes.c_ulong
        x11.XDefaultRootWindow.argtypes = [ctypes.c_void_p]
        x11.XGetImage.restype = ctypes.POINTER(_XImage)
        x11.XGetImage.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_int, ctypes.c_int, ctypes.c_uint,
                                  ctypes.c_uint, ctypes.c_ulong, ctypes.c_int]
        x11.XSync.argtypes = [ctypes.c_void_p, ctypes.c_int]
        x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
        self.x11 = x11
        self.dpy = x11.XOpenDisplay(None)
        if not self.dpy:
            raise RuntimeError(f"cannot open DISPLAY={os.environ.get('DISPLAY')!r}")

    def grab(self, w: int, h: int) -> np.ndarray:
        """(h, w, 3) uint8 RGB, row 0 at the top, from the root window's top-left corner."""
        x11 = self.x11
        x11.XSync(self.dpy, 0)
        img = x11.XGetImage(self.dpy, x11.XDefaultRootWindow(self.dpy), 0, 0, w, h, 0xFFFFFFFF, 2).contents
        assert (img.bits_per_pixel, img.red_mask, img.green_mask, img.blue_mask, img.byte_order) == \
            (32, 0xFF0000, 0xFF00, 0xFF, 0), "unexpected X visual"
        raw = np.ctypeslib.as_array(img.data, shape=(img.height * img.bytes_per_line,))
        return raw.reshape(img.height, img.bytes_per_line)[:, : w * 4].reshape(h, w, 4)[:, :, [2, 1, 0]].copy()

    def close(self) -> None:
        if self.dpy:
            self.x11.XCloseDisplay(self.dpy)
            self.dpy = None
