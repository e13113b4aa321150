"""Shadow masks per (candidate, pose), computed once; the proxy of any subset is then sums over them.

With ``E[i, j]`` candidate i's irradiance at sample j (0 where it does not
reach) and ``M[p][i, j]`` whether hand pose p blocks it there, the light drop
of a subset S at sample j under pose p is
``sum_{i in S} E[i, j] M[p][i, j] / sum_{i in S} E[i, j]``, the room's
definition (:meth:`sim.truth.Truth.light_drop`). Each pose keeps only the
samples some candidate's shadow reaches (elsewhere the drop is 0 for every
subset), so adding one candidate to every subset at once is a few array
operations on ``(candidates, shadowed samples)`` per pose.

Proxies (lower is better; means over the poses), as :func:`studies.proxies.point_proxies`
defines them: ``max_drop``, ``area_above_10_mm2``, ``umbra_mm2``, ``penumbra_mm2``, ``shadow_mm2``;
or any *pointwise* proxy: a callable that weighs each sample by its drop
(``weigh(drop) -> weights``, the same shape), summed over the area
(:class:`planner.pointwise.BandWeights`).
"""
from __future__ import annotations

import copy
from collections.abc import Callable, Sequence

import numpy as np

from planner.surface import Surface
from studies.proxies import UMBRA_WEIGHT
from sim.sop_shadows import Source, rasterize, shadow_polygons

#: the proxies the planner can minimise (see the module docstring)
PLAN_PROXIES = ("max_drop", "area_above_10_mm2", "umbra_mm2", "penumbra_mm2", "shadow_mm2")


def shadow_masks(surface: Surface, sources: Sequence[Source], hand) -> np.ndarray:
    """Which samples each source's light misses because of ``hand``.

    The table: shadow polygons rasterised on its grid; a mesh: a ray test
    from the source to every sample against every primitive.

    Returns
    -------
    (len(sources), n) bool
    """
    prims = hand.primitives()
    out = np.zeros((len(sources), surface.size), bool)
    if surface.grid is not None:
        for i, s in enumerate(sources):
            out[i] = rasterize(shadow_polygons(s.center, prims), surface.grid).ravel()
        return out
    pts = surface.points
    for i, s in enumerate(sources):
        v = pts - s.center
        dist = np.linalg.norm(v, axis=1)
        d = v / dist[:, None]
        blocked = np.zeros(len(pts), bool)
        for prim in prims:
            t_in, t_out = prim.interval_from(s.center, d[:, 0], d[:, 1], d[:, 2])
            blocked |= (t_in < dist - 1e-6) & (t_out > 1e-6)
        out[i] = blocked
    return out


def proxy_of(drop: np.ndarray, area: np.ndarray, proxy) -> np.ndarray:
    """One proxy along the last axis of ``drop`` ((..., m) float) with ``area`` (m,) mm^2 per sample: (...,).

    ``proxy``: a name of :data:`PLAN_PROXIES`, or a callable weighing each drop (pointwise).
    """
    if callable(proxy):
        return np.asarray(proxy(drop), np.float32) @ area
    if proxy == "max_drop":
        return drop.max(axis=-1, initial=0.0)
    if proxy == "area_above_10_mm2":
        return (drop > 0.1).astype(np.float32) @ area
    if proxy == "umbra_mm2":
        return (drop >= 0.9).astype(np.float32) @ area
    if proxy == "penumbra_mm2":
        return ((drop >= 0.01) & (drop < 0.9)).astype(np.float32) @ area
    if proxy == "shadow_mm2":  # studies.proxies's: penumbra + UMBRA_WEIGHT x umbra
        weight = np.where(drop >= 0.9, np.float32(UMBRA_WEIGHT), (drop >= 0.01).astype(np.float32))
        return weight @ area
    raise ValueError(f"unknown proxy {proxy!r}; the planner minimises one of {', '.join(PLAN_PROXIES)}")


def _checked(proxy):
    if not callable(proxy) and proxy not in PLAN_PROXIES:
        raise ValueError(f"unknown proxy {proxy!r}; the planner minimises one of {', '.join(PLAN_PROXIES)}")
    return proxy


