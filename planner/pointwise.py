"""Can a pointwise proxy both reproduce the study's orderings and keep few projectors behind many?

A *pointwise* proxy weighs each table point by a nondecreasing function of its
light drop and sums the weights over the area (mean over hand poses): the
umbra and penumbra areas, ``shadow_mm2``, every "area losing more than t"
and every power of the drop are such proxies. The study's four orderings
(:data:`studies.proxies.ORDERINGS`) are linear in the weight function once each
layout's drop is binned into bands: a layout's value is its histogram (mm^2
per drop band) times the weights. So whether *some* weight function
reproduces them, and also ranks given layouts behind P25, is a linear
programme (:func:`fit`).

:func:`search` asks it together with the planner. It fits weights, lets the
planner (:func:`planner.search.plan`) minimise them with at most ``most``
projectors, adds every such layout it finds ahead of P25 as one more
constraint, and fits again, until either no small layout beats P25 (the
weights are returned) or the programme has no solution: then no pointwise
proxy at all, at the bands' resolution, reproduces the four orderings
without ranking one of those small layouts ahead of the paper's 25, which a
proxy whose curve flattens near 17 projectors must not do. :func:`conflict` then
says which of the orderings must give, and by how much: the least violation over
every weighting (an elastic form of the same programme).

Everything is measured on one :class:`~planner.evaluate.Evaluator` world
(its samples and hands): the planner's candidates, and the reference rig's
layouts (:data:`sim.scene.SUBSETS`) on a second evaluator of the same
surface and hands.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linprog

from planner.evaluate import Evaluator
from planner.search import plan
from planner.surface import Surface, irradiance
from sim.scene import SUBSETS, reference_scene
from sim.sop_shadows import Source

#: every constraint of :func:`fit` holds with this fraction of P1's value to spare (the LP solver's tolerance)
SPARE = 1e-6

#: drops below this count zero in every pointwise proxy (the samples beside a shadow hold drop 0)
FLOOR = 1e-6


@dataclass(frozen=True, eq=False)
class BandWeights:
    """A pointwise proxy: a sample counts its area times the weight of the band its drop falls in.

    Attributes
    ----------
    edges : (B + 1,) float64
        Increasing; band j is ``edges[j] <= drop < edges[j + 1]``. A drop below
        ``edges[0]`` weighs 0; the last edge lies above 1.
    weights : (B,) float64
        Nondecreasing, nonnegative.
    """

    edges: np.ndarray
    weights: np.ndarray

    def __post_init__(self) -> None:
        e, w = np.asarray(self.edges, np.float64), np.asarray(self.weights, np.float64)
        if e.ndim != 1 or w.shape != (len(e) - 1,) or len(w) < 1:
            raise ValueError(f"need B + 1 edges for B weights, got {e.shape} and {w.shape}")
        if not (np.all(np.diff(e) > 0) and e[0] > 0 and e[-1] > 1):
            raise ValueError("edges must increase from above 0 to above 1")
        if w.min() < 0 or np.any(np.diff(w) < -1e-12):
            raise ValueError("weights must be nonnegative and nondecreasing")
        object.__setattr__(self, "edges", e)
        object.__setattr__(self, "weights", w)

    @classmethod
    def bands(cls, count: int, weights: np.ndarray | None = None) -> BandWeights:
        """``count`` bands of equal width over (0, 1] (the first from :data:`FLOOR`); weights default to all ones."""
        if count < 1:
            raise ValueError("need at least one band")
        edges = np.r_[FLOOR, np.arange(1, count) / count, 1.0 + 1e-9]
        return cls(edges, np.ones(count) if weights is None else weights)

    def __call__(self, drop: np.ndarray) -> np.ndarray:
        """Weight per sample: (...) float32 from a (...) drop."""
        d = np.asarray(drop)
        i = np.searchsorted(self.edges, d, side="right") - 1
        return np.where(i >= 0, self.weights[np.clip(i, 0, len(self.weights) - 1)], 0.0).astype(np.float32)

    def histogram(self, ev: Evaluator, subset: Sequence[int]) -> np.ndarray:
        """Mean over ``ev``'s poses of the area (mm^2) whose drop under ``subset`` falls in each band: (B,) float64.

        The proxy's value of the subset is this times :attr:`weights`.
        """
        out = np.zeros(len(self.weights))
        for idx, drop in ev.drops(subset):
            out += np.histogram(drop, bins=self.edges, weights=ev.area[idx])[0]
        return out / len(ev.index)

    def at(self, drop: float) -> float:
        return float(self(np.array([drop]))[0])

    def __str__(self) -> str:
        return "pointwise"


#: the names :func:`conflict` gives the constraints: :data:`studies.proxies.ORDERINGS` and the small layouts
BEHIND = "behind_p25"


def _constraints(reference: Mapping[str, np.ndarray], behind: Sequence[np.ndarray], nb: int, tolerance: float,
                 margin: float) -> tuple[np.ndarray, list[str], dict[str, np.ndarray]]:
    """``A`` with ``A @ a <= 0`` for the increments ``a`` (w = T a), each row's name, and each layout's ``h T``."""
    need = {"P1", "P9D", "P9W", "P17", "P20", "P25"}
    if not need <= set(reference):
        raise ValueError(f"need histograms of {sorted(need)}, got {sorted(reference)}")
    for k, h in reference.items():
        if np.shape(h) != (nb,):
            raise ValueError(f"{k}'s histogram has {np.shape(h)} bands, the edges make {nb}")
    # w = T a with a >= 0 (increments): w is nondecreasing and nonnegative; a value is h . w = (h T) . a
    cum = np.tril(np.ones((nb, nb)))
    row = {k: np.asarray(h, np.float64) @ cum for k, h in reference.items()}
    A: list[np.ndarray] = []
    names: list[str] = []

    def better(x: np.ndarray, y: np.ndarray, name: str, strict: bool = True) -> None:  # value x (+ margin) <= value y
        A.append(x - y + (margin * row["P1"] if strict else 0.0))
        names.append(name)

    for k in reference:
        if k != "P1":
            better(row[k], row["P1"], "p1_worst")
    better(row["P9D"], row["P9W"], "dense_beats_wide_9")
    trio = ("P17", "P20", "P25")
    for x in trio:
        for y in trio:
            if x != y:
                A.append(row[x] - row[y] - tolerance * (row["P1"] - row["P25"]))
                names.append("p17_p20_p25_alike")
    better(row["P20"], row["P25"], "p20_not_worse_than_p25", strict=False)
    for h in behind:
        better(row["P25"], np.asarray(h, np.float64) @ cum, BEHIND)
    return np.array(A), names, row


def fit(reference: Mapping[str, np.ndarray], behind: Sequence[np.ndarray] = (), *, edges: np.ndarray,
        tolerance: float = 0.1, margin: float = 1e-3) -> BandWeights | None:
    """Nondecreasing band weights that reproduce the four orderings and rank every ``behind`` layout after P25.

    Parameters
    ----------
    reference : {"P1": h, "P9D": h, "P9W": h, "P17": h, "P20": h, "P25": h, ...}
        Each layout's band histogram, (B,) float (:meth:`BandWeights.histogram`).
    behind : sequence of (B,) float
        Histograms of layouts that must be worse than P25.
    edges : (B + 1,) float
    tolerance : float
        :func:`studies.proxies.orderings`' "alike" tolerance.
    margin : float
        Every strict ordering ("worse", "better", "behind") must hold by
        ``margin`` times P1's value; the weights are scaled so the top band weighs 1.

    Returns
    -------
    The weights, or None when no nondecreasing weights satisfy every constraint.
    """
    nb = len(edges) - 1
    A, _, row = _constraints(reference, behind, nb, tolerance, margin)
    A = A + SPARE * row["P1"]  # every constraint, so the solver's own tolerance cannot break one
    res = linprog(np.zeros(nb), A_ub=A, b_ub=np.zeros(len(A)), A_eq=np.ones((1, nb)), b_eq=[1.0],
                  bounds=[(0, None)] * nb, method="highs")
    if res.status == 2:
        return None
    if res.status != 0:
        raise RuntimeError(f"the linear programme did not finish: {res.message}")
    cum = np.tril(np.ones((nb, nb)))
    return BandWeights(np.asarray(edges, np.float64), np.maximum.accumulate(cum @ np.maximum(res.x, 0.0)))


def conflict(reference: Mapping[str, np.ndarray], behind: Sequence[np.ndarray] = (), *, edges: np.ndarray,
             tolerance: float = 0.1, margin: float = 1e-3) -> dict[str, float]:
    """What must give when :func:`fit` has no solution: the least violation of its constraints.

    The same programme made elastic: each constraint may be broken by a slack ``s >= 0``, the
    weights scaled so that P1's value is 1, and the total slack minimised over every
    nondecreasing weighting. Returns the slack per constraint group that needs one, as a fraction
    of P1's value: the names of :data:`studies.proxies.ORDERINGS`, and :data:`BEHIND` for the small
    layouts together. Empty when the constraints hold (up to :data:`SPARE`). Which orderings
    appear tells which of the paper's findings a pointwise proxy cannot reconcile with the rest;
    how much, how far it is from holding.
    """
    nb = len(edges) - 1
    A, names, row = _constraints(reference, behind, nb, tolerance, margin)
    m = len(A)
    res = linprog(np.r_[np.zeros(nb), np.ones(m)], A_ub=np.hstack([A, -np.eye(m)]), b_ub=np.zeros(m),
                  A_eq=np.r_[row["P1"], np.zeros(m)][None], b_eq=[1.0], bounds=[(0, None)] * (nb + m), method="highs")
    if res.status != 0:
        raise RuntimeError(f"the elastic programme did not finish: {res.message}")
    out: dict[str, float] = {}
    for name, slack in zip(names, res.x[nb:]):
        if slack > SPARE:
            out[name] = out.get(name, 0.0) + float(slack)
    return out


@dataclass
class Outcome:
    """What :func:`search` found.

    Attributes
    ----------
    weights : BandWeights or None
        Weights under which the planner found no layout of at most ``most``
        projectors ahead of P25; None when none exist (see ``layouts``).
    layouts : list of list of str
        The small layouts the planner found ahead of P25 in some round (candidate names).
    rounds : list of dict
        Per round: the layouts it added and the best value per projector count against P25's.
    must_give : dict
        When no weights exist: :func:`conflict`'s least violation per ordering (fractions of P1's value).
    """

    weights: BandWeights | None
    layouts: list[list[str]] = field(default_factory=list)
    rounds: list[dict] = field(default_factory=list)
    must_give: dict[str, float] = field(default_factory=dict)

    @property
    def exists(self) -> bool:
        return self.weights is not None


def reference_evaluator(surface: Surface, hands, *, seed: int = 0,
                        proxy="max_drop") -> tuple[Evaluator, dict[str, list[int]]]:
    """The reference rig (:func:`sim.scene.reference_scene`) on ``surface`` under ``hands``, and its
    named layouts (:data:`sim.scene.SUBSETS`) as indices into it: :func:`search`'s reference world."""
    sources = [Source.from_spec(p) for p in reference_scene(seed=seed).projectors]
    ev = Evaluator(surface, sources, irradiance(surface, sources), hands, proxy=proxy)
    names = [s.name for s in sources]
    return ev, {n: [names.index(x) for x in slots] for n, slots in SUBSETS.items()}


