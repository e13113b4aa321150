"""The hand with forearm that shadows the table, and a hand moving along keyframes.

A :class:`Hand` is a union of the analytic solids of :mod:`sim.occluders` (an
ellipsoid palm, capsule fingers and thumb, a capsule forearm), placed on the
table by a reference point, a height and a yaw; like every occluder it answers
``primitives()``. :class:`HandPath` moves a hand along keyframes for dynamic
tests and studies.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sim.geometry import rotation_about
from sim.occluders import Capsule, Ellipsoid, Primitive


@dataclass(frozen=True, eq=False)
class Hand:
    """A right or left hand with forearm, built from analytic primitives.

    Parameters
    ----------
    position : (float, float)
        Table (x, y) mm of the reference point: the palm centre for
        ``pose="flat"``, the index fingertip for ``pose="point"``.
    height : float
        Height (mm) of the hand's lowest point above the table: 200 for the
        paper's hand 0.2 m above the surface, 0 touches the table.
    yaw_deg : float
        Direction the fingers point, counter-clockwise from world +y (0: the
        person stands at the -y edge of the table and reaches across it).
    pose : "flat" or "point"
        Flat: palm parallel to the table, fingers extended. Point: index finger
        extended and tilted down 35 degrees, the other fingers curled.
    scale : float
        1.0 is an adult hand (palm 84 mm wide, middle fingertip 160 mm from the
        wrist) with a forearm 260 mm long and 60 mm thick.
    side : "right" or "left"
        Which side the thumb is on (palm down, right hand: thumb towards -x).
    """

    position: tuple[float, float] = (0.0, 0.0)
    height: float = 200.0
    yaw_deg: float = 0.0
    pose: str = "flat"
    scale: float = 1.0
    side: str = "right"
    _parts: tuple[Primitive, ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.pose not in ("flat", "point"):
            raise ValueError(f"pose must be 'flat' or 'point', got {self.pose!r}")
        if self.side not in ("right", "left"):
            raise ValueError(f"side must be 'right' or 'left', got {self.side!r}")
        if self.scale <= 0 or self.height < 0:
            raise ValueError("scale must be positive and height >= 0")
        object.__setattr__(self, "position", (float(self.position[0]), float(self.position[1])))
        object.__setattr__(self, "_parts", self._build())

    def _build(self) -> tuple[Primitive, ...]:
        s = self.scale
        thumb_x = -1.0 if self.side == "right" else 1.0
        # Local frame: palm centre at the origin, fingers along +y, back of the hand towards +z.
        parts: list[Primitive] = [Ellipsoid((0, 0, 0), (42 * s, 48 * s, 14 * s))]
        fingers = [(-24, 70, 8.5, "index"), (-8, 78, 8.5, "middle"), (8, 72, 8.0, "ring"), (23, 56, 7.0, "little")]
        tip = None
        for x, length, r, name in fingers:
            # Right hand palm down: the index is on the thumb side (-x); mirrored for the left hand.
            xs = -thumb_x * x * s
            base = np.array([xs, 38 * s, -14 * s + r * s])
            if self.pose == "point" and name != "index":
                end = base + np.array([0.0, 12 * s, -24 * s])  # curled under the palm
            else:
                end = base + np.array([0.0, length * s, 0.0])
            parts.append(Capsule(base, end, r * s))
            if name == "index":
                tip = (end, r * s)
        parts.append(Capsule((thumb_x * 30 * s, -5 * s, -2 * s), (thumb_x * 62 * s, 32 * s, -2 * s), 10 * s))
        wrist = np.array([0.0, -45 * s, 16 * s])
        rise = math.radians(25.0)
        elbow = wrist + 260 * s * np.array([0.0, -math.cos(rise), math.sin(rise)])
        parts.append(Capsule(wrist, elbow, 30 * s))
        pitch = math.radians(35.0) if self.pose == "point" else 0.0
        R = rotation_about((0, 0, 1), math.radians(self.yaw_deg)) @ rotation_about((1, 0, 0), -pitch)
        parts = [p.moved(R, np.zeros(3)) for p in parts]
        if self.pose == "point":
            assert tip is not None
            ref_xy = (R @ tip[0])[:2]
        else:
            ref_xy = np.zeros(2)
        low = min(p.lowest_z() for p in parts)
        shift = np.array([self.position[0] - ref_xy[0], self.position[1] - ref_xy[1], self.height - low])
        return tuple(p.moved(np.eye(3), shift) for p in parts)

    def primitives(self) -> tuple[Primitive, ...]:
        return self._parts

    def lowest_z(self) -> float:
        return min(p.lowest_z() for p in self._parts)


@dataclass(frozen=True)
class HandPath:
    """A hand moving through keyframes ``(time s, x mm, y mm, height mm)``, linearly.

    With ``loop`` the path repeats (for a back-and-forth sweep, list the
    return keyframes too). Other hand parameters come from ``template``.
    """

    keyframes: tuple[tuple[float, float, float, float], ...]
    loop: bool = True
    template: Hand = field(default_factory=Hand)

    def __post_init__(self) -> None:
        kf = tuple(tuple(float(v) for v in k) for k in self.keyframes)
        if len(kf) < 1 or any(len(k) != 4 for k in kf):
            raise ValueError("keyframes must be (time, x, y, height) tuples")
        if any(b[0] <= a[0] for a, b in zip(kf, kf[1:])):
            raise ValueError("keyframe times must increase")
        object.__setattr__(self, "keyframes", kf)

    @classmethod
    def sweep(cls, start, end, *, height: float = 200.0, period: float = 4.0, template: Hand | None = None) -> "HandPath":
        """Back and forth between table points ``start`` and ``end`` once per ``period`` seconds."""
        if period <= 0:
            raise ValueError("period must be positive")
        kf = ((0.0, start[0], start[1], height), (period / 2, end[0], end[1], height), (period, start[0], start[1], height))
        return cls(kf, loop=True, template=template or Hand(height=height))

    @property
    def duration(self) -> float:
        return self.keyframes[-1][0] - self.keyframes[0][0]

    def hand_at(self, t: float) -> Hand:
        """The hand at time ``t`` seconds."""
        kf = np.asarray(self.keyframes)
        t0 = kf[0, 0]
        if self.loop and self.duration > 0:
            t = t0 + (t - t0) % self.duration
        x, y, h = (float(np.interp(t, kf[:, 0], kf[:, k])) for k in (1, 2, 3))
        tpl = self.template
        return Hand(position=(x, y), height=h, yaw_deg=tpl.yaw_deg, pose=tpl.pose, scale=tpl.scale, side=tpl.side)
