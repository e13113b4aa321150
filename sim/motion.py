"""A hand in motion over the table: light drop per frame for each projector subset, and a reactive model.

The paper's claim, measured: a synthetic aperture computes nothing while the hand
moves, so its soft shadow is where the hand is at every frame; a reactive system
(:mod:`sim.reactive`) compensates for where the hand was one latency ago.

:func:`run_motion` samples a gesture (:data:`GESTURES`: waving 0.2 m above the
table, reaching in, touching) at the projectors' frame rate and, per frame, reads
the room's ground truth once (which projectors' lines of sight the hand crosses,
:meth:`sim.room.Room.dynamic_state`) and from it computes:

* for every passive rig (P1 ... P25 of :data:`sim.scene.SUBSETS`, and P2 of
  :data:`sim.reactive.PRIOR_RIGS`: every projector at its nominal drive), the light-drop
  map ``1 - sum_i E_i v_i / sum_i E_i`` (what :meth:`sim.truth.Truth.light_drop`
  returns with that subset powered, from the same data without re-summing every
  projector);
* for every :class:`~sim.reactive.ReactiveSpec`, the light it puts on the table
  (:func:`sim.reactive.reactive_light`, fed the visibility of ``latency`` frames
  earlier; frames before the first are the gesture at negative times).

Per frame and system, over the table (figures in mm^2 of table, from the camera
pixels' exact footprints, :func:`table_pixel_area`):

* ``max_drop``: the largest drop; ``area_above_{10,50,90}_mm2``: the area whose
  drop is at least 10, 50 or 90 % (the last is the umbra); ``deficit_mm2``: the
  light lost, ``sum(drop x area)`` (mm^2 of table-equivalent darkness);
* reactive systems also: ``max_overbright`` (largest ``light - 1``),
  ``area_overbright_above_10_mm2`` (at least 10 % too bright: the ghosts),
  ``surplus_mm2`` (``sum(max(light - 1, 0) x area)``).

Areas are of the table surface, also where the hand hides it from the room's camera
(what an observer sees of a shadow depends on where they stand; under a fingertip
touching the table every rig has a small umbra nobody sees).

Each frame is shown for ``1 / fps`` s, so a figure integrated over time is its
sum over frames divided by fps (``..._mm2_s``).
"""
from __future__ import annotations

import math
import sys
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from sim.hand import Hand, HandPath
from sim.precompute import TABLE
from sim.reactive import PRIOR_RIGS, ReactiveSpec, reactive_light, rig_slots, shares
from sim.scene import SUBSETS

__all__ = [
    "DEFAULT_FPS",
    "DEFAULT_SUBSETS",
    "GESTURES",
    "THRESHOLDS",
    "MotionFrame",
    "MotionResult",
    "WavePath",
    "drop_figures",
    "gesture",
    "overbright_figures",
    "reach_path",
    "run_motion",
    "table_pixel_area",
    "touch_path",
]

#: Default frame rate: the projectors' refresh (a 60 Hz video signal), so one frame is 16.7 ms.
DEFAULT_FPS = 60.0

#: Passive rigs measured by default: the paper's subsets and the two-projector rig of prior systems.
DEFAULT_SUBSETS: tuple[str, ...] = (*SUBSETS, *PRIOR_RIGS)

#: Drop thresholds of the area figures (fractions of the light).
THRESHOLDS = (0.1, 0.5, 0.9)

#: Frames per progress line on stderr.
_PROGRESS_EVERY = 30


class Path(Protocol):
    """Anything that places a hand at a time: :class:`WavePath`, :class:`sim.hand.HandPath`."""

    def hand_at(self, t: float) -> Hand: ...


@dataclass(frozen=True)
class WavePath:
    """A flat hand waving side to side above the table: palm centre ``x = cx + amplitude sin(2 pi t / period)``.

    The defaults wave 250 mm either side of the table centre once a second, 0.2 m
    above the table (the hand's lowest point): 1.0 m/s on average, 1.57 m/s
    through the middle, so in 100 ms the hand moves up to 157 mm, about twice
    its palm's width.
    """

    center: tuple[float, float] = (0.0, 0.0)
    amplitude: float = 250.0
    period: float = 1.0
    height: float = 200.0
    template: Hand = field(default_factory=Hand)

    def __post_init__(self) -> None:
        if not (self.period > 0 and self.amplitude >= 0 and self.height >= 0):
            raise ValueError("period must be positive, amplitude and height >= 0")

    def hand_at(self, t: float) -> Hand:
        """The hand at ``t`` seconds (any real t: the wave has no start)."""
        x = self.center[0] + self.amplitude * math.sin(2.0 * math.pi * t / self.period)
        tpl = self.template
        return Hand(position=(x, self.center[1]), height=self.height, yaw_deg=tpl.yaw_deg, pose=tpl.pose, scale=tpl.scale, side=tpl.side)