def search(ev: Evaluator, reference_ev: Evaluator, subsets: Mapping[str, Sequence[int]], *, most: int = 4, bands: int = 200,
           rounds: int = 20, tolerance: float = 0.1, margin: float = 1e-3,
           progress: Callable[[str], None] | None = None) -> Outcome:
    """Look for a pointwise proxy that reproduces the orderings and keeps every layout of ``most`` or fewer behind P25.

    Parameters
    ----------
    ev : Evaluator
        The planner's candidates.
    reference_ev : Evaluator
        The reference rig on the same surface and hands; ``subsets`` name its
        layouts by index (:data:`sim.scene.SUBSETS`).
    most : int
        The largest projector count that must stay behind P25.
    bands : int
        Drop bands of equal width: the weight function's resolution.
    rounds : int
        At most this many fits; a :class:`RuntimeError` if still undecided.
    """
    if not 1 <= most <= ev.candidates:
        raise ValueError(f"most must be 1..{ev.candidates}, got {most}")
    grid = BandWeights.bands(bands)
    ref = {name: grid.histogram(reference_ev, s) for name, s in subsets.items()}
    behind: dict[tuple[int, ...], np.ndarray] = {}
    out = Outcome(None)
    for r in range(rounds):
        w = fit(ref, list(behind.values()), edges=grid.edges, tolerance=tolerance, margin=margin)
        if w is None:
            out.must_give = conflict(ref, list(behind.values()), edges=grid.edges, tolerance=tolerance, margin=margin)
            if progress is not None:
                progress(f"round {r + 1}: no weights satisfy the orderings and the {len(behind)} small layouts")
            return out
        judged = ev.using(w)
        p1, p25 = float(ref["P1"] @ w.weights), float(ref["P25"] @ w.weights)
        bar = p25 + margin * p1
        found: dict[tuple[int, ...], float] = {}
        best = {}
        for n in range(1, most + 1):
            res = plan(judged, n)
            layout = tuple(sorted(res.chosen))
            best[n] = res.value
            if res.value < bar and layout not in behind:
                found[layout] = res.value
        out.rounds.append({"round": r + 1, "p25": round(p25, 6), "best_by_count": {n: round(v, 6) for n, v in best.items()},
                           "added": [[ev.sources[i].name for i in k] for k in found]})
        if progress is not None:
            progress(f"round {r + 1}: P25 {p25:.4g}; best of 1..{most}: " + ", ".join(f"{v:.4g}" for v in best.values())
                     + f"; {len(found)} small layout{'s' if len(found) != 1 else ''} ahead of P25")
        if not found:
            out.weights = w
            return out
        for k in found:
            behind[k] = w.histogram(ev, k)
            out.layouts.append([ev.sources[i].name for i in k])
    raise RuntimeError(f"undecided after {rounds} rounds ({len(behind)} small layouts so far); allow more rounds")
