"""Scheffé's paired comparison with Nakaya's modification: the analysis of the paper's second
study (which projector configuration gives the better sense of projection).

Design: ``t`` configurations, ``n`` participants; every participant judges every unordered pair
once, on a symmetric scale (e.g. -2..2; positive: the first of the pair is preferred). The display
order is counterbalanced, not analysed (that is Nakaya's modification: no order effect).

Model, with ``x[i, j, l] = -x[j, i, l]`` the rating of participant ``l`` for ``i`` over ``j``::

    x[i, j, l] = (a[i] - a[j]) + (a[i, l] - a[j, l]) + g[i, j] + e[i, j, l]

main effects ``a`` (the scale values), individual differences in them ``a[i, l]``, combination
effects ``g`` (what the pair adds beyond the two scale values) and error. With
``X_i = sum_{j, l} x[i, j, l]``, ``X_il = sum_j x[i, j, l]`` and ``X_ij = sum_l x[i, j, l]``:

* scale values ``a_i = X_i / (t n)``;
* ``S_a = sum_i X_i**2 / (t n)`` on ``t - 1`` degrees of freedom;
* ``S_a(B) = sum_{i, l} X_il**2 / t - S_a`` on ``(t - 1)(n - 1)``;
* ``S_g = sum_{i<j} X_ij**2 / n - S_a`` on ``(t - 1)(t - 2) / 2``;
* ``S_T = sum_{i<j, l} x[i, j, l]**2`` on ``n t (t - 1) / 2``, the error the rest;
* the yardstick ``Y = q(t, f_e; p) * sqrt(MS_e / (t n))``, with ``q`` the studentized range:
  two scale values further apart than ``Y`` differ at level ``p``.

The sums of squares are the least-squares decomposition of that model (tests fit it with numpy
directly and compare).
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from itertools import combinations
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class AnovaRow:
    source: str
    ss: float
    df: int
    ms: float
    f: float          # NaN for error and total
    p: float          # NaN for error and total


@dataclass(frozen=True)
class ScheffeResult:
    """The analysis: items in input order, their scale values, the ANOVA table, the yardsticks
    and letter groupings (items sharing a letter do not differ at that level)."""

    items: tuple[str, ...]
    participants: tuple[str, ...]
    scale: np.ndarray                       # (t,) float64
    anova: tuple[AnovaRow, ...]
    yardstick: dict[float, float]           # level -> Y
    letters: dict[float, tuple[str, ...]]   # level -> a letter string per item

    def row(self, source: str) -> AnovaRow:
        return next(r for r in self.anova if r.source == source)


def ratings_array(rows: list[tuple[str, str, str, float]]) -> tuple[np.ndarray, tuple[str, ...], tuple[str, ...]]:
    """``(participant, first, second, score)`` rows -> ``x`` (t, t, n) float64, antisymmetric in
    its first two axes, with the items and participants in order of first appearance.

    ValueError when a participant rated a pair twice or not at all, or an item against itself."""
    items: list[str] = []
    people: list[str] = []
    for person, a, b, _ in rows:
        for it in (a, b):
            if it not in items:
                items.append(it)
        if person not in people:
            people.append(person)
    t, n = len(items), len(people)
    if t < 3 or n < 2:
        raise ValueError(f"need at least 3 items and 2 participants, got {t} and {n}")
    x = np.zeros((t, t, n))
    seen = np.zeros((t, t, n), bool)
    for person, a, b, score in rows:
        i, j, l = items.index(a), items.index(b), people.index(person)
        if i == j:
            raise ValueError(f"participant {person} rated {a} against itself")
        if seen[i, j, l]:
            raise ValueError(f"participant {person} rated the pair {a}/{b} twice")
        if not math.isfinite(score):
            raise ValueError(f"participant {person}: score {score!r} for {a}/{b} is not a number")
        seen[i, j, l] = seen[j, i, l] = True
        x[i, j, l], x[j, i, l] = score, -score
    missing = [(items[i], items[j], people[l]) for i, j in combinations(range(t), 2) for l in range(n)
               if not seen[i, j, l]]
    if missing:
        a, b, person = missing[0]
        raise ValueError(f"{len(missing)} ratings missing, e.g. participant {person} on {a}/{b}: Nakaya's "
                         f"design needs every participant to rate every pair once")
    return x, tuple(items), tuple(people)


def read_ratings(path: str | Path, *, image: str | None = None) -> list[tuple[str, str, str, float]]:
    """A ratings CSV with columns ``participant,first,second,score`` (a header row).

    With an ``image`` column too (``shadowless study run`` writes one), each participant on each
    image is one judge, ``participant/image``: Nakaya's design has every judge rate every pair
    once, and a participant rates every pair once per image. ``image``: keep that image's rows only.
    """
    p = Path(path)
    try:
        with p.open(newline="") as f:
            reader = csv.DictReader(f)
            need = {"participant", "first", "second", "score"}
            if not reader.fieldnames or not need <= set(reader.fieldnames):
                raise ValueError(f"{p}: the header must name the columns participant, first, second, score "
                                 f"(found: {', '.join(reader.fieldnames or []) or 'none'})")
            rows = []
            for k, r in enumerate(reader, start=2):
                img = r.get("image") or ""
                if image is not None and img != image:
                    continue
                try:
                    rows.append((f"{r['participant']}/{img}" if img else r["participant"], r["first"], r["second"],
                                 float(r["score"])))
                except (TypeError, ValueError):
                    raise ValueError(f"{p}:{k}: score {r.get('score')!r} is not a number") from None
            if image is not None and not rows:
                raise ValueError(f"{p}: no ratings of image {image!r}")
    except OSError as exc:
        raise ValueError(f"cannot read {p}: {exc.strerror or exc}") from None
    return rows


def _letters(scale: np.ndarray, y: float) -> tuple[str, ...]:
    """Compact letter display: items whose scale values lie within ``y`` of each other share a
    letter (maximal groups of consecutive items in sorted order)."""
    order = np.argsort(-scale)
    groups: list[tuple[int, int]] = []
    for start in range(len(order)):
        end = start
        while end + 1 < len(order) and scale[order[start]] - scale[order[end + 1]] <= y:
            end += 1
        if not groups or end > groups[-1][1]:
            groups.append((start, end))
    out = [""] * len(scale)
    for g, (a, b) in enumerate(groups):
        for k in range(a, b + 1):
            out[order[k]] += chr(ord("a") + g) if g < 26 else "*"
    return tuple(out)


def scheffe_nakaya(x: np.ndarray, items: tuple[str, ...], participants: tuple[str, ...],
                   levels: tuple[float, ...] = (0.05, 0.01)) -> ScheffeResult:
    """The analysis of ratings ``x`` (t, t, n), antisymmetric (see :func:`ratings_array`)."""
    from scipy import stats   # the coordinator's stack

    t, _, n = x.shape
    xi = x.sum(axis=(1, 2))                   # X_i
    xil = x.sum(axis=1)                       # X_il, (t, n)
    iu = np.triu_indices(t, 1)
    xij = x.sum(axis=2)[iu]                   # X_ij, i < j
    s_a = float((xi ** 2).sum() / (t * n))
    s_ab = float((xil ** 2).sum() / t - s_a)
    s_g = float((xij ** 2).sum() / n - s_a)
    s_t = float((x[iu] ** 2).sum())
    s_e = s_t - s_a - s_ab - s_g
    df = {"main effect": t - 1, "individual differences": (t - 1) * (n - 1),
          "combination": (t - 1) * (t - 2) // 2}
    df_e = n * t * (t - 1) // 2 - sum(df.values())
    ms_e = s_e / df_e if df_e > 0 else float("nan")
    rows = []
    for source, ss in (("main effect", s_a), ("individual differences", s_ab), ("combination", s_g)):
        ms = ss / df[source]
        f = ms / ms_e if ms_e > 0 else float("inf")
        rows.append(AnovaRow(source, ss, df[source], ms, f, float(stats.f.sf(f, df[source], df_e))))
    rows.append(AnovaRow("error", s_e, df_e, ms_e, float("nan"), float("nan")))
    rows.append(AnovaRow("total", s_t, n * t * (t - 1) // 2, float("nan"), float("nan"), float("nan")))
    scale = xi / (t * n)
    yard = {lv: float(stats.studentized_range.ppf(1 - lv, t, df_e) * math.sqrt(ms_e / (t * n))) for lv in levels}
    return ScheffeResult(items, participants, scale, tuple(rows), yard,
                         {lv: _letters(scale, y) for lv, y in yard.items()})
