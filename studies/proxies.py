"""Sense-of-projection (SoP) proxies: geometric figures of a hand's shadow, per projector layout.

The paper's second study ranked layouts by how much their image under a hand
still reads as a pattern of the surface rather than a projection: P1 (one
projector) clearly worst; P9D (dense 3 x 3 cluster) preferred to P9W (the same
nine spread wide); P17, P20 and P25 indistinguishable, P20 (no centre
projector) if anything better than P25. This module computes candidate
proxies for that judgement on the table, over a set of hand poses
(:class:`PoseSet`), and tells which orderings each proxy reproduces
(:func:`orderings`).

Per pose the shadow of every projector is rasterised exactly
(:mod:`sim.sop_shadows`) on a fine lattice around the shadows (``pitch_mm``);
each projector's irradiance (the room's model) is read from a coarse grid. The
light drop at a table point is the room's: ``sum_i E_i s_i / sum_i E_i`` over
the powered projectors (``s_i``: projector i is blocked there). Proxies of one
pose (lower is better, every one):

``max_drop``
    The largest drop: the darkest point a viewer can find under the hand
    (Weber contrast of the shadow's core).
``umbra_mm2``
    Table area losing at least 90 % of its light: content gone.
``penumbra_mm2``
    Area losing between 1 % and 90 %: dimmed but present.
``area_above_10_mm2``
    Area losing more than 10 %: how far a visible drop spreads.
``shadow_mm2``
    ``penumbra_mm2 + UMBRA_WEIGHT * umbra_mm2``: the area where the picture is
    visibly dimmed, where it is gone counting :data:`UMBRA_WEIGHT` (10) times.
    Every weight in :func:`umbra_weight_interval` reproduces the four
    orderings with the default poses (about 5.4 to 44); 10 is a round number
    inside it, not a fit. It rewards a compact shadow, so it prefers few
    projectors close together: each of those weights ranks P9D ahead of
    P25, and the planner minimising it stops improving after two (docs/research.md).
``edge_per_arcmin``
    The steepest drop gradient at the eye's scale, in drop per arcminute of
    visual angle: the drop map is blurred by a Gaussian of ``edge_sigma_mm``,
    the largest gradient (per mm) times the mm one arcminute spans at
    ``distance_mm``. A hard step of height J reads ``J / (sqrt(2 pi) sigma)``
    per mm. Defaults: a viewer 0.7 m from the table with 1 arcmin acuity
    (0.20 mm); the blur is 1 mm because the projector lens itself blurs each
    shadow edge by about that much (a 10 mm aperture and a hand 200-300 mm
    above the table, 1.4 m from the projectors: a penumbra 1.7-2.8 mm wide)
    and the raster resolves it (0.5 mm).
``copies``
    Effective number of distinct shadow copies: the area of the union of the
    projectors' shadows over the mean area of one (1 when they coincide, the
    number of projectors when they do not touch).
``overlap``
    Mean number of projectors blocked at a shadowed point.

Proxies over a pose set are the means over poses.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from sim.hand import Hand
from sim.sop_shadows import (
    Grid,
    Source,
    polygons_bounds,
    rasterize,
    resample,
    shadow_polygons,
    table_irradiance,
)

#: proxy name -> one line about it (the order of every table).
PROXIES: dict[str, str] = {
    "max_drop": "largest light drop (fraction)",
    "umbra_mm2": "area losing >= 90 % (mm^2)",
    "penumbra_mm2": "area losing 1-90 % (mm^2)",
    "area_above_10_mm2": "area losing > 10 % (mm^2)",
    "shadow_mm2": "penumbra + 10 x umbra area (mm^2)",
    "edge_per_arcmin": "steepest drop gradient at the eye's scale (drop per arcmin)",
    "copies": "effective number of distinct shadow copies",
    "overlap": "mean number of projectors blocked at a shadowed point",
}

#: how many times an umbra's area counts against a penumbra's in ``shadow_mm2``
UMBRA_WEIGHT = 10.0

#: the proxy this project uses to compare layouts (see docs in :mod:`studies.proxies_cli` and the report).
CHOSEN = "max_drop"

#: the paper's orderings, each checked on a proxy's per-subset values (lower = less SoP).
ORDERINGS: dict[str, str] = {
    "p1_worst": "P1 worse than every other layout",
    "dense_beats_wide_9": "P9D better than P9W",
    "p17_p20_p25_alike": "P17, P20, P25 within the tolerance of each other",
    "p20_not_worse_than_p25": "P20 not worse than P25",
}


@dataclass(frozen=True)
class Viewing:
    """How the table is looked at and sampled (see the module docstring for the defaults' reasons)."""

    distance_mm: float = 700.0
    acuity_arcmin: float = 1.0
    edge_sigma_mm: float = 1.0
    pitch_mm: float = 0.5
    irradiance_pitch_mm: float = 10.0

    def __post_init__(self) -> None:
        if min(self.distance_mm, self.acuity_arcmin, self.edge_sigma_mm, self.pitch_mm, self.irradiance_pitch_mm) <= 0:
            raise ValueError("every viewing figure must be positive")

    @property
    def mm_per_arcmin(self) -> float:
        """Table mm one arcminute spans at the viewing distance."""
        return self.distance_mm * math.tan(math.radians(1.0 / 60.0))


@dataclass(frozen=True)
class PoseSet:
    """Hands over the workspace: every combination of positions, heights and yaws.

    Heights are of the hand's lowest point; yaws are the direction the fingers
    point, counter-clockwise from +y (a person at the -y edge reaching across).
    """

    xs: tuple[float, ...] = (-300.0, 0.0, 300.0)
    ys: tuple[float, ...] = (-150.0, 0.0, 150.0)
    heights: tuple[float, ...] = (100.0, 200.0, 300.0)
    yaws: tuple[float, ...] = (-30.0, 0.0, 30.0)
    pose: str = "flat"

    def hands(self) -> list[Hand]:
        return [Hand(position=(x, y), height=h, yaw_deg=yaw, pose=self.pose)
                for h in self.heights for yaw in self.yaws for y in self.ys for x in self.xs]

    def describe(self) -> dict:
        return {"x_mm": list(self.xs), "y_mm": list(self.ys), "height_mm": list(self.heights), "yaw_deg": list(self.yaws),
                "pose": self.pose, "count": len(self.xs) * len(self.ys) * len(self.heights) * len(self.yaws)}


#: the default pose set: 81 flat hands, 3 x 3 positions over the table, 100-300 mm up, fingers -30..30 deg.
WORKSPACE = PoseSet()
#: a small set for smoke runs and tests.
QUICK = PoseSet(xs=(-300.0, 150.0), ys=(0.0,), heights=(200.0,), yaws=(0.0, 30.0))


def point_proxies(drop: np.ndarray, area: np.ndarray | float) -> dict[str, float]:
    """The proxies that need only the drop at samples and the area each stands for.

    Parameters
    ----------
    drop : (...) float
        Light drop in [0, 1] per sample.
    area : (...) float or float
        mm^2 per sample.

    Returns
    -------
    dict with ``max_drop``, ``umbra_mm2``, ``penumbra_mm2``, ``area_above_10_mm2``, ``shadow_mm2``.
    """
    d = np.asarray(drop, np.float64)
    a = np.broadcast_to(np.asarray(area, np.float64), d.shape)
    umbra, penumbra = float(a[d >= 0.9].sum()), float(a[(d >= 0.01) & (d < 0.9)].sum())
    return {
        "max_drop": float(d.max(initial=0.0)),
        "umbra_mm2": umbra,
        "penumbra_mm2": penumbra,
        "area_above_10_mm2": float(a[d > 0.1].sum()),
        "shadow_mm2": penumbra + UMBRA_WEIGHT * umbra,
    }


def edge_per_arcmin(drop: np.ndarray, grid: Grid, viewing: Viewing) -> float:
    """Steepest gradient of the drop after the eye-scale blur, per arcminute (see the module docstring).

    Parameters
    ----------
    drop : (rows, cols) float
        On ``grid``; the grid must extend a few ``edge_sigma_mm`` beyond any
        shadow (the border is repeated).
    """
    d = np.asarray(drop, np.float32)
    if d.shape != grid.shape:
        raise ValueError(f"drop must have the grid's shape {grid.shape}, got {d.shape}")
    blurred = cv2.GaussianBlur(d, (0, 0), viewing.edge_sigma_mm / grid.pitch, borderType=cv2.BORDER_REPLICATE)
    if min(d.shape) < 2:
        return 0.0
    gy, gx = np.gradient(blurred.astype(np.float64), grid.pitch)
    return float(np.hypot(gx, gy).max()) * viewing.mm_per_arcmin


@dataclass
class _Pose:
    """One pose's rasters: the window, every source's shadow mask and irradiance there."""

    grid: Grid
    masks: dict[str, np.ndarray]
    irradiance: dict[str, np.ndarray] = field(default_factory=dict)


class ShadowRasters:
    """Shadows of a pose set from a set of sources on a table, for evaluating many subsets of them.

    Parameters
    ----------
    sources : mapping name -> Source
    table_size : (float, float)
        mm, centred on the origin.
    viewing : Viewing
    """

    def __init__(self, sources: Mapping[str, Source], table_size: tuple[float, float], viewing: Viewing = Viewing()) -> None:
        self.sources = dict(sources)
        self.viewing = viewing
        self.fine = Grid.covering(table_size, viewing.pitch_mm)
        self.coarse = Grid.covering(table_size, viewing.irradiance_pitch_mm)
        self._coarse_e = {n: table_irradiance(self.coarse, s) for n, s in self.sources.items()}

    def pose(self, hand, names: Sequence[str] | None = None) -> _Pose | None:
        """Rasters of ``hand`` (any occluder with ``primitives()``); None when no shadow falls on the table."""
        names = list(self.sources) if names is None else list(names)
        prims = hand.primitives()
        polys = {n: shadow_polygons(self.sources[n].center, prims) for n in names}
        lo = np.min([polygons_bounds(p)[0] for p in polys.values()], axis=0)
        hi = np.max([polygons_bounds(p)[1] for p in polys.values()], axis=0)
        pad = 4.0 * self.viewing.edge_sigma_mm + 2.0 * self.viewing.pitch_mm
        win = self.fine.window(tuple(lo - pad), tuple(hi + pad))
        if win is None:
            return None
        out = _Pose(win, {n: rasterize(polys[n], win) for n in names})
        out.irradiance = {n: resample(self._coarse_e[n], self.coarse, win) for n in names}
        return out

    def proxies(self, pose: _Pose, subset: Sequence[str]) -> dict[str, float]:
        """Every proxy of :data:`PROXIES` for one pose and one subset of the sources."""
        total = np.zeros(pose.grid.shape, np.float32)
        blocked = np.zeros(pose.grid.shape, np.float32)
        count = np.zeros(pose.grid.shape, np.int32)
        single = []
        for n in subset:
            e, m = pose.irradiance[n], pose.masks[n]
            total += e
            blocked += e * m
            count += m
            single.append(float(np.count_nonzero(m & (e > 0))))
        with np.errstate(divide="ignore", invalid="ignore"):
            drop = np.where(total > 0, blocked / total, 0.0).astype(np.float32)
        area = pose.grid.cell_area
        out = point_proxies(drop, area)
        out["edge_per_arcmin"] = edge_per_arcmin(drop, pose.grid, self.viewing)
        shadowed = (count > 0) & (total > 0)
        union = float(np.count_nonzero(shadowed))
        mean_single = float(np.mean(single)) if single else 0.0
        out["copies"] = union / mean_single if mean_single > 0 else 0.0
        out["overlap"] = float(count[shadowed].mean()) if union > 0 else 0.0
        return {k: out[k] for k in PROXIES}


def evaluate_subsets(
    sources: Mapping[str, Source],
    subsets: Mapping[str, Sequence[str]],
    *,
    table_size: tuple[float, float],
    poses: PoseSet = WORKSPACE,
    viewing: Viewing = Viewing(),
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, dict[str, float]]:
    """Mean of every proxy over ``poses`` for each named subset of ``sources``.

    Returns
    -------
    {subset name: {proxy name: mean over the poses that cast a shadow on the table}}
    """
    missing = sorted({n for s in subsets.values() for n in s} - set(sources))
    if missing:
        raise ValueError(f"subsets name sources that do not exist: {missing}")
    rasters = ShadowRasters(sources, table_size, viewing)
    needed = sorted({n for s in subsets.values() for n in s})
    acc: dict[str, list[dict[str, float]]] = {name: [] for name in subsets}
    hands = poses.hands()
    for k, hand in enumerate(hands):
        pose = rasters.pose(hand, needed)
        if pose is not None:
            for name, subset in subsets.items():
                acc[name].append(rasters.proxies(pose, subset))
        if progress is not None:
            progress(k + 1, len(hands))
    return {name: {p: float(np.mean([r[p] for r in rows])) if rows else 0.0 for p in PROXIES} for name, rows in acc.items()}


def orderings(values: Mapping[str, float], *, tolerance: float = 0.1) -> dict[str, bool]:
    """Which of the paper's orderings (:data:`ORDERINGS`) one proxy's values reproduce (lower = better).

    ``p17_p20_p25_alike``: every pair of P17, P20, P25 differs by at most
    ``tolerance`` times |P1 - P25| (the proxy's whole range over the study).
    ``p20_not_worse_than_p25``: P20 <= P25, strictly by value.

    Parameters
    ----------
    values : {"P1": v, "P9D": v, "P9W": v, "P17": v, "P20": v, "P25": v, ...}
    """
    need = {"P1", "P9D", "P9W", "P17", "P20", "P25"}
    if not need <= set(values):
        raise ValueError(f"need values for {sorted(need)}, got {sorted(values)}")
    v = {k: float(x) for k, x in values.items()}
    others = [x for k, x in v.items() if k != "P1"]
    span = abs(v["P1"] - v["P25"])
    trio = [v["P17"], v["P20"], v["P25"]]
    return {
        "p1_worst": v["P1"] > max(others),
        "dense_beats_wide_9": v["P9D"] < v["P9W"],
        "p17_p20_p25_alike": max(trio) - min(trio) <= tolerance * span,
        "p20_not_worse_than_p25": v["P20"] <= v["P25"],
    }


def umbra_weight_interval(results: Mapping[str, Mapping[str, float]], *, tolerance: float = 0.1,
                          weights: np.ndarray | None = None) -> tuple[float, float] | None:
    """The weights ``w`` for which ``penumbra_mm2 + w * umbra_mm2`` reproduces all four orderings.

    ``results``: :func:`evaluate_subsets`' output. ``weights``: the ``w`` tried (default 2001
    log-spaced from 0.01 to 1000). Returns the smallest and largest of them that reproduce every
    ordering, or None when none does (the weights in between need not all reproduce them).
    """
    ws = np.logspace(-2, 3, 2001) if weights is None else np.asarray(weights, np.float64)
    good = [float(w) for w in ws if all(orderings(
        {name: r["penumbra_mm2"] + w * r["umbra_mm2"] for name, r in results.items()}, tolerance=tolerance).values())]
    return (min(good), max(good)) if good else None


def ordering_table(results: Mapping[str, Mapping[str, float]], *, tolerance: float = 0.1) -> dict[str, dict[str, bool]]:
    """{proxy: {ordering: reproduced}} from :func:`evaluate_subsets`' output."""
    return {p: orderings({name: r[p] for name, r in results.items()}, tolerance=tolerance) for p in PROXIES}