def reach_path(*, height: float = 200.0, target: tuple[float, float] = (60.0, 20.0)) -> HandPath:
    """A flat hand reaching in from the near edge (-y) to hover over ``target``, then withdrawing (3.5 s, looped).

    0-1 s in from 520 mm off the table centre at 320 mm, 1-2 s hovering at
    ``height``, 2-3 s back out, 3-3.5 s away (the arm still over the edge).
    """
    x, y = target
    kf = ((0.0, x - 60.0, -520.0, 320.0), (1.0, x, y, height), (2.0, x, y, height), (3.0, x - 60.0, -520.0, 320.0), (3.5, x - 60.0, -520.0, 320.0))
    return HandPath(kf, loop=True, template=Hand(height=height))


def touch_path(*, points: tuple[tuple[float, float], ...] = ((-250.0, -40.0), (200.0, 80.0)), lift: float = 150.0) -> HandPath:
    """A pointing hand touching the table at each of ``points`` in turn (1.2 s per touch, looped).

    Per point: 0.4 s down from ``lift`` mm to the table, 0.3 s touching, 0.3 s up,
    0.2 s moving over to the next point at ``lift``.
    """
    if not points:
        raise ValueError("touch_path needs at least one point")
    kf: list[tuple[float, float, float, float]] = []
    t = 0.0
    for x, y in points:
        kf += [(t, x, y, lift), (t + 0.4, x, y, 0.0), (t + 0.7, x, y, 0.0), (t + 1.0, x, y, lift)]
        t += 1.2
    x, y = points[0]
    kf.append((t, x, y, lift))
    return HandPath(tuple(kf), loop=True, template=Hand(height=lift, pose="point"))


#: name -> (factory taking the hand height in mm, what it does).
GESTURES: dict[str, tuple[Callable[[float], Path], str]] = {
    "wave": (lambda h: WavePath(height=h), "a flat hand waving +-250 mm across the table centre once a second, HEIGHT above it"),
    "reach": (lambda h: reach_path(height=h), "a flat hand reaching in from the near edge, hovering HEIGHT above the table, withdrawing (3.5 s)"),
    "touch": (lambda h: touch_path(), "a pointing hand touching the table at two places in turn (1.2 s per touch; HEIGHT unused)"),
}


def gesture(name: str, *, height: float = 200.0) -> Path:
    """The path of gesture ``name`` (a key of :data:`GESTURES`)."""
    try:
        factory, _ = GESTURES[name]
    except KeyError:
        raise ValueError(f"no gesture {name!r}; gestures are {', '.join(GESTURES)}") from None
    return factory(height)


# ---------------------------------------------------------------- figures


def table_pixel_area(table_to_camera: np.ndarray, roi: tuple[int, int, int, int]) -> np.ndarray:
    """Table area (mm^2) each camera pixel of ``roi`` covers, in closed form.

    A camera pixel (u, v) sees table point ``(x, y) = H^-1 (u, v)`` (a plane
    homography); the area of its unit square is the Jacobian determinant of that
    map, ``|det(G)| / (g3 . (u, v, 1))^3`` for ``G = H^-1`` with third row g3.

    Parameters
    ----------
    table_to_camera : (3, 3) float64
        Table mm -> camera pixels (:meth:`sim.truth.Truth.table_to_camera_homography`).
    roi : (x0, y0, x1, y1)
        Camera pixels, pixel centres at integer coordinates.

    Returns
    -------
    (y1 - y0, x1 - x0) float64
    """
    H = np.asarray(table_to_camera, np.float64)
    if H.shape != (3, 3):
        raise ValueError(f"table_to_camera must be (3, 3), got {H.shape}")
    G = np.linalg.inv(H)
    x0, y0, x1, y1 = roi
    u, v = np.meshgrid(np.arange(x0, x1, dtype=np.float64), np.arange(y0, y1, dtype=np.float64))
    w = G[2, 0] * u + G[2, 1] * v + G[2, 2]
    return np.abs(np.linalg.det(G) / w**3)


