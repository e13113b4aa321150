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

What the numbers cannot say is said, not guessed: when the error sum of squares is 0 (a panel
whose every rating the model explains, or all-zero ratings) an F ratio is ``MS / 0`` or
``0 / 0`` and the yardstick is 0; they are reported as undefined (NaN here, null in JSON) with
the reason in :attr:`AnovaRow.undefined` and :attr:`ScheffeResult.undefined`, never as
``F = inf, p = 0``. Scores are read on a stated scale (:func:`read_ratings`, ``-2..2`` unless
told): a score outside it, or a fraction on a scale of whole steps, is refused naming the file,
row and value.

Nakaya's design has no order term: each judge rates each pair once, shown one way round, so a
preference for the side (or the moment) a configuration is shown on is not separated from the
configurations in this table. What it does to the result depends on the balance of sides: with
every pair shown each way round equally often across judges (``shadowless study schedule``
does that) a side preference only adds to the error term, widening the yardsticks; without
that balance it shifts the scale values, and nothing in the table shows it. The checks in
:mod:`studies.side_checks` look for it from outside the model, as warnings.
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
    f: float          # NaN for error and total, and when undefined
    p: float          # NaN for error and total, and when undefined
    undefined: str = ""   # why F and p are undefined (an effect's row only); "" when they are defined


@dataclass(frozen=True)
class ScheffeResult:
    """The analysis: items in input order, their scale values, the ANOVA table, the yardsticks
    and letter groupings (items sharing a letter do not differ at that level)."""

    items: tuple[str, ...]
    participants: tuple[str, ...]
    scale: np.ndarray                       # (t,) float64
    anova: tuple[AnovaRow, ...]
    yardstick: dict[float, float]           # level -> Y; NaN when undefined
    letters: dict[float, tuple[str, ...]]   # level -> a letter string per item; no entry when undefined
    undefined: str = ""                     # why the yardsticks are undefined; "" when they are defined

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


#: the scale `study run` records on (-2 clearly left .. 2 clearly right), and the default of :func:`read_ratings`
RUN_SCALE = (-2.0, 2.0)


def parse_scale(text: str) -> tuple[float, float]:
    """``"-3..3"`` -> (-3.0, 3.0). ValueError unless it is MIN..MAX, symmetric around 0: the rating
    of i over j is minus the rating of j over i, so a paired-comparison scale has both sides."""
    lo, sep, hi = str(text).strip().partition("..")
    try:
        a, b = float(lo), float(hi)
    except ValueError:
        a = b = math.nan
    if not sep or not (math.isfinite(a) and math.isfinite(b)):
        raise ValueError(f"{text!r} is not a scale MIN..MAX, e.g. -3..3")
    if not (a < 0 < b and a == -b):
        raise ValueError(f"{text!r}: a paired-comparison scale runs from -MAX to MAX (a rating of i over j is minus "
                         f"the rating of j over i), e.g. -3..3")
    return a, b


def scale_text(scale: tuple[float, float]) -> str:
    return f"{scale[0]:g}..{scale[1]:g}"


def read_questions(path: str | Path) -> tuple[tuple[str, ...], bool]:
    """The questions a ratings file answers, in order of first appearance, and whether it is a
    run's file from before `study run` asked two questions (the run's columns without ``question``).

    ``()`` for a file without a question column (one question, unnamed)."""
    p = Path(path)
    try:
        with p.open(newline="") as f:
            reader = csv.DictReader(f)
            cols = set(reader.fieldnames or [])
            if "question" not in cols:
                return (), {"image", "trial", "answer"} <= cols
            seen: dict[str, None] = {}
            for r in reader:
                seen.setdefault(r.get("question") or "", None)
    except OSError as exc:
        raise ValueError(f"cannot read {p}: {exc.strerror or exc}") from None
    return tuple(seen), False


