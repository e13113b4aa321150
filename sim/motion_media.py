"""Pictures of the motion study: an animation of the table under the moving hand, and drop-over-time plots.

* :class:`MotionMovie` writes an MP4 (H.264 through PyAV) of several systems side
  by side, one panel each: the light on the table as the camera sees it (grey,
  gamma-encoded so that it looks as it would: black is no light, the mid-light grey
  the intended image, brighter the over-bright ghosts), the hand's outline, the
  system's name, and the time stamp and each panel's current figures below.
* :func:`plot_png` draws the per-frame figures of a :class:`~sim.motion.MotionResult`
  over time (PNG through OpenCV): the largest drop, the area at least 50 % and 90 %
  darker, and the reactive systems' over-bright area, with a legend and units.
"""
from __future__ import annotations

import math
from fractions import Fraction
from pathlib import Path
from typing import Self

import cv2
import numpy as np

from sim.motion import MotionFrame, MotionResult

__all__ = ["COLORS", "MotionMovie", "light_to_grey", "nice_step", "plot_png"]

#: Light shown as full white (so 1 = intended sits at mid-light grey and ghosts are visibly brighter).
WHITE_LIGHT = 1.6

#: Line colours (BGR), in the order systems are given.
COLORS = [(40, 40, 220), (60, 160, 40), (0, 140, 255), (200, 80, 20), (160, 40, 160), (120, 120, 0), (90, 90, 90), (0, 200, 200), (180, 130, 255), (30, 90, 150)]

_FONT = cv2.FONT_HERSHEY_SIMPLEX
_SKIN = np.array([120, 160, 225], np.float32)  # BGR
_BACKGROUND = (24, 24, 24)


def light_to_grey(light: np.ndarray) -> np.ndarray:
    """8-bit display values of relative light: ``255 (light / WHITE_LIGHT) ** (1 / 2.2)`` clipped.

    ``light``: any shape, float (1 = the intended image). Returns uint8 of the same shape
    (1 -> 206, 0.5 -> 150, 0 -> 0, 1.6 and above -> 255).
    """
    v = np.clip(np.asarray(light, np.float64) / WHITE_LIGHT, 0.0, 1.0) ** (1.0 / 2.2)
    return np.round(255.0 * v).astype(np.uint8)


def _text(img, s: str, org, scale: float = 0.5, color=(235, 235, 235), thick: int = 1) -> None:
    cv2.putText(img, s, (int(org[0]), int(org[1])), _FONT, scale, color, thick, cv2.LINE_AA)


