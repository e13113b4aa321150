"""Candidate mounting positions and the projector model that turns one into a light source.

A candidate is a position (world mm) from which a projector is aimed at the
surface's centre. Its focal length is either given (a throw ratio: focal /
image width) or fitted, per candidate, so the whole surface (its bounding
corners, with a margin) fits in the image, as the reference rig's projectors
are (:func:`sim.scene.reference_scene`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim.geometry import Pinhole, intrinsics, look_at
from sim.sop_shadows import Source


@dataclass(frozen=True)
class Candidate:
    """A mounting position: a name and where (world mm)."""

    name: str
    position: tuple[float, float, float]


@dataclass(frozen=True)
class ProjectorModel:
    """Native resolution and throw ratio (focal / width; None: fitted per candidate to the surface)."""

    resolution: tuple[int, int] = (1280, 800)
    throw_ratio: float | None = None
    margin: float = 0.04

    def __post_init__(self) -> None:
        if self.resolution[0] <= 0 or self.resolution[1] <= 0:
            raise ValueError(f"resolution must be positive, got {self.resolution}")
        if self.throw_ratio is not None and self.throw_ratio <= 0:
            raise ValueError(f"throw ratio must be positive, got {self.throw_ratio}")


def up_for(direction: np.ndarray) -> np.ndarray:
    """The world direction towards the image top: +y for a projector looking down or up, +z for one looking sideways."""
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    return np.array([0.0, 1.0, 0.0]) if abs(d[2]) > 0.7 else np.array([0.0, 0.0, 1.0])


def source_for(candidate: Candidate, target: np.ndarray, corners: np.ndarray, model: ProjectorModel) -> Source:
    """The projector at ``candidate`` aimed at ``target``.

    Parameters
    ----------
    target : (3,) float64
    corners : (m, 3) float64
        Points that must fit in the image when the focal length is fitted.
    """
    pos = np.asarray(candidate.position, np.float64)
    tgt = np.asarray(target, np.float64)
    up = up_for(tgt - pos)
    R, t = look_at(pos, tgt, up=up)
    w, h = model.resolution
    if model.throw_ratio is not None:
        focal = model.throw_ratio * w
    else:
        Xc = np.asarray(corners, np.float64) @ R.T + t
        if np.any(Xc[:, 2] <= 1e-6):
            raise ValueError(f"candidate {candidate.name} at {pos.tolist()} is inside or beside the surface's bounds")
        xn = np.abs(Xc[:, 0] / Xc[:, 2]).max()
        yn = np.abs(Xc[:, 1] / Xc[:, 2]).max()
        focal = min((w / 2) * (1 - model.margin) / max(xn, 1e-9), (h / 2) * (1 - model.margin) / max(yn, 1e-9))
    return Source(candidate.name, Pinhole(intrinsics((w, h), focal=focal), R, t, (w, h)))


def ceiling_grid(cols: int, rows: int, *, span: tuple[float, float] = (1000.0, 1000.0), height: float = 1400.0) -> list[Candidate]:
    """``cols x rows`` positions on the plane z = ``height``, spanning ``span`` (mm) centred over the origin.

    Named ``g{row}_{col}``; the reference rig is ``ceiling_grid(5, 5)``.
    """
    if cols < 1 or rows < 1:
        raise ValueError("need at least one column and one row")
    xs = np.linspace(-span[0] / 2, span[0] / 2, cols) if cols > 1 else np.zeros(1)
    ys = np.linspace(-span[1] / 2, span[1] / 2, rows) if rows > 1 else np.zeros(1)
    return [Candidate(f"g{r}_{c}", (float(x), float(y), float(height))) for r, y in enumerate(ys) for c, x in enumerate(xs)]


def walls(per_wall: int, *, half_size: tuple[float, float] = (1000.0, 800.0), heights: tuple[float, ...] = (700.0, 1100.0)) -> list[Candidate]:
    """Positions on four walls at x = +-half_size[0] and y = +-half_size[1], ``per_wall`` across each, at each height.

    Named ``w{side}{height index}_{i}`` with side one of n, s, e, w (+y, -y, +x, -x).
    """
    if per_wall < 1:
        raise ValueError("need at least one position per wall")
    hx, hy = half_size
    out = []
    for k, z in enumerate(heights):
        for i in range(per_wall):
            f = (i + 0.5) / per_wall - 0.5
            out += [
                Candidate(f"wn{k}_{i}", (2 * f * hx * 0.8, hy, z)),
                Candidate(f"ws{k}_{i}", (2 * f * hx * 0.8, -hy, z)),
                Candidate(f"we{k}_{i}", (hx, 2 * f * hy * 0.8, z)),
                Candidate(f"ww{k}_{i}", (-hx, 2 * f * hy * 0.8, z)),
            ]
    return out


def from_file(path: str | Path) -> list[Candidate]:
    """Candidates from a text file: one ``x,y,z[,name]`` per line (mm); blank lines and ``#`` comments skipped.

    Raises
    ------
    ValueError
        Naming the file and line that is wrong.
    """
    path = Path(path)
    out = []
    for no, line in enumerate(path.read_text().splitlines(), 1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        parts = [p.strip() for p in text.split(",")]
        try:
            xyz = tuple(float(v) for v in parts[:3])
        except ValueError:
            raise ValueError(f"{path}:{no}: expected x,y,z[,name] in mm, got {line!r}") from None
        if len(parts) < 3 or len(parts) > 4 or not all(math.isfinite(v) for v in xyz):
            raise ValueError(f"{path}:{no}: expected x,y,z[,name] in mm, got {line!r}")
        out.append(Candidate(parts[3] if len(parts) == 4 and parts[3] else f"c{len(out)}", xyz))
    if not out:
        raise ValueError(f"{path}: no candidate positions")
    names = [c.name for c in out]
    if len(set(names)) != len(names):
        raise ValueError(f"{path}: candidate names repeat")
    return out
