"""Checks of a paired-comparison study for a preference of side (or order), which Nakaya's model
cannot see: warnings beside the analysis, never a change to it.

A rating row ``(participant, first, second, score)`` is read with ``first`` as the one shown
first — in a `study run` file the configuration on the participant's left — and ``score > 0``
preferring it. Two checks:

* **Side effect** (:func:`side_effect`): a shift ``d`` of every rating toward the first-shown
  one, fitted by least squares beside one free mean per unordered pair::

      score[r] = s[r] * m[pair(r)] + d + e[r]       (s[r] = +1 shown i-first, -1 shown j-first)

  so the pair's own difference (whatever it is: the main effects and the combination effect of
  Scheffé's model together) cannot pass for a side preference. Only pairs shown both ways round
  inform ``d``; with none, ``d`` is undefined and the reason says so. ``d``'s t test uses the
  residual variance on ``N - rank`` degrees of freedom, which also holds the judges' individual
  differences: a conservative test. With every pair shown each way equally often, ``d`` is the
  mean of all scores; with one pair it is half the difference of its two orientations' means,
  and the t test is the pooled two-sample t test of those (the tests check both).
* **One-sided participants** (:func:`one_sided`): a participant whose every rating, over all
  images, prefers the first-shown one (or every one the second). With random sides a
  participant who judged only the configurations does that with probability ``2 * 2**-k`` for
  ``k`` ratings, so it is flagged when that is below 5 % (``k >= 6``); with fewer ratings the
  check cannot tell a habit of side from a taste.

What the design can and cannot detect: Nakaya's modification has every judge rate each pair
once, so a side preference is not a term of its ANOVA. If the schedule balances the sides
across judges (``shadowless study schedule`` does), a side preference inflates the error term
(wider yardsticks, the scale values unmoved); if it does not, the preference leaks into the
scale values and the ANOVA shows nothing. The side effect above is estimable only from pairs
that some judges saw each way round, and it measures the panel's average preference: a
participant's own habit of side is not separable from their taste for a pair they saw once,
except in the extreme that :func:`one_sided` flags. A file whose ``first`` column is in a fixed
order (not the order shown) makes both checks meaningless.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

Row = tuple[str, str, str, float]

#: what the report says beside the side effect (the paragraph above, in one sentence)
DESIGN_NOTE = ("Nakaya's design has no side (order) term: with the sides balanced across judges a side preference "
               "only widens the yardsticks, without that balance it shifts the scale values unseen; it is estimated "
               "here from the pairs shown both ways round, and a participant's own habit shows only if it is total")


@dataclass(frozen=True)
class SideEffect:
    estimate: float          # d: the mean shift toward the first-shown one, in scale steps; NaN when undefined
    t: float
    df: int
    p: float                 # two-sided
    pairs_both_ways: int     # pairs shown each way round at least once (they inform d)
    pairs: int
    undefined: str = ""      # why d (or its test) is undefined; "" when defined


def side_effect(rows: Sequence[Row]) -> SideEffect:
    """The side effect of ``rows`` (see the module's docstring)."""
    from scipy import stats   # the coordinator's stack

    pairs: dict[tuple[str, str], int] = {}
    ways: dict[tuple[str, str], set[int]] = {}
    cols, y = [], []
    for _, a, b, score in rows:
        key, sign = ((a, b), 1) if a < b else ((b, a), -1)
        k = pairs.setdefault(key, len(pairs))
        ways.setdefault(key, set()).add(sign)
        cols.append((k, sign))
        y.append(float(score))
    both = sum(len(w) == 2 for w in ways.values())
    nan = math.nan
    if not both:
        return SideEffect(nan, nan, 0, nan, 0, len(pairs), "no pair was shown both ways round: a side preference "
                                                           "cannot be told from the pair's own difference")
    x = np.zeros((len(y), len(pairs) + 1))        # (N, P + 1) float64: the pairs' signed columns, then d
    for r, (k, sign) in enumerate(cols):
        x[r, k] = sign
    x[:, -1] = 1.0
    yv = np.asarray(y)
    coef, _, rank, _ = np.linalg.lstsq(x, yv, rcond=None)
    df = len(yv) - int(rank)
    d = float(coef[-1])
    if df <= 0:
        return SideEffect(d, nan, 0, nan, both, len(pairs), "no degrees of freedom left for the error")
    resid = yv - x @ coef
    s2 = float(resid @ resid) / df
    cov = np.linalg.pinv(x.T @ x)
    se = math.sqrt(max(s2 * float(cov[-1, -1]), 0.0))
    if se <= 1e-12 * max(1.0, abs(d)):
        why = ("every rating is the same within its pair and side: t = 0 / 0" if abs(d) <= 1e-12 else
               "the ratings vary with nothing but pair and side: t = d / 0 is undefined")
        return SideEffect(d, nan, df, nan, both, len(pairs), why)
    t = d / se
    return SideEffect(d, t, df, float(2 * stats.t.sf(abs(t), df)), both, len(pairs))


def one_sided(rows: Sequence[Row], *, min_ratings: int = 6) -> list[tuple[str, str, int]]:
    """``(participant, "first" | "second", k)`` for each participant of at least ``min_ratings``
    ratings, every one of which prefers the first-shown (score > 0) or every one the second."""
    scores: dict[str, list[float]] = {}
    for person, _, _, score in rows:
        scores.setdefault(person, []).append(score)
    out = []
    for person, s in scores.items():
        if len(s) >= min_ratings and (all(v > 0 for v in s) or all(v < 0 for v in s)):
            out.append((person, "first" if s[0] > 0 else "second", len(s)))
    return out


def warnings(rows: Sequence[Row], *, level: float = 0.05, shown: str = "first-shown") -> tuple[SideEffect, list[str]]:
    """The side effect and the warnings of ``rows`` (one participant per row's participant, not per
    image), one line each; ``shown`` names the first-shown one ("left" for a run's file)."""
    eff = side_effect(rows)
    out = []
    if not eff.undefined and eff.p < level:
        toward = shown if eff.estimate > 0 else "other"
        out.append(f"side effect: ratings lean {abs(eff.estimate):.3g} scale steps toward the {toward} one "
                   f"(t = {eff.t:.2f}, df = {eff.df}, p = {eff.p:.2g}, from {eff.pairs_both_ways} of {eff.pairs} "
                   f"pairs shown both ways); Nakaya's analysis has no term for it")
    for person, side, k in one_sided(rows):
        which = shown if side == "first" else ("right" if shown == "left" else "second-shown")
        out.append(f"participant {person} preferred the {which} one in all {k} ratings (1 in {2 ** (k - 1):,} by chance "
                   f"with random sides): a habit of side, or an unusually clear taste")
    return eff, out
