"""Paired comparison of one measure in two conditions, each participant in both: the analysis of
the paper's first study (ten A5 sheets on the table, three of them blank and carrying projected
text; the participant names the three, under the 25-projector rig and under one bright projector;
its completion times and its accuracies, the fraction of the three named; `studies.search_runner`
runs it on the rig).

Every difference is **second − first** (the conditions in the order the file names them first):
t, Cohen's d_z, the signed effect r and the mean and median differences all point the same way,
and the report says so.

* **Times** (column ``time_s``, positive) are compared on their logarithm by default (task times
  are skewed; a ratio is what people feel). Summaries: the geometric mean of the ratios
  second / first (``exp`` of the mean log difference) and their median, each under its own name.
* **Accuracies** (column ``accuracy``, fractions 0..1; zeros are accuracies too) are compared as
  they are, with Wilcoxon's test by default: bounded and tie-heavy, their differences are rarely
  normal. The ratios' geometric mean is reported only where it is defined (every value
  positive); otherwise the report says why not.

Test choice (``test="auto"``): Shapiro-Wilk on the differences; if they pass at ``alpha``, a paired
t test with d_z = mean / sd of the differences; if not, Wilcoxon's signed-rank test with
r = Z / sqrt(N), N the differences the test ranks. Zero differences (ties between the two
conditions, common with accuracies) are handled as the standard packages do: ``zero_method=
"wilcox"`` drops them before ranking (R's ``wilcox.test``, SPSS and the usual textbook procedure,
hence the paper's), with the normal approximation, its continuity correction and the tie
correction of the variance (an exact p value does not exist with ties). ``"pratt"`` ranks the
zeros with the rest and then drops them (Pratt 1959), which keeps the other ranks as if the zeros
were small differences; it is offered for a comparison, not used by default. When a statistic is
a ratio of zeros (every difference 0, or all equal so their sd is 0) it is undefined and the
reason is given, never a t of infinity. Differences are rounded to 12 decimals first, so that
equal differences of decimal inputs are ties (0.6 − 0.2 is 0.39999999999999997 in floating point).

SciPy computes the tests (Shapiro-Wilk, ``ttest_rel``, ``wilcoxon``); this module chooses,
orients, summarises and reads the CSV.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

TESTS = ("auto", "t", "wilcoxon")
ZERO_METHODS = ("wilcox", "pratt")
#: the measure columns a file may have: column -> (what it is, its unit in text)
MEASURES = {"time_s": "time", "accuracy": "accuracy"}


@dataclass(frozen=True)
class PairedResult:
    conditions: tuple[str, str]
    n: int
    log: bool
    direction: str            # "second - first" in the conditions' names, e.g. "P25 − P1"
    normality_w: float        # NaN when undefined (differences all equal)
    normality_p: float
    test: str                 # "paired t" or "Wilcoxon signed-rank"
    statistic: float          # t of second − first, or W+ (the rank sum of the positive second − first differences)
    df: float                 # t's degrees of freedom; NaN for Wilcoxon
    p: float                  # two-sided; NaN when undefined
    effect: str               # "cohen_dz" or "r"
    effect_size: float        # signed: positive when second > first; NaN when undefined
    mean_difference: float    # of second − first on the compared scale (log or raw)
    median_difference: float
    geometric_mean_ratio: float   # of second / first; NaN when undefined
    median_ratio: float           # the median of second / first; NaN when undefined
    ratio_undefined: str = ""     # why the ratios are undefined
    ranked: int = 0               # differences Wilcoxon's test ranked (zeros dropped)
    zero_method: str = "wilcox"
    undefined: str = ""           # why the test is undefined; "" when it is defined
    note: str = ""                # why this test was chosen when it was not by Shapiro-Wilk


def paired_tests(first: np.ndarray, second: np.ndarray, *, names: tuple[str, str] = ("A", "B"), log: bool = True,
                 alpha: float = 0.05, test: str = "auto", zero_method: str = "wilcox") -> PairedResult:
    """Compare ``first`` and ``second`` (each (N,) float, participant-aligned): differences
    second − first, on the log scale when ``log``."""
    from scipy import stats   # the coordinator's stack

    if test not in TESTS or zero_method not in ZERO_METHODS:
        raise ValueError(f"test is one of {', '.join(TESTS)}, zero_method one of {', '.join(ZERO_METHODS)}")
    a, b = np.asarray(first, np.float64), np.asarray(second, np.float64)
    if a.shape != b.shape or a.ndim != 1 or len(a) < 3:
        raise ValueError(f"need two aligned series of at least 3 values, got shapes {a.shape} and {b.shape}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ValueError("the values must be finite numbers")
    positive = bool(np.all(a > 0) and np.all(b > 0))
    if log and not positive:
        raise ValueError("the values must be positive to compare their logarithms")
    if positive:
        ratios = b / a
        gm, med_ratio, why_ratio = float(np.exp(np.mean(np.log(ratios)))), float(np.median(ratios)), ""
    else:
        gm = med_ratio = math.nan
        why_ratio = "a value is 0 or negative: the ratios second / first (and their geometric mean) are undefined"
    if log:
        a, b = np.log(a), np.log(b)
    d = np.round(b - a, 12)     # equal differences of decimal inputs tie (0.6 - 0.2 is 0.39999999999999997)
    common = dict(conditions=names, n=len(d), log=log, direction=f"{names[1]} − {names[0]}",
                  mean_difference=float(d.mean()), median_difference=float(np.median(d)), geometric_mean_ratio=gm,
                  median_ratio=med_ratio, ratio_undefined=why_ratio, zero_method=zero_method)
    if np.ptp(d) == 0:
        w = pw = math.nan
        note = "the differences are all equal: normality is undefined"
    else:
        sw = stats.shapiro(d)
        w, pw, note = float(sw.statistic), float(sw.pvalue), ""
    if test == "t" or (test == "auto" and not note and pw >= alpha):
        sd = float(d.std(ddof=1))
        if np.ptp(d) == 0:          # (sd itself may come out as 1e-17 of rounding)
            why = "every difference is 0: t = 0 / 0" if not d.any() else "the differences are all equal: t = mean / 0"
            return PairedResult(normality_w=w, normality_p=pw, test="paired t", statistic=math.nan, df=len(d) - 1.0,
                                p=math.nan, effect="cohen_dz", effect_size=math.nan, undefined=why, note=note,
                                **common)
        t = stats.ttest_rel(b, a)         # second − first
        return PairedResult(normality_w=w, normality_p=pw, test="paired t", statistic=float(t.statistic),
                            df=float(t.df), p=float(t.pvalue), effect="cohen_dz", effect_size=float(d.mean() / sd),
                            note="" if test == "auto" else "the t test by choice, not by Shapiro-Wilk", **common)
    if test == "wilcoxon":
        note = "Wilcoxon's test by choice, not by Shapiro-Wilk"
    elif note:
        note += ", so Wilcoxon's test"
    ranked = int(np.count_nonzero(d))
    if ranked == 0:
        return PairedResult(normality_w=w, normality_p=pw, test="Wilcoxon signed-rank", statistic=math.nan,
                            df=math.nan, p=math.nan, effect="r", effect_size=math.nan, ranked=0,
                            undefined="every difference is 0: nothing to rank", note=note, **common)
    kw = dict(zero_method=zero_method, correction=True, method="approx")
    two = stats.wilcoxon(d, **kw)
    w_plus = float(stats.wilcoxon(d, alternative="greater", **kw).statistic)     # the positive ranks' sum
    n_ranked = ranked if zero_method == "wilcox" else len(d)     # Pratt's Z is on all N ranks
    w_minus = n_ranked * (n_ranked + 1) / 2 - w_plus - (0 if zero_method == "wilcox" else _zero_ranks(d))
    z = abs(float(two.zstatistic)) * (1 if w_plus > w_minus else -1 if w_plus < w_minus else 0)
    return PairedResult(normality_w=w, normality_p=pw, test="Wilcoxon signed-rank", statistic=w_plus, df=math.nan,
                        p=float(two.pvalue), effect="r", effect_size=z / math.sqrt(n_ranked), ranked=ranked,
                        note=note, **common)


def _zero_ranks(d: np.ndarray) -> float:
    """The ranks Pratt's method gives the zero differences (the smallest |d|), summed."""
    from scipy import stats

    r = stats.rankdata(np.abs(d))
    return float(r[d == 0].sum())


