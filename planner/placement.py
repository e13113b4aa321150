"""Where to put the object on the table: a coarse-to-fine search over its position and yaw.

The projectors stay where the layout hangs them; the object moves by ``x -> Rz(yaw) x + (x0, y0, 0)``
(a layout's ``[mesh] position`` and ``yaw_deg``, :class:`protos.layout.MeshSpec`). No tilt: the
object stands on its base. Each placement is judged by a ``score`` callable (the wiring,
:mod:`shadowless.placement`, counts coverage as `shadowless coverage` does); this module holds
what does not depend on how coverage is counted:

* :class:`Placement` and the transforms between the object's frame and the room's;
* :func:`fits`: the object's footprint stays on the table;
* :func:`search`: a coarse grid over the table and the yaws, then finer steps around the best
  few, until the steps are small or the time budget is spent;
* :func:`hand_shadow`: the predicted hand shadow of a placement, a stated proxy (below);
* :func:`reference_layout` and :func:`placed_layout_text`: the default room and the placement
  written as a layout any other tool reads.

The hand-shadow proxy: pointing hands around the object (:func:`planner.surface.bust_poses`,
fingertips 210 mm from its axis at 250 and 420 mm, from six directions, turned and moved with
the object) block projectors' rays (exact ray tests against the hand's primitives); the light
drop at a point is the blocked share of its irradiance (the room's definition). The proxy is the
share of the surface's area where the drop exceeds one half, averaged over the hands.
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from planner.surface import bust_poses
from protos.wording import count
from sim.rigs import layout_toml
from sim.scene import reference_scene

__all__ = ["Placement", "Score", "area_quantile", "fits", "search", "hand_shadow", "reference_layout", "placed_layout_text", "DROP_LIMIT"]

#: the drop above which a point counts as shadowed by a hand
DROP_LIMIT = 0.5


@dataclass(frozen=True)
class Placement:
    """The object at (x, y) mm on the table, turned ``yaw_deg`` counter-clockwise about +z."""

    x: float = 0.0
    y: float = 0.0
    yaw_deg: float = 0.0

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) float64 Rz(yaw)."""
        c, s = math.cos(math.radians(self.yaw_deg)), math.sin(math.radians(self.yaw_deg))
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    @property
    def offset(self) -> np.ndarray:
        return np.array([self.x, self.y, 0.0])

    def to_room(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) float64 room mm of points (n, 3) in the object's frame."""
        return np.asarray(points, np.float64) @ self.rotation.T + self.offset

    def normals_to_room(self, normals: np.ndarray) -> np.ndarray:
        return np.asarray(normals, np.float64) @ self.rotation.T

    def device_in_object_frame(self, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A device ``x ~ K (R X + t)`` (room frame) as ``(R', t')`` in the object's frame: the same
        image of the object, since ``R X + t = R (Rz x + p) + t = (R Rz) x + (R p + t)``."""
        R = np.asarray(R, np.float64)
        return R @ self.rotation, R @ self.offset + np.asarray(t, np.float64)

    def as_dict(self) -> dict:
        return {"x_mm": round(self.x, 1), "y_mm": round(self.y, 1), "yaw_deg": round(self.yaw_deg % 360.0, 1)}

    def __str__(self) -> str:
        return f"x {self.x:.0f} mm, y {self.y:.0f} mm, yaw {self.yaw_deg % 360.0:.0f} deg"


@dataclass(frozen=True)
class Score:
    """What one placement scores (higher ``key`` is better).

    count_min : fewest projectors reaching a lit point (the coverage tool's ``count_min``)
    unlit_pct : % of the surface no projector reaches
    shadow_pct : the hand-shadow proxy, % of the surface (module docstring)
    count_mean : projectors per point, mean by area over the lit surface
    count_p5 : the count that 5 % of the lit surface (by area) falls below or at (the tool's ``count_p5``)
    """

    count_min: int
    unlit_pct: float
    shadow_pct: float
    count_mean: float
    count_p5: int = 0

    @property
    def key(self) -> tuple[float, ...]:
        """Most projectors at the worst point first, then at the worst 5 % of the surface, then the
        least surface left unlit or in a hand's deep shadow (in % of the surface, to 0.5 %: finer
        differences are the sampling's), then the most projectors on average."""
        return (self.count_min, self.count_p5, -round(2.0 * (self.unlit_pct + self.shadow_pct)) / 2.0, round(self.count_mean, 3))

    def as_dict(self) -> dict:
        return {"count_min": self.count_min, "count_p5": self.count_p5, "unlit_pct": round(self.unlit_pct, 2),
                "hand_shadow_pct": round(self.shadow_pct, 2), "count_mean": round(self.count_mean, 3)}


def area_quantile(count: np.ndarray, area: np.ndarray, q: float) -> int:
    """The count (n,) int below or at which a share ``q`` of the area (n,) lies, as
    :meth:`coordinator.coverage.Coverage.summary` computes ``count_p5`` (q = 0.05); 0 when empty."""
    if not len(count):
        return 0
    order = np.argsort(count, kind="stable")
    cum = np.cumsum(np.asarray(area, np.float64)[order])
    return int(np.asarray(count)[order][min(len(cum) - 1, int(np.searchsorted(cum, q * cum[-1])))])


def fits(footprint: np.ndarray, placement: Placement, table_size: tuple[float, float], *, margin: float = 20.0) -> bool:
    """Whether the object's footprint ((k, 2) or (k, 3) points of its frame; x, y used) stays
    ``margin`` mm inside the table (``table_size`` (w, h) mm centred on the origin)."""
    xy = placement.to_room(np.column_stack([np.asarray(footprint)[:, :2], np.zeros(len(footprint))]))[:, :2]
    half = np.asarray(table_size, np.float64) / 2 - margin
    return bool(np.all(np.abs(xy) <= half + 1e-9))


def _axis(lo: float, hi: float, step: float) -> np.ndarray:
    if hi <= lo:
        return np.array([(lo + hi) / 2])
    n = max(1, int(math.floor((hi - lo) / step + 1e-9)))
    return (lo + hi) / 2 + (np.arange(n + 1) - n / 2) * ((hi - lo) / n)


@dataclass
class SearchResult:
    best: Placement
    score: Score
    evaluated: list[tuple[Placement, Score]]
    seconds: float
    stopped_early: bool


def search(score: Callable[[Placement], Score], footprint: np.ndarray, table_size: tuple[float, float], *,
           step_mm: float = 200.0, yaws: int = 6, keep: int = 3, rounds: int = 3, seconds: float = 60.0,
           include: Sequence[Placement] = (Placement(),), progress: Callable[[str], None] = lambda text: None) -> SearchResult:
    """Maximise ``score(placement).key`` over placements whose footprint stays on the table.

    Coarse: a grid ``step_mm`` apart over the positions that fit at any yaw, times ``yaws`` yaws
    evenly over the turn, judged from the table's centre outwards, after ``include`` (the default placement, so the result is never worse
    than it). Then ``rounds`` times: around each of the ``keep`` best so far, one move at a time:
    half the previous step along x and along y (both ways) and half the previous yaw step (both ways). Stops early when
    ``seconds`` have passed (the best so far is the answer; ``stopped_early`` says so).
    """
    t0 = time.perf_counter()
    seen: dict[tuple[float, float, float], Score] = {}
    order: list[Placement] = []
    late = False

    def judge(batch: list[Placement], label: str) -> None:
        nonlocal late
        todo = []
        for p in batch:
            k = (round(p.x, 1), round(p.y, 1), round(p.yaw_deg % 360.0, 1))
            if k not in seen and fits(footprint, p, table_size) and k not in {(round(q.x, 1), round(q.y, 1), round(q.yaw_deg % 360.0, 1)) for q in todo}:
                todo.append(p)
        for i, p in enumerate(todo):
            if time.perf_counter() - t0 > seconds and seen:
                late = True
                return
            s = score(p)
            seen[(round(p.x, 1), round(p.y, 1), round(p.yaw_deg % 360.0, 1))] = s
            order.append(p)
            if (i + 1) % 10 == 0 or i + 1 == len(todo):
                best = max(order, key=lambda q: _key(seen, q))
                progress(f"{label}: {i + 1}/{len(todo)} placements, best so far {best} "
                         f"(at least {count(_score(seen, best).count_min, 'projector')} on every lit point), {time.perf_counter() - t0:.0f} s")

    reach = float(np.max(np.linalg.norm(np.asarray(footprint)[:, :2], axis=1)))
    half = np.asarray(table_size, np.float64) / 2 - 20.0
    xs, ys = _axis(-half[0] + reach, half[0] - reach, step_mm), _axis(-half[1] + reach, half[1] - reach, step_mm)
    if len(xs) == 1 and len(ys) == 1:  # the object fits only when turned: search the whole table
        xs, ys = _axis(-half[0], half[0], step_mm), _axis(-half[1], half[1], step_mm)
    yaw_step = 360.0 / max(1, yaws)
    grid = [Placement(float(x), float(y), float(k * yaw_step)) for x in xs for y in ys for k in range(yaws)]
    # nearest the table's centre first: a budget that runs out has judged the middle of the table
    coarse = list(include) + sorted(grid, key=lambda p: (round(math.hypot(p.x, p.y), 1), p.yaw_deg))
    judge(coarse, "coarse")
    step = step_mm
    for r in range(rounds):
        if late:
            break
        step, yaw_step = step / 2, yaw_step / 2
        best = sorted(order, key=lambda q: _key(seen, q), reverse=True)[:keep]
        fine = [Placement(b.x + dx * step, b.y + dy * step, b.yaw_deg + dyaw)
                for b in best for dx, dy, dyaw in ((-1, 0, 0.0), (1, 0, 0.0), (0, -1, 0.0), (0, 1, 0.0), (0, 0, -yaw_step), (0, 0, yaw_step))]
        judge(fine, f"fine {r + 1}/{rounds} ({step:.0f} mm, {yaw_step:.0f} deg)")
    best = max(order, key=lambda q: _key(seen, q))
    return SearchResult(best, _score(seen, best), [(p, _score(seen, p)) for p in order], time.perf_counter() - t0, late)


def _score(seen: dict, p: Placement) -> Score:
    return seen[(round(p.x, 1), round(p.y, 1), round(p.yaw_deg % 360.0, 1))]


def _key(seen: dict, p: Placement):
    # ties: the placement nearer the table's centre, then the smaller turn
    return (*_score(seen, p).key, -round(math.hypot(p.x, p.y), 1), -round(min(p.yaw_deg % 360.0, 360.0 - p.yaw_deg % 360.0), 1))


def hand_shadow(points: np.ndarray, area: np.ndarray, irradiance: np.ndarray, centers: np.ndarray, placement: Placement) -> float:
    """The hand-shadow proxy (module docstring), % of the area.

    Parameters
    ----------
    points : (n, 3) float64 room mm of surface samples (the object as placed)
    area : (n,) float64 mm^2 each sample stands for
    irradiance : (S, n) float64 each projector's light at each sample, 0 where it does not reach
    centers : (S, 3) float64 the projectors' centres, room mm
    """
    X = np.asarray(points, np.float64)
    E = np.asarray(irradiance, np.float64)
    total = E.sum(axis=0)
    a = np.asarray(area, np.float64)
    if a.sum() <= 0:
        return 0.0
    hands = []
    for h in bust_poses():
        # bust_poses stands the object at the origin facing +y: turn and move the hands with it
        p = placement.to_room(np.array([[h.position[0], h.position[1], 0.0]]))[0]
        hands.append(type(h)(position=(p[0], p[1]), height=h.height, yaw_deg=h.yaw_deg + placement.yaw_deg, pose=h.pose))
    shares = []
    for hand in hands:
        prims = hand.primitives()
        blocked_light = np.zeros(len(X))
        spheres = [prim.bounding_sphere() for prim in prims]
        for i, c in enumerate(np.asarray(centers, np.float64)):
            v = X - c
            dist = np.linalg.norm(v, axis=1)
            d = v / dist[:, None]
            # only rays passing near one of the primitives are tested against it (exact below)
            near = np.zeros((len(prims), len(X)), bool)
            for k, (sc, sr) in enumerate(spheres):
                along = d @ (sc - c)
                closest = np.clip(along, 0.0, dist)
                gap2 = np.sum((c + d * closest[:, None] - sc) ** 2, axis=1)
                near[k] = (gap2 <= sr * sr) & (E[i] > 0)
            if not near.any():
                continue
            blocked = np.zeros(len(X), bool)
            for k, prim in enumerate(prims):
                idx = np.flatnonzero(near[k] & ~blocked)
                if not len(idx):
                    continue
                t_in, t_out = prim.interval_from(c, d[idx, 0], d[idx, 1], d[idx, 2])
                blocked[idx] |= (t_in < dist[idx] - 1e-6) & (t_out > 1e-6)
            blocked_light[blocked] += E[i, blocked]
        with np.errstate(divide="ignore", invalid="ignore"):
            drop = np.where(total > 0, blocked_light / np.where(total > 0, total, 1.0), 0.0)
        shares.append(float(a[drop > DROP_LIMIT].sum() / a.sum()))
    return 100.0 * float(np.mean(shares))


def reference_layout() -> dict:
    """The paper's 5 x 5 ceiling rig (:func:`sim.scene.reference_scene`, without the units' mounting
    jitter and without the unpowered ``p1``) with the room's bust at the table's centre, as a layout
    document (:func:`sim.rigs.layout_toml` writes it)."""
    scene = reference_scene(surface="bust", jitter=False)
    projectors = []
    for p in scene.projectors:
        if not p.powered:
            continue
        n = p.native
        projectors.append({"slot": p.slot, "position": [round(float(v), 3) for v in n.center],
                           "target": [round(float(v), 3) for v in n.center + n.axis * p.focus],
                           "up": [round(float(v), 6) for v in -n.R[1]], "resolution": list(n.size),
                           "focal_px": round(float(n.K[0, 0]), 4)})
    cam = scene.cameras[0].native
    dist = -cam.center[2] / cam.axis[2]
    return {"name": "reference-5x5-bust", "table": {"size": [1200.0, 600.0]}, "mesh": {"builtin": "bust"},
            "projector": projectors,
            "camera": [{"name": "ceiling", "position": [round(float(v), 3) for v in cam.center],
                        "target": [round(float(v), 3) for v in cam.center + dist * cam.axis],
                        "up": [round(float(v), 6) for v in -cam.R[1]], "resolution": list(cam.size),
                        "focal_px": round(float(cam.K[0, 0]), 4)}]}


def placed_layout_text(doc: dict, placement: Placement, *, header: str = "") -> str:
    """The layout ``doc`` (as :mod:`tomllib` reads it) with its object at ``placement``: ``[mesh]``
    gets ``position`` and ``yaw_deg`` (a placement within the object's own frame, which ``doc`` may
    already move, is not composed: ``doc``'s own position and yaw are replaced)."""
    out = dict(doc)
    mesh = dict(out.get("mesh") or {"builtin": "bust"})
    mesh["position"] = [round(placement.x, 3), round(placement.y, 3), 0.0]
    mesh["yaw_deg"] = round(placement.yaw_deg % 360.0, 3)
    out["mesh"] = mesh
    return layout_toml(out, header=header)
