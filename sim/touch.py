"""A hand whose index fingertip touches a surface point anywhere in 3D (on the bust, not only the table).

:class:`sim.hand.Hand` stands on the table: a position, a height and a yaw. Touching a
point of a 3D object needs any orientation: :class:`TouchingHand` builds the same pointing hand
(``Hand(pose="point")``: palm, fingers, thumb, forearm) and moves it rigidly so that

* its index finger points along the inward surface normal ``-n`` (or along ``direction``, any
  direction into the surface),
* its fingertip (the end sphere of the index finger's capsule) touches the point from outside:
  the sphere's centre at ``point + (radius + gap) n``,
* the back of the hand and the forearm lean towards ``towards`` (its part across the finger;
  by default world up, or world -y where the finger itself is nearly vertical),
* with ``shoulder``, an upper arm (a capsule) joins the forearm's elbow to the shoulder.

A person who touches an object stands beside it and reaches in: :meth:`TouchingHand.reaching`
builds that pose from the shoulder alone (the finger along the reach, tilted into the surface
as far as a fingertip touch needs, the forearm leaning back towards the shoulder, the upper arm
up to it). :meth:`TouchingHand.reaching` is what the bust's touch study uses; the finger along the
normal is the pose of the table's tests.

It is an occluder like any other: :meth:`primitives` for the room (``room.set_occluders``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sim.hand import Hand
from sim.occluders import Capsule, Primitive

__all__ = ["TouchingHand", "inside", "reach_direction"]

#: A fingertip touch: the finger at least this far from the surface's tangent plane (degrees).
MIN_INTO_DEG = 35.0
#: The upper arm's radius at scale 1 (mm): an adult's arm is about 30 cm round.
UPPER_ARM_RADIUS = 45.0


def _unit(v, name: str) -> np.ndarray:
    a = np.asarray(v, np.float64).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be a finite 3-vector, got {v!r}")
    n = float(np.linalg.norm(a))
    if n < 1e-9:
        raise ValueError(f"{name} must not be zero")
    return a / n


def _perpendicular(v: np.ndarray, axis: np.ndarray) -> np.ndarray | None:
    p = v - (v @ axis) * axis
    n = float(np.linalg.norm(p))
    return p / n if n > 1e-6 else None


def reach_direction(point, normal, shoulder, *, min_into_deg: float = MIN_INTO_DEG) -> np.ndarray:
    """(3,) unit: where the index finger of a hand reaching from ``shoulder`` to ``point`` points.

    Along the reach (``point - shoulder``) where that enters the surface at least ``min_into_deg``
    from its tangent plane; otherwise the reach's part along the surface, tilted into it by exactly
    ``min_into_deg`` (a fingertip touch on a surface the reach skims, or one facing away from the
    shoulder). A reach straight along the normal keeps the normal.
    """
    p = np.asarray(point, np.float64).reshape(3)
    n = _unit(normal, "normal")
    r = _unit(p - np.asarray(shoulder, np.float64).reshape(3), "point - shoulder")
    a = np.radians(min_into_deg)
    if -float(r @ n) >= np.sin(a) - 1e-12:
        return r
    along = _perpendicular(r, n)
    if along is None:
        return -n
    return np.cos(a) * along - np.sin(a) * n


@dataclass(frozen=True, eq=False)
class TouchingHand:
    """A pointing hand whose index fingertip touches ``point`` (world mm) with the finger along ``-normal``.

    Parameters
    ----------
    point : (3,) world mm, on the surface
    normal : (3,) the surface's outward normal there (need not be unit length)
    direction : (3,), optional
        Where the index finger points (default ``-normal``); it must point into the surface, at
        least 30 degrees from the tangent plane.
    towards : (3,), optional
        Where the back of the hand and the forearm lean (its part along the finger is ignored).
    shoulder : (3,), optional
        World mm: adds an upper arm, a capsule of radius ``arm_radius`` from the forearm's elbow end
        to here (its length is whatever the pose leaves: the person leans in or stands back).
    arm_radius : float
        The upper arm's radius, mm at scale 1.
    gap : float
        Millimetres between the fingertip and the surface (0: touching exactly).
    scale, side : as :class:`~sim.hand.Hand`.
    """

    point: np.ndarray
    normal: np.ndarray
    direction: np.ndarray | None = None
    towards: np.ndarray | None = None
    shoulder: np.ndarray | None = None
    arm_radius: float = UPPER_ARM_RADIUS
    gap: float = 0.5
    scale: float = 1.0
    side: str = "right"
    _parts: tuple[Primitive, ...] = field(init=False, repr=False)
    _tip: tuple[np.ndarray, float] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        p = np.asarray(self.point, np.float64).reshape(-1)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ValueError(f"point must be a finite 3-vector, got {self.point!r}")
        n = _unit(self.normal, "normal")
        if self.gap < 0:
            raise ValueError("gap must be >= 0")
        g = -n if self.direction is None else _unit(self.direction, "direction")
        if float(g @ n) > -0.5:
            raise ValueError("the finger must point into the surface, at least 30 degrees from its tangent plane")
        object.__setattr__(self, "point", p)
        object.__setattr__(self, "normal", n)
        object.__setattr__(self, "direction", g)
        hand = Hand(position=(0.0, 0.0), height=500.0, pose="point", scale=self.scale, side=self.side)
        parts = hand.primitives()
        # The pointing hand's reference point is its index fingertip: the capsule ending at (0, 0) in x, y.
        finger = next(q for q in parts if isinstance(q, Capsule) and np.hypot(q.b[0], q.b[1]) < 1e-6)
        forearm = max((q for q in parts if isinstance(q, Capsule)), key=lambda q: q.radius)
        f = _unit(finger.b - finger.a, "finger")
        back = _perpendicular(_unit(forearm.b - forearm.a, "forearm"), f)
        E = np.column_stack([f, back, np.cross(f, back)])            # the hand's frame
        want = None if self.towards is None else _perpendicular(_unit(self.towards, "towards"), g)
        for default in ((0.0, 0.0, 1.0), (0.0, -1.0, 0.0), (1.0, 0.0, 0.0)):
            if want is not None:
                break
            want = _perpendicular(np.asarray(default), g) if abs(float(g @ default)) < 0.9 else None
        G = np.column_stack([g, want, np.cross(g, want)])            # where that frame goes
        Q = G @ E.T
        centre = p + (finger.radius + self.gap) * n
        T = centre - Q @ finger.b
        moved = [q.moved(Q, T) for q in parts]
        if self.shoulder is not None:
            s = np.asarray(self.shoulder, np.float64).reshape(-1)
            if s.shape != (3,) or not np.all(np.isfinite(s)):
                raise ValueError(f"shoulder must be a finite 3-vector, got {self.shoulder!r}")
            if self.arm_radius <= 0:
                raise ValueError("arm_radius must be positive")
            elbow = Q @ forearm.b + T
            moved.append(Capsule(elbow, s, self.arm_radius * self.scale))
            object.__setattr__(self, "shoulder", s)
        object.__setattr__(self, "_parts", tuple(moved))
        object.__setattr__(self, "_tip", (centre, float(finger.radius)))

    @classmethod
    def reaching(cls, point, normal, shoulder, *, min_into_deg: float = MIN_INTO_DEG, **kwargs) -> TouchingHand:
        """The hand of a person whose shoulder is at ``shoulder`` touching ``point``: the finger along
        :func:`reach_direction`, the back of the hand up (a pointing hand, palm down; towards the
        shoulder where the finger is nearly vertical), the upper arm from the elbow to the shoulder."""
        g = reach_direction(point, normal, shoulder, min_into_deg=min_into_deg)
        up = np.array([0.0, 0.0, 1.0])
        back = up if abs(float(g @ up)) < 0.9 else np.asarray(shoulder, np.float64).reshape(3) - np.asarray(point, np.float64).reshape(3)
        return cls(point, normal, direction=g, towards=back, shoulder=shoulder, **kwargs)

    @property
    def fingertip(self) -> tuple[np.ndarray, float]:
        """(centre (3,) world mm, radius mm) of the index fingertip's sphere."""
        return self._tip[0].copy(), self._tip[1]

    def primitives(self) -> tuple[Primitive, ...]:
        return self._parts

    def lowest_z(self) -> float:
        return min(q.lowest_z() for q in self._parts)


def inside(occluder, points: np.ndarray) -> np.ndarray:
    """(n,) bool: which points (n, 3) world mm lie inside any primitive of ``occluder``
    (e.g. mesh vertices a misplaced hand would cut through)."""
    X = np.asarray(points, np.float64).reshape(-1, 3)
    d = np.broadcast_to(np.array([0.0, 0.0, 1.0]), X.shape)
    out = np.zeros(len(X), bool)
    for q in occluder.primitives():
        t_in, t_out, _ = q.interval(X, d)
        out |= (t_in <= 0) & (t_out >= 0)
    return out