def drop_figures(drop: np.ndarray, area: np.ndarray) -> dict[str, float]:
    """Light-drop figures of one frame (module docstring).

    Parameters
    ----------
    drop : (P,) float
        Fraction of the intended light missing at each point (<= 0: none missing).
    area : (P,) float64
        mm^2 per point; 0 off the table.
    """
    d = np.clip(np.asarray(drop, np.float64), 0.0, 1.0)
    a = np.asarray(area, np.float64)
    if d.shape != a.shape:
        raise ValueError(f"drop and area must have one shape, got {d.shape} and {a.shape}")
    on = a > 0
    out = {"max_drop": float(d[on].max(initial=0.0))}
    for th in THRESHOLDS:
        out[f"area_above_{round(100 * th)}_mm2"] = float(a[d >= th].sum())
    out["deficit_mm2"] = float((d * a).sum())
    return out


def overbright_figures(light: np.ndarray, area: np.ndarray) -> dict[str, float]:
    """Over-bright figures of one frame: ``max_overbright``, ``area_overbright_above_10_mm2``, ``surplus_mm2``.

    ``light``: (P,) float, 1 = the intended image; ``area`` as :func:`drop_figures`.
    """
    over = np.maximum(np.asarray(light, np.float64) - 1.0, 0.0)
    a = np.asarray(area, np.float64)
    if over.shape != a.shape:
        raise ValueError(f"light and area must have one shape, got {over.shape} and {a.shape}")
    return {
        "max_overbright": float(over[a > 0].max(initial=0.0)),
        "area_overbright_above_10_mm2": float(a[over >= 0.1].sum()),
        "surplus_mm2": float((over * a).sum()),
    }


# ---------------------------------------------------------------- the run


@dataclass(eq=False)
class MotionFrame:
    """One frame, as :func:`run_motion` hands it to ``on_frame`` (for pictures).

    Attributes
    ----------
    index : int
    time : float
        Seconds from the start.
    shape : (int, int)
        The view's ROI shape (hr, wr); every map below is flat over it.
    light : dict
        system name -> (hr * wr,) float32 light (1 = intended; passive: ``1 - drop``).
    hand : (hr * wr,) bool
        The camera sees the hand at the pixel.
    table : (hr * wr,) bool
        The pixel sees the table.
    """

    index: int
    time: float
    shape: tuple[int, int]
    light: dict[str, np.ndarray]
    hand: np.ndarray
    table: np.ndarray


@dataclass
class MotionResult:
    """Per-frame figures of every system; :meth:`summary` integrates them."""

    fps: float
    times: np.ndarray  # (F,) float64 s
    frames: dict[str, dict[str, np.ndarray]]  # system -> figure -> (F,) float64
    projectors: dict[str, int]
    reactive: dict[str, ReactiveSpec]
    table_mm2: float

    def summary(self) -> dict:
        """Per system: the time integrals (``integrated_<figure>_s``), maxima and seconds with an umbra."""
        dt = 1.0 / self.fps
        out = {}
        for name, figs in self.frames.items():
            s: dict = {"projectors": self.projectors[name]}
            spec = self.reactive.get(name)
            if spec is not None:
                s.update({"reactive": True, "latency_ms": round(1000.0 * spec.latency_frames(self.fps) / self.fps, 1),
                          "latency_frames": spec.latency_frames(self.fps), "cap": spec.cap, "suppress": spec.suppress, "rig": spec.subset})
            s["max_drop"] = round(float(figs["max_drop"].max()), 4)
            for key, series in figs.items():
                if key.endswith("_mm2"):
                    s[f"integrated_{key}_s"] = round(float(series.sum() * dt), 1)
                    s[f"peak_{key}"] = round(float(series.max()), 1)
            if "max_overbright" in figs:
                s["max_overbright"] = round(float(figs["max_overbright"].max()), 4)
            s["umbra_visible_s"] = round(float((figs["area_above_90_mm2"] > 0).sum() * dt), 4)
            out[name] = s
        return out


def _passive_weights(view, slots: list[str]) -> np.ndarray:
    return np.stack([view.plans[s].weight.reshape(-1).astype(np.float32) for s in slots])