def read_measures(path: str | Path,
                  measure: str | None = None) -> tuple[str, tuple[str, str], np.ndarray, np.ndarray]:
    """A CSV with columns ``participant,condition`` and a measure, ``time_s`` (seconds, positive)
    or ``accuracy`` (a fraction 0..1), with exactly two conditions; ``measure`` names the column
    to read when the file has both (default: ``time_s`` if present). A participant's repeated
    trials are averaged per condition: times by their geometric mean, accuracies by their mean.
    Returns the measure's column, the conditions in order of first appearance and two aligned
    (N,) float64 arrays. ValueError naming the file (and row) for anything else."""
    p = Path(path)
    data: dict[tuple[str, str], list[float]] = {}
    conditions: list[str] = []
    try:
        with p.open(newline="") as f:
            reader = csv.DictReader(f)
            cols = set(reader.fieldnames or [])
            if measure is not None and measure not in MEASURES:
                raise ValueError(f"the measure is one of {', '.join(MEASURES)}, not {measure!r}")
            if measure is not None and measure not in cols:
                raise ValueError(f"{p}: has no {measure} column "
                                 f"(found: {', '.join(reader.fieldnames or []) or 'none'})")
            column = measure or next((c for c in MEASURES if c in cols), None)
            if not {"participant", "condition"} <= cols or column is None:
                raise ValueError(f"{p}: the header must name the columns participant, condition and time_s or "
                                 f"accuracy (found: {', '.join(reader.fieldnames or []) or 'none'})")
            for k, r in enumerate(reader, start=2):
                try:
                    v = float(r[column])
                except (TypeError, ValueError):
                    raise ValueError(f"{p}:{k}: {MEASURES[column]} {r.get(column)!r} is not a number") from None
                if column == "time_s" and not (math.isfinite(v) and v > 0):
                    raise ValueError(f"{p}:{k}: time {r[column]!r} must be a positive number of seconds")
                if column == "accuracy" and not (math.isfinite(v) and 0 <= v <= 1):
                    raise ValueError(f"{p}:{k}: accuracy {r[column]!r} must be a fraction 0..1 (85 % is 0.85)")
                if r["condition"] not in conditions:
                    conditions.append(r["condition"])
                data.setdefault((r["participant"], r["condition"]), []).append(v)
    except OSError as exc:
        raise ValueError(f"cannot read {p}: {exc.strerror or exc}") from None
    if len(conditions) != 2:
        raise ValueError(f"{p}: need exactly two conditions, found {len(conditions)}: {', '.join(conditions)}")
    people = sorted({person for person, _ in data})
    lacking = [person for person in people if any((person, c) not in data for c in conditions)]
    if lacking:
        raise ValueError(f"{p}: participant(s) {', '.join(lacking)} lack a {MEASURES[column]} in one condition")
    if column == "time_s":
        avg = lambda v: float(np.exp(np.mean(np.log(v))))  # noqa: E731
    else:
        avg = lambda v: float(np.mean(v))  # noqa: E731
    a = np.array([avg(data[(person, conditions[0])]) for person in people])
    b = np.array([avg(data[(person, conditions[1])]) for person in people])
    return column, (conditions[0], conditions[1]), a, b


def read_times(path: str | Path) -> tuple[tuple[str, str], np.ndarray, np.ndarray]:
    """:func:`read_measures` of a file of times (``time_s``): the conditions and the two arrays."""
    column, names, a, b = read_measures(path)
    if column != "time_s":
        raise ValueError(f"{path}: not a file of times (no time_s column)")
    return names, a, b