class Evaluator:
    """Irradiance and shadow masks of every candidate under every pose, and the proxy of subsets.

    Parameters
    ----------
    surface : Surface
    sources : list of Source
        The candidates, in order (indices below refer to it).
    irradiance : (C, n) float32
        :func:`planner.surface.irradiance` of the sources.
    hands : list
        The occluder distribution (each with ``primitives()``), equally likely.
    proxy : str or callable
        One of :data:`PLAN_PROXIES`, or a pointwise weighing (see the module docstring).
    """

    def __init__(self, surface: Surface, sources: Sequence[Source], irradiance: np.ndarray, hands: Sequence, *, proxy: str = "max_drop",
                 progress: Callable[[int, int], None] | None = None) -> None:
        _checked(proxy)
        E = np.asarray(irradiance, np.float32)
        if E.shape != (len(sources), surface.size):
            raise ValueError(f"irradiance must be ({len(sources)}, {surface.size}), got {E.shape}")
        if not hands:
            raise ValueError("need at least one hand pose")
        self.surface, self.sources, self.E, self.proxy = surface, list(sources), E, proxy
        self.area = surface.area.astype(np.float32)
        self.index: list[np.ndarray] = []   # per pose: the samples some shadow reaches
        self.blocked: list[np.ndarray] = []  # per pose: (C, m) float32, E where blocked
        for k, hand in enumerate(hands):
            m = shadow_masks(surface, self.sources, hand) & (E > 0)
            idx = np.flatnonzero(m.any(axis=0))
            self.index.append(idx)
            self.blocked.append(np.where(m[:, idx], E[:, idx], 0.0).astype(np.float32))
            if progress is not None:
                progress(k + 1, len(hands))

    @property
    def candidates(self) -> int:
        return len(self.sources)

    def using(self, proxy) -> Evaluator:
        """The same cached shadows judged by another proxy (a shallow copy; nothing is recomputed)."""
        out = copy.copy(self)
        out.proxy = _checked(proxy)
        return out

    def drops(self, subset: Sequence[int]) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per pose, the samples some shadow reaches (m,) int and the subset's light drop there (m,) float32."""
        s = list(subset)
        total = self.E[s].sum(axis=0) if s else np.zeros(self.surface.size, np.float32)
        out = []
        for idx, B in zip(self.index, self.blocked):
            t = total[idx]
            with np.errstate(divide="ignore", invalid="ignore"):
                drop = np.where(t > 0, B[s].sum(axis=0) / t, 0.0).astype(np.float32)
            out.append((idx, drop))
        return out

    def value(self, subset: Sequence[int]) -> float:
        """The proxy of one subset of candidate indices (mean over poses)."""
        if not list(subset):
            return 0.0
        return float(np.mean([proxy_of(drop[None], self.area[idx], self.proxy)[0] for idx, drop in self.drops(subset)]))

    def with_each(self, subset: Sequence[int]) -> np.ndarray:
        """The proxy of ``subset`` plus each candidate in turn: (C,) float64 (a member added again counts twice)."""
        s = list(subset)
        total = self.E[s].sum(axis=0) if s else np.zeros(self.surface.size, np.float32)
        acc = np.zeros(self.candidates)
        for idx, B in zip(self.index, self.blocked):
            base_b = B[s].sum(axis=0) if s else np.zeros(len(idx), np.float32)
            t = total[idx][None, :] + self.E[:, idx]
            with np.errstate(divide="ignore", invalid="ignore"):
                drop = np.where(t > 0, (base_b[None, :] + B) / t, 0.0)
            acc += proxy_of(drop, self.area[idx], self.proxy)
        return acc / len(self.index)

    def coverage(self, subset: Sequence[int]) -> np.ndarray:
        """(n,) int: how many of ``subset`` light each sample (no hands)."""
        s = list(subset)
        return (self.E[s] > 0).sum(axis=0) if s else np.zeros(self.surface.size, int)

    def uncovered_with_each(self, subset: Sequence[int], k: int) -> np.ndarray:
        """(C,) float64: surface area (mm^2) lit by fewer than ``k`` after adding each candidate."""
        cov = self.coverage(subset)[None, :] + (self.E > 0)
        return (cov < k).astype(np.float32) @ self.area