def run_motion(
    room,
    path: Path,
    *,
    duration: float = 5.0,
    fps: float = DEFAULT_FPS,
    subsets: list[str] | None = None,
    reactive: list[ReactiveSpec] = (),
    on_frame: Callable[[MotionFrame], None] | None = None,
    progress: bool = False,
) -> MotionResult:
    """Sample ``path`` for ``duration`` s at ``fps`` and compute every system's figures per frame.

    Parameters
    ----------
    room : sim.room.Room
        A room with a table (its occluders are replaced; its powered projectors are left alone).
    path : a gesture (:func:`gesture`), anything with ``hand_at(t) -> Hand``
    subsets : list of str
        Passive rigs (names for :func:`sim.reactive.rig_slots`); default :data:`DEFAULT_SUBSETS`.
    reactive : list of ReactiveSpec
    on_frame : callable, optional
        Called with each :class:`MotionFrame` (the light maps, for animations).
    progress : bool
        A line on stderr every 30 frames.

    Returns
    -------
    MotionResult with ``round(duration * fps)`` frames at ``t = k / fps``.
    """
    subsets = list(DEFAULT_SUBSETS) if subsets is None else list(subsets)
    rigs = {name: rig_slots(name) for name in [*subsets, *(r.subset for r in reactive)]}
    if not (fps > 0 and duration > 0):
        raise ValueError("fps and duration must be positive")
    n_frames = max(1, round(duration * fps))
    if room.scene.table is None:
        raise ValueError("the motion study needs a room with a table")
    view = room.view()
    x0, y0, x1, y1 = view.roi
    W = room.camera_size()[0]
    table = view.kind.reshape(-1) == TABLE
    area = np.where(table, table_pixel_area(room.truth.table_to_camera_homography(), view.roi).reshape(-1), 0.0)
    weights = {name: _passive_weights(view, rigs[name]) for name in set(subsets) | {r.subset for r in reactive}}
    totals = {name: w.sum(axis=0, dtype=np.float64) for name, w in weights.items()}
    share = {name: shares(w) for name, w in weights.items()}
    names = {r.name(fps): r for r in reactive}
    if len(names) != len(reactive):
        raise ValueError("two reactive systems with the same name (same latency in frames, rig and rule)")
    lag = max((r.latency_frames(fps) for r in reactive), default=0)
    history: deque[dict[str, np.ndarray]] = deque(maxlen=lag + 1)

    def blocked_at(t: float):
        room.set_occluders([path.hand_at(t)])
        dyn = room.dynamic_state(view)
        return dict(dyn.blocked), dyn.hand_index

    for k in range(lag, 0, -1):  # what the reactive systems saw before the first frame
        history.append(blocked_at(-k / fps)[0])
    empty = np.zeros(0, np.int64)
    frames: dict[str, dict[str, list[float]]] = {}
    times = np.arange(n_frames, dtype=np.float64) / fps
    for f, t in enumerate(times):
        blocked, hand_index = blocked_at(float(t))
        history.append(blocked)
        lights: dict[str, np.ndarray] = {}
        figs: dict[str, dict[str, float]] = {}
        for name in subsets:
            lost = np.zeros(len(area), np.float64)
            for i, slot in enumerate(rigs[name]):
                b = blocked.get(slot, empty)
                lost[b] += weights[name][i, b]
            with np.errstate(divide="ignore", invalid="ignore"):
                drop = np.where(totals[name] > 0, np.clip(lost / totals[name], 0.0, 1.0), 0.0)
            lights[name] = (1.0 - drop).astype(np.float32)
            figs[name] = drop_figures(drop, area)
        for name, spec in names.items():
            slots = rigs[spec.subset]
            seen = history[-1 - spec.latency_frames(fps)]
            light = reactive_light(share[spec.subset], [seen.get(s, empty) for s in slots], [blocked.get(s, empty) for s in slots],
                                   cap=spec.cap, suppress=spec.suppress)
            lights[name] = light.astype(np.float32)
            figs[name] = {**drop_figures(1.0 - light, area), **overbright_figures(light, area)}
        for name, fig in figs.items():
            row = frames.setdefault(name, {})
            for key, v in fig.items():
                row.setdefault(key, []).append(v)
        if on_frame is not None:
            hand = np.zeros(view.shape, bool)
            hy, hx = np.divmod(hand_index, W)
            inside = (hx >= x0) & (hx < x1) & (hy >= y0) & (hy < y1)
            hand[hy[inside] - y0, hx[inside] - x0] = True
            on_frame(MotionFrame(f, float(t), view.shape, lights, hand.reshape(-1), table))
        if progress and (f + 1) % _PROGRESS_EVERY == 0:
            print(f"motion: frame {f + 1}/{n_frames} (t = {t:.2f} s)", file=sys.stderr, flush=True)
    room.set_occluders([])
    projectors = {name: len(rigs[name]) for name in subsets}
    projectors.update({name: len(rigs[spec.subset]) for name, spec in names.items()})
    return MotionResult(
        fps=float(fps), times=times,
        frames={name: {k: np.asarray(v) for k, v in figs.items()} for name, figs in frames.items()},
        projectors=projectors, reactive=names, table_mm2=float(area.sum()),
    )
