"""Each projector's light on a camera grid: :class:`Contributions`, and the grid's geometry.

The camera sees, at a point ``x`` of the surface, ``sum_i black_i(x) + T_i(x) * y_i(x)`` where
``y_i`` is projector ``i``'s linear value there (its node shows content through its inverse
response LUT, so light above black is linear in the value) and ``T_i`` its light above black at
full white. A :class:`Contributions` holds ``T_i`` (``white``) and ``black_i`` per projector on a
grid that is the camera image reduced ``scale`` times, and the calibrated camera -> projector
mapping that places each grid point in each projector's pixels.

The grid: for a camera image of ``W x H`` pixels and a grid of ``w x h`` (``w = ceil(W / scale)``),
grid pixel ``(gx, gy)`` has its centre at camera pixel ``((gx + 0.5) W / w - 0.5, (gy + 0.5) H / h -
0.5)``, the same convention as the blend maps' texels (:mod:`protos.blend`).

Planar rigs map camera pixels to projector pixels with a homography. A mesh rig gives each grid
point its projector coordinates instead (``projector_xy``: where the projector shows the surface
point the camera sees there, NaN where it does not reach it); :meth:`Contributions.projector_coords`
is the one place that asks, and :func:`projector_mapper` turns either into a function of camera
pixels.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping

import numpy as np

from imaging.blending.errors import BlendError

__all__ = ["Contributions", "LUMA", "luma", "grid_shape", "grid_to_camera", "apply_homography_grid", "projector_mapper"]

#: Rec. 709 luminance weights, applied to the camera's linear RGB
LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)


def luma(image: np.ndarray) -> np.ndarray:
    """``(..., 3) -> (...)`` float32: luminance of linear RGB (Rec. 709 weights)."""
    a = np.asarray(image, np.float32)
    if a.shape[-1] != 3:
        raise ValueError(f"luminance needs (..., 3) RGB, got shape {a.shape}")
    return a @ LUMA


def grid_shape(camera_size: tuple[int, int], scale: int) -> tuple[int, int]:
    """``(h, w)`` of the grid for a camera of ``(W, H)`` pixels reduced ``scale`` times."""
    W, H = (int(v) for v in camera_size)
    return int(math.ceil(H / scale)), int(math.ceil(W / scale))


def grid_to_camera(camera_size: tuple[int, int], shape: tuple[int, int]) -> np.ndarray:
    """``(h, w, 2) float64``: camera pixel ``(x, y)`` of every grid pixel's centre."""
    W, H = (int(v) for v in camera_size)
    h, w = shape
    xs = (np.arange(w) + 0.5) * (W / w) - 0.5
    ys = (np.arange(h) + 0.5) * (H / h) - 0.5
    gx, gy = np.meshgrid(xs, ys)
    return np.stack([gx, gy], axis=-1)