def read_ratings(path: str | Path, *, image: str | None = None, question: str | None = None,
                 scale: tuple[float, float] = RUN_SCALE, continuous: bool = False,
                 judge_per_image: bool = True) -> list[tuple[str, str, str, float]]:
    """A ratings CSV with columns ``participant,first,second,score`` (a header row).

    With an ``image`` column too (``shadowless study run`` writes one), each participant on each
    image is one judge, ``participant/image`` (unless ``judge_per_image`` is False): Nakaya's design
    has every judge rate every pair once, and a participant rates every pair once per image.
    ``image``: keep that image's rows only. With a ``question`` column (a run's file records
    every question of a trial), ``question`` keeps that question's rows; a file of several
    questions needs it (each is its own analysis).

    Every score must lie on ``scale`` (MIN, MAX) and, unless ``continuous``, be a whole number:
    ValueError naming the file, row and value otherwise (the rows of other images and questions
    too: a file with a bad row is a bad file).
    """
    p = Path(path)
    lo, hi = scale
    try:
        with p.open(newline="") as f:
            reader = csv.DictReader(f)
            need = {"participant", "first", "second", "score"}
            if not reader.fieldnames or not need <= set(reader.fieldnames):
                raise ValueError(f"{p}: the header must name the columns participant, first, second, score "
                                 f"(found: {', '.join(reader.fieldnames or []) or 'none'})")
            asked = "question" in reader.fieldnames
            rows, questions = [], set()
            for k, r in enumerate(reader, start=2):
                try:
                    score = float(r["score"])
                except (TypeError, ValueError):
                    raise ValueError(f"{p}:{k}: score {r.get('score')!r} is not a number") from None
                if not math.isfinite(score):
                    raise ValueError(f"{p}:{k}: score {r['score']!r} is not a number")
                if not lo <= score <= hi:
                    raise ValueError(f"{p}:{k}: score {r['score']!r} is outside the scale {scale_text(scale)} "
                                     f"(--scale gives another)")
                if not continuous and score != round(score):
                    raise ValueError(f"{p}:{k}: score {r['score']!r} is not a whole step of the scale "
                                     f"{scale_text(scale)} (--continuous allows fractions)")
                img, q = r.get("image") or "", r.get("question") or ""
                questions.add(q)
                if (image is not None and img != image) or (question is not None and q != question):
                    continue
                judge = f"{r['participant']}/{img}" if img and judge_per_image else r["participant"]
                rows.append((judge, r["first"], r["second"], score))
            if question is not None and not asked:
                raise ValueError(f"{p}: no question column (one question per trial): leave out the question")
            if question is None and len(questions) > 1:
                raise ValueError(f"{p}: answers {len(questions)} questions ({', '.join(sorted(questions))}): "
                                 f"analyse one at a time")
            if question is not None and question not in questions:
                raise ValueError(f"{p}: no answers to question {question!r} (questions: "
                                 f"{', '.join(sorted(questions)) or 'none'})")
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
    if s_e <= 1e-10 * s_t:      # 0 up to rounding (the sums are of integers on a whole-step scale)
        s_e = 0.0
    df = {"main effect": t - 1, "individual differences": (t - 1) * (n - 1),
          "combination": (t - 1) * (t - 2) // 2}
    df_e = n * t * (t - 1) // 2 - sum(df.values())     # (t - 1)(t - 2)(n - 1) / 2 >= 1 for t >= 3, n >= 2
    ms_e = s_e / df_e
    rows = []
    for source, ss in (("main effect", s_a), ("individual differences", s_ab), ("combination", s_g)):
        ms = ss / df[source]
        if s_t == 0:
            why = "every rating is 0: F = 0 / 0"
        elif ms_e == 0:
            why = (f"the error term is 0 (the model explains every rating): F = {'0 / 0' if ms <= 0 else 'MS / 0'} "
                   f"is undefined, not significant")
        else:
            why = ""
        if why:
            rows.append(AnovaRow(source, ss, df[source], ms, math.nan, math.nan, why))
        else:
            f = ms / ms_e
            rows.append(AnovaRow(source, ss, df[source], ms, f, float(stats.f.sf(f, df[source], df_e))))
    rows.append(AnovaRow("error", s_e, df_e, ms_e, math.nan, math.nan))
    rows.append(AnovaRow("total", s_t, n * t * (t - 1) // 2, math.nan, math.nan, math.nan))
    scale = xi / (t * n)
    if ms_e == 0:
        why = ("every rating is 0: no yardstick" if s_t == 0 else
               "the error term is 0: a yardstick of 0 would call every difference significant; it is undefined")
        return ScheffeResult(items, participants, scale, tuple(rows), {lv: math.nan for lv in levels}, {}, why)
    yard = {lv: float(stats.studentized_range.ppf(1 - lv, t, df_e) * math.sqrt(ms_e / (t * n))) for lv in levels}
    return ScheffeResult(items, participants, scale, tuple(rows), yard,
                         {lv: _letters(scale, y) for lv, y in yard.items()})