class MotionMovie:
    """An MP4 of several systems side by side (call :meth:`add` from ``run_motion(on_frame=...)``).

    Parameters
    ----------
    path : path of the .mp4 written
    systems : list of (name, label)
        The systems shown, left to right: a name of the run's systems and the label above its panel.
    fps : float
    shape : (hr, wr)
        The view's ROI shape (:attr:`sim.motion.MotionFrame.shape`).
    note : str
        One line under the panels (e.g. the gesture).
    """

    HEADER = 44
    FOOTER = 58
    GAP = 8
    MIN_WIDTH = 720  # room for the time stamp and the light key under narrow panels

    def __init__(self, path: str | Path, systems: list[tuple[str, str]], *, fps: float, shape: tuple[int, int], note: str = "") -> None:
        import av  # PyAV; imported here so the numerics do not need it

        if not systems:
            raise ValueError("a movie needs at least one system")
        self.systems = list(systems)
        self.note = note
        self.shape = shape
        hr, wr = shape
        width = max(len(systems) * wr + (len(systems) + 1) * self.GAP, self.MIN_WIDTH)
        self.size = (width + width % 2, self.HEADER + hr + self.FOOTER + (hr + self.HEADER + self.FOOTER) % 2)
        self.frames = 0
        self._container = av.open(str(path), "w")
        try:
            self._stream = self._container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
            self._stream.width, self._stream.height = self.size
            self._stream.pix_fmt = "yuv420p"
            self._stream.options = {"crf": "20", "preset": "veryfast"}
        except Exception:
            self._container.close()
            raise
        self._av = av

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def picture(self, frame: MotionFrame) -> np.ndarray:
        """The (height, width, 3) uint8 BGR picture of ``frame``."""
        hr, wr = frame.shape
        if (hr, wr) != tuple(self.shape):
            raise ValueError(f"frame shape {frame.shape} differs from the movie's {self.shape}")
        W, H = self.size
        img = np.full((H, W, 3), _BACKGROUND, np.uint8)
        hand = frame.hand.reshape(hr, wr)
        outline, _ = cv2.findContours(hand.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        table = frame.table.reshape(hr, wr)
        for k, (name, label) in enumerate(self.systems):
            x = self.GAP + k * (wr + self.GAP)
            light = frame.light[name].reshape(hr, wr)
            grey = np.where(table, light_to_grey(light), 40).astype(np.float32)
            panel = np.repeat(grey[:, :, None], 3, axis=2)
            panel[hand] = 0.65 * panel[hand] + 0.35 * _SKIN
            panel = np.ascontiguousarray(panel.astype(np.uint8))
            cv2.drawContours(panel, outline, -1, (90, 140, 230), 1, cv2.LINE_AA)
            img[self.HEADER:self.HEADER + hr, x:x + wr] = panel
            _text(img, name, (x, 18), 0.55, thick=1)
            _text(img, label, (x, 37), 0.42, (190, 190, 190))
            drop = np.where(table, np.clip(1.0 - light, 0.0, 1.0), 0.0)
            over = np.where(table, np.maximum(light - 1.0, 0.0), 0.0)
            figs = f"max drop {100 * drop.max():.0f} %   over-bright max {100 * over.max():.0f} %"
            _text(img, figs, (x, self.HEADER + hr + 18), 0.42, (200, 200, 200))
        y = self.HEADER + hr + 44
        _text(img, f"t = {frame.time:5.2f} s", (self.GAP, y), 0.6, thick=2)
        self._key(img, (self.GAP + 130, y - 12))
        if self.note:
            _text(img, self.note, (self.GAP + 470, y), 0.42, (190, 190, 190))
        return img

    def _key(self, img: np.ndarray, org: tuple[int, int]) -> None:
        """A grey ramp from no light to 150 %, marked at 0, 50, 100 (intended) and 150 %."""
        x0, y0 = org
        w, h = 240, 12
        ramp = light_to_grey(np.linspace(0.0, 1.5, w))
        img[y0:y0 + h, x0:x0 + w] = ramp[None, :, None]
        for v in (0.0, 0.5, 1.0, 1.5):
            x = x0 + round(v / 1.5 * (w - 1))
            cv2.line(img, (x, y0 + h), (x, y0 + h + 3), (235, 235, 235), 1)
            _text(img, f"{100 * v:.0f}%", (x - 10, y0 + h + 14), 0.35)
        _text(img, "light", (x0 + w + 8, y0 + 10), 0.4, (190, 190, 190))

    def add(self, frame: MotionFrame) -> None:
        """Encode one frame."""
        picture = self.picture(frame)
        vf = self._av.VideoFrame.from_ndarray(picture, format="bgr24")
        for packet in self._stream.encode(vf):
            self._container.mux(packet)
        self.frames += 1

    def close(self) -> None:
        """Flush and close the file (idempotent)."""
        if self._container is None:
            return
        try:
            for packet in self._stream.encode():
                self._container.mux(packet)
        finally:
            self._container.close()
            self._container = None


# ---------------------------------------------------------------- plots


def nice_step(span: float, ticks: int = 5) -> float:
    """A round tick step (1, 2 or 5 x 10^k) giving about ``ticks`` intervals over ``span`` (> 0)."""
    if not (span > 0 and math.isfinite(span)):
        return 1.0
    raw = span / ticks
    k = 10.0 ** math.floor(math.log10(raw))
    return next(m * k for m in (1.0, 2.0, 5.0, 10.0) if m * k >= raw)


def _chart(img, rect, series, *, title: str, t_end: float, xlabel: bool) -> None:
    """One line chart in ``rect`` = (x, y, w, h): ``series`` = [(times, values, colour)]."""
    x, y, w, h = rect
    top = max((float(np.max(v)) for _, v, _ in series if len(v)), default=0.0)
    step = nice_step(top if top > 0 else 1.0)
    ymax = step * max(1, math.ceil(top / step - 1e-9)) if top > 0 else 1.0
    cv2.rectangle(img, (x, y), (x + w, y + h), (0, 0, 0), 1)
    _text(img, title, (x, y - 8), 0.5, (0, 0, 0))
    v = 0.0
    while v <= ymax + 1e-9:
        py = y + h - round(v / ymax * h)
        cv2.line(img, (x, py), (x + w, py), (225, 225, 225), 1)
        _text(img, f"{v:g}", (x - 8 - 9 * len(f'{v:g}'), py + 4), 0.4, (60, 60, 60))
        v += step
    ts = nice_step(t_end, 10)
    t = 0.0
    while t <= t_end + 1e-9:
        px = x + round(t / t_end * w)
        cv2.line(img, (px, y + h), (px, y + h + 4), (0, 0, 0), 1)
        if xlabel:
            _text(img, f"{t:g}", (px - 8, y + h + 18), 0.4, (60, 60, 60))
        t += ts
    for times, values, color in series:
        if len(times) == 0:
            continue
        pts = np.column_stack([x + times / t_end * w, y + h - np.asarray(values) / ymax * h])
        cv2.polylines(img, [np.round(pts).astype(np.int32)], False, color, 2, cv2.LINE_AA)


def plot_png(result: MotionResult, path: str | Path, *, systems: list[str] | None = None, title: str = "") -> None:
    """Write the figures of ``result`` over time as a PNG (four charts sharing the time axis, a legend).

    ``systems``: which to draw (default all); reactive systems alone have the over-bright chart.
    """
    names = list(result.frames) if systems is None else list(systems)
    for n in names:
        if n not in result.frames:
            raise ValueError(f"no system {n!r} in the result; it has {', '.join(result.frames)}")
    colors = {n: COLORS[k % len(COLORS)] for k, n in enumerate(names)}
    t = result.times
    t_end = float(t[-1] + 1.0 / result.fps) if len(t) else 1.0
    W, left, right, ch, gap = 1100, 90, 30, 170, 62
    legend_rows = math.ceil(len(names) / 4)
    top = 50 + 22 * legend_rows + 30
    H = top + 4 * ch + 3 * gap + 60
    img = np.full((H, W, 3), 255, np.uint8)
    _text(img, title or "light drop under the moving hand, per frame", (left, 28), 0.65, (0, 0, 0), 2)
    for k, n in enumerate(names):
        lx, ly = left + (k % 4) * 250, 52 + 22 * (k // 4)
        cv2.line(img, (lx, ly - 4), (lx + 28, ly - 4), colors[n], 3, cv2.LINE_AA)
        _text(img, n, (lx + 36, ly), 0.45, (0, 0, 0))
    charts = [
        ("largest light drop (%)", lambda f: 100.0 * f["max_drop"]),
        ("area with >= 50 % light drop (cm^2)", lambda f: f["area_above_50_mm2"] / 100.0),
        ("umbra: area with >= 90 % light drop (cm^2)", lambda f: f["area_above_90_mm2"] / 100.0),
        ("reactive ghosts: area >= 10 % over-bright (cm^2)", lambda f: f["area_overbright_above_10_mm2"] / 100.0),
    ]
    for k, (label, value) in enumerate(charts):
        y = top + k * (ch + gap)
        series = [(t, value(result.frames[n]), colors[n]) for n in names if k < 3 or "area_overbright_above_10_mm2" in result.frames[n]]
        _chart(img, (left, y, W - left - right, ch), series, title=label, t_end=t_end, xlabel=True)
    _text(img, "time (s)", (W // 2 - 30, H - 14), 0.5, (0, 0, 0))
    if not cv2.imwrite(str(path), img):
        raise OSError(f"could not write {path}")
