"""Paired comparison of task times between two conditions: the analysis of the paper's first study
(touching targets with and without shadows, each participant in both conditions).

Times are compared on their logarithm (task times are skewed; a ratio is what people feel). The
differences are checked for normality with Shapiro-Wilk; if they pass, a paired t test on log time
with Cohen's d_z (mean difference over its standard deviation); if not, Wilcoxon's signed-rank
test (zero differences dropped, normal approximation with continuity correction) with
r = |Z| / sqrt(N). SciPy computes the tests; this module chooses, reports and reads the CSV.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class PairedResult:
    conditions: tuple[str, str]
    n: int
    log: bool
    normality_w: float
    normality_p: float
    test: str                 # "paired t" or "Wilcoxon signed-rank"
    statistic: float          # t, or Wilcoxon's W (the smaller rank sum)
    df: float                 # t's degrees of freedom; NaN for Wilcoxon
    p: float
    effect: str               # "cohen_dz" or "r"
    effect_size: float
    ratio: float              # geometric mean of second / first (log) or mean difference (raw)


def paired_tests(first: np.ndarray, second: np.ndarray, *, names: tuple[str, str] = ("A", "B"), log: bool = True,
                 alpha: float = 0.05) -> PairedResult:
    """Compare ``first`` and ``second`` (each (N,) float, participant-aligned)."""
    from scipy import stats   # the coordinator's stack

    a, b = np.asarray(first, np.float64), np.asarray(second, np.float64)
    if a.shape != b.shape or a.ndim != 1 or len(a) < 3:
        raise ValueError(f"need two aligned series of at least 3 values, got shapes {a.shape} and {b.shape}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ValueError("times must be finite numbers")
    if log:
        if np.any(a <= 0) or np.any(b <= 0):
            raise ValueError("times must be positive to compare their logarithms")
        a, b = np.log(a), np.log(b)
    d = b - a
    w, pw = stats.shapiro(d)
    if pw >= alpha:
        t = stats.ttest_rel(a, b)
        sd = d.std(ddof=1)
        return PairedResult(names, len(d), log, float(w), float(pw), "paired t", float(t.statistic), float(t.df),
                            float(t.pvalue), "cohen_dz", float(d.mean() / sd) if sd > 0 else math.inf,
                            float(math.exp(d.mean())) if log else float(d.mean()))
    r = stats.wilcoxon(a, b, zero_method="wilcox", correction=True, method="approx")
    n = int(np.count_nonzero(d))
    return PairedResult(names, len(d), log, float(w), float(pw), "Wilcoxon signed-rank", float(r.statistic),
                        math.nan, float(r.pvalue), "r", float(abs(r.zstatistic) / math.sqrt(n)) if n else 0.0,
                        float(math.exp(np.median(d))) if log else float(np.median(d)))


def read_times(path: str | Path) -> tuple[tuple[str, str], np.ndarray, np.ndarray]:
    """A CSV with columns ``participant,condition,time_s`` and exactly two conditions; a
    participant's repeated trials are averaged (geometric mean) per condition. Returns the
    conditions in order of first appearance and two aligned (N,) arrays."""
    p = Path(path)
    data: dict[tuple[str, str], list[float]] = {}
    conditions: list[str] = []
    try:
        with p.open(newline="") as f:
            reader = csv.DictReader(f)
            if not reader.fieldnames or not {"participant", "condition", "time_s"} <= set(reader.fieldnames):
                raise ValueError(f"{p}: the header must name the columns participant, condition, time_s "
                                 f"(found: {', '.join(reader.fieldnames or []) or 'none'})")
            for k, r in enumerate(reader, start=2):
                try:
                    v = float(r["time_s"])
                except (TypeError, ValueError):
                    raise ValueError(f"{p}:{k}: time {r.get('time_s')!r} is not a number") from None
                if not (math.isfinite(v) and v > 0):
                    raise ValueError(f"{p}:{k}: time {v} must be a positive number of seconds")
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
        raise ValueError(f"{p}: participant(s) {', '.join(lacking)} lack a time in one condition")
    gm = lambda v: float(np.exp(np.mean(np.log(v))))  # noqa: E731
    a = np.array([gm(data[(person, conditions[0])]) for person in people])
    b = np.array([gm(data[(person, conditions[1])]) for person in people])
    return (conditions[0], conditions[1]), a, b