def apply_homography_grid(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``(..., 2) -> (..., 2) float64``: ``H`` applied to points (NaN where the point goes to infinity)."""
    p = np.asarray(points, np.float64)
    H = np.asarray(H, np.float64)
    x = H[0, 0] * p[..., 0] + H[0, 1] * p[..., 1] + H[0, 2]
    y = H[1, 0] * p[..., 0] + H[1, 1] * p[..., 1] + H[1, 2]
    z = H[2, 0] * p[..., 0] + H[2, 1] * p[..., 1] + H[2, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.stack([x / z, y / z], axis=-1)
    out[~(z > 1e-12)] = np.nan
    return out


def projector_mapper(mapping: np.ndarray, camera_size: tuple[int, int]):
    """A function from camera pixels ``(..., 2)`` to projector pixels ``(..., 2) float64`` (NaN where none).

    ``mapping``: a ``(3, 3)`` homography (full-camera pixels -> projector pixels), or an ``(h, w, 2)`` map of
    projector coordinates on a grid over the camera image (grid convention of this module), interpolated
    bilinearly (NaN next to a point without coordinates)."""
    m = np.asarray(mapping)
    if m.shape == (3, 3):
        return lambda p: apply_homography_grid(m, p)
    if m.ndim != 3 or m.shape[2] != 2:
        raise ValueError(f"a camera -> projector mapping is a (3, 3) homography or an (h, w, 2) map, got {m.shape}")
    W, H = (int(v) for v in camera_size)
    h, w = m.shape[:2]
    table = np.ascontiguousarray(m, np.float32)

    def f(points: np.ndarray) -> np.ndarray:
        import cv2  # lazy: a coordinator's start loads this module; OpenCV only when a blend is computed or sampled

        p = np.asarray(points, np.float64)
        n = int(np.prod(p.shape[:-1]))
        rows = max(1, -(-n // 1024))     # remap takes maps of at most 32767 a side: lay the points out 1024 wide
        gx = np.full(rows * 1024, -10.0, np.float32)
        gy = np.full(rows * 1024, -10.0, np.float32)
        gx[:n] = ((p[..., 0] + 0.5) * (w / W) - 0.5).reshape(-1)
        gy[:n] = ((p[..., 1] + 0.5) * (h / H) - 0.5).reshape(-1)
        out = cv2.remap(table, gx.reshape(rows, 1024), gy.reshape(rows, 1024), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_CONSTANT, borderValue=(np.nan, np.nan))
        return out.reshape(-1, 2)[:n].reshape(*p.shape[:-1], 2).astype(np.float64)

    return f


@dataclass(frozen=True, eq=False)
class Contributions:
    """Per-projector light on a camera grid (see the module docstring).

    Attributes
    ----------
    camera_size : (W, H)
        The full camera image the grid reduces.
    scale : int
        Grid = camera / scale (rounded up).
    white : dict slot -> (h, w, 3) float32
        Light above black at full linear white, camera units; 0 outside the projector's footprint.
    black : dict slot -> (h, w, 3) float32
        The projector's share of the black level.
    camera_to_projector : dict slot -> (3, 3) float64
        Full-camera pixels -> projector pixels (a planar rig's homography; unused for a slot of ``projector_xy``).
    projector_size : dict slot -> (W, H)
    projector_xy : dict slot -> (h, w, 2) float32, optional
        A mesh rig's projector coordinates of every grid point (NaN where the projector does not reach it).
    """

    camera_size: tuple[int, int]
    scale: int
    white: Mapping[str, np.ndarray]
    black: Mapping[str, np.ndarray]
    camera_to_projector: Mapping[str, np.ndarray]
    projector_size: Mapping[str, tuple[int, int]]
    projector_xy: Mapping[str, np.ndarray] | None = None
    _coords: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        W, H = (int(v) for v in self.camera_size)
        if W < 1 or H < 1 or int(self.scale) < 1:
            raise ValueError(f"camera size {W}x{H} and scale {self.scale} must be positive")
        object.__setattr__(self, "camera_size", (W, H))
        object.__setattr__(self, "scale", int(self.scale))
        shape = grid_shape((W, H), self.scale)
        slots = list(self.white)
        if set(slots) != set(self.black) or set(slots) != set(self.camera_to_projector) \
                or set(slots) != set(self.projector_size):
            raise ValueError("white, black, camera_to_projector and projector_size must name the same slots")
        white, black, c2p, sizes = {}, {}, {}, {}
        for s in slots:
            for name, src, dst in (("white", self.white, white), ("black", self.black, black)):
                a = np.ascontiguousarray(np.asarray(src[s], np.float32))
                if a.shape != (*shape, 3):
                    raise ValueError(f"{name}[{s}] must be {(*shape, 3)} (the camera grid), got {a.shape}")
                if not np.all(np.isfinite(a)) or float(a.min(initial=0.0)) < 0.0:
                    raise ValueError(f"{name}[{s}] must be finite and non-negative")
                a.setflags(write=False)
                dst[s] = a
            m = np.asarray(self.camera_to_projector[s], np.float64)
            if m.shape != (3, 3) or not np.all(np.isfinite(m)):
                raise ValueError(f"camera_to_projector[{s}] must be a finite (3, 3) matrix, got shape {m.shape}")
            c2p[s] = m
            pw, ph = (int(v) for v in self.projector_size[s])
            if pw < 1 or ph < 1:
                raise ValueError(f"projector_size[{s}] must be positive, got {pw}x{ph}")
            sizes[s] = (pw, ph)
        object.__setattr__(self, "white", white)
        object.__setattr__(self, "black", black)
        object.__setattr__(self, "camera_to_projector", c2p)
        object.__setattr__(self, "projector_size", sizes)
        if self.projector_xy is not None:
            xy = {}
            for s, a in self.projector_xy.items():
                if s not in white:
                    raise ValueError(f"projector_xy names {s}, which has no contribution")
                a = np.ascontiguousarray(np.asarray(a, np.float32))
                if a.shape != (*shape, 2):
                    raise ValueError(f"projector_xy[{s}] must be {(*shape, 2)} (the camera grid), got {a.shape}")
                a.setflags(write=False)
                xy[s] = a
            object.__setattr__(self, "projector_xy", xy or None)

    # ------------------------------------------------------------------ the grid
    @property
    def slots(self) -> list[str]:
        return list(self.white)

    @property
    def shape(self) -> tuple[int, int]:
        """``(h, w)`` of the grid."""
        return grid_shape(self.camera_size, self.scale)

    def camera_points(self) -> np.ndarray:
        """``(h, w, 2) float64``: the camera pixel of every grid point."""
        return grid_to_camera(self.camera_size, self.shape)

    def projector_coords(self, slot: str) -> np.ndarray:
        """``(h, w, 2) float64``: ``slot``'s projector pixel of every grid point (NaN where none)."""
        hit = self._coords.get(slot)
        if hit is None:
            if self.projector_xy is not None and slot in self.projector_xy:
                hit = self.projector_xy[slot].astype(np.float64)
            else:
                hit = apply_homography_grid(self.camera_to_projector[slot], self.camera_points())
            self._coords[slot] = hit
        return hit

    def mapping(self, slot: str) -> np.ndarray:
        """What places ``slot``'s pixels: its (h, w, 2) projector coordinates on a mesh rig, else its homography."""
        if self.projector_xy is not None and slot in self.projector_xy:
            return self.projector_xy[slot]
        return self.camera_to_projector[slot]

    def footprint(self, slot: str) -> np.ndarray:
        """``(h, w) bool``: where ``slot`` adds light (computed once; do not modify it)."""
        key = ("footprint", slot)
        hit = self._coords.get(key)
        if hit is None:
            hit = self._coords[key] = np.any(self.white[slot] > 0, axis=-1)
            hit.setflags(write=False)
        return hit

    # ------------------------------------------------------------------ variants
    def without(self, slots: Iterable[str]) -> "Contributions":
        """The same rig without ``slots`` (a lost node, a dead lamp)."""
        drop = set(slots)
        keep = [s for s in self.slots if s not in drop]
        xy = None if self.projector_xy is None else {s: a for s, a in self.projector_xy.items() if s in keep}
        return Contributions(self.camera_size, self.scale, {s: self.white[s] for s in keep},
                             {s: self.black[s] for s in keep}, {s: self.camera_to_projector[s] for s in keep},
                             {s: self.projector_size[s] for s in keep}, xy or None)

    def with_gains(self, gains: Mapping[str, float]) -> "Contributions":
        """Each named slot's light (white and black alike: both come from its lamp) scaled by its gain."""
        for s, g in gains.items():
            if s not in self.white:
                raise BlendError(f"lamp gain for {s}: no such projector in the measured contributions")
            if not (math.isfinite(float(g)) and float(g) >= 0.0):
                raise BlendError(f"lamp gain for {s} must be a finite number >= 0, got {g!r}")
        white = {s: self.white[s] * np.float32(gains.get(s, 1.0)) for s in self.slots}
        black = {s: self.black[s] * np.float32(gains.get(s, 1.0)) for s in self.slots}
        return Contributions(self.camera_size, self.scale, white, black, dict(self.camera_to_projector),
                             dict(self.projector_size), self.projector_xy)

    # ------------------------------------------------------------------ storage
    def to_arrays(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Arrays (``white.SLOT``, ``black.SLOT``, ``camera_to_projector.SLOT``) and a JSON-able meta."""
        arrays: dict[str, np.ndarray] = {}
        for s in self.slots:
            arrays[f"white.{s}"] = np.asarray(self.white[s])
            arrays[f"black.{s}"] = np.asarray(self.black[s])
            arrays[f"camera_to_projector.{s}"] = np.asarray(self.camera_to_projector[s])
            if self.projector_xy is not None and s in self.projector_xy:
                arrays[f"projector_xy.{s}"] = np.asarray(self.projector_xy[s])
        meta = {"camera_size": list(self.camera_size), "scale": self.scale, "slots": self.slots,
                "projector_size": {s: list(self.projector_size[s]) for s in self.slots},
                "mesh": self.projector_xy is not None}
        return arrays, meta

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> "Contributions":
        """The inverse of :meth:`to_arrays`; :class:`BlendError` (one line) when something is missing or wrong."""
        try:
            slots = [str(s) for s in meta["slots"]]
            camera_size = tuple(int(v) for v in meta["camera_size"])
            scale = int(meta["scale"])
            sizes = {s: tuple(int(v) for v in meta["projector_size"][s]) for s in slots}
            white = {s: arrays[f"white.{s}"] for s in slots}
            black = {s: arrays[f"black.{s}"] for s in slots}
            c2p = {s: arrays[f"camera_to_projector.{s}"] for s in slots}
            xy = {s: arrays[f"projector_xy.{s}"] for s in slots if f"projector_xy.{s}" in arrays}
            if meta.get("mesh") and len(xy) != len(slots):
                raise KeyError("projector_xy of every slot of a mesh rig")
        except (KeyError, TypeError, ValueError) as exc:
            raise BlendError(f"stored contributions are incomplete ({type(exc).__name__}: {exc}); "
                             "run `shadowless blend` again") from exc
        try:
            return cls(camera_size, scale, white, black, c2p, sizes, xy or None)  # type: ignore[arg-type]
        except ValueError as exc:
            raise BlendError(f"stored contributions are inconsistent: {exc}; run `shadowless blend` again") from exc
