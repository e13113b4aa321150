"""`shadowless study paired FILE.csv`: a paired test of task times (on the log scale by default) or
of accuracies in two conditions, as lines of text (or JSON for scripts). Every difference is
second − first; undefined numbers are said to be, and are null in JSON."""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from studies.paired import TESTS, ZERO_METHODS, PairedResult, paired_tests, read_measures
from studies.report import dumps, num_text, p_text


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("times", type=Path, metavar="FILE",
                   help="CSV: participant,condition,time_s (seconds) or participant,condition,accuracy (0..1)")
    p.add_argument("--measure", choices=("time_s", "accuracy"), default=None,
                   help="the column to compare when the file has both (`study search` writes both; default time_s)")
    p.add_argument("--raw", action="store_true", help="compare the times themselves, not their logarithms "
                   "(accuracies are always compared as they are)")
    p.add_argument("--test", choices=TESTS, default=None,
                   help="auto: Shapiro-Wilk on the differences chooses the paired t test or Wilcoxon's; t or "
                        "wilcoxon: that one (default: auto for times, wilcoxon for accuracies)")
    p.add_argument("--zeros", choices=ZERO_METHODS, default="wilcox",
                   help="Wilcoxon's zero differences: wilcox drops them before ranking (default; R's wilcox.test, "
                        "SPSS), pratt ranks them with the rest, then drops them")
    p.add_argument("--json", action="store_true", help="print JSON for scripts")


def _doc(column: str, r: PairedResult) -> dict:
    return {
        "measure": column, "conditions": list(r.conditions), "n": r.n, "log": r.log, "direction": r.direction,
        "shapiro_w": r.normality_w, "shapiro_p": r.normality_p, "test": r.test,
        "statistic": r.statistic, "statistic_is": "t" if r.test == "paired t" else "W+ (rank sum of positive "
                                                                                   "differences)",
        "df": r.df, "p": r.p, r.effect: r.effect_size,
        **({"ranked": r.ranked, "zero_method": r.zero_method} if r.test != "paired t" else {}),
        "mean_difference": r.mean_difference, "median_difference": r.median_difference,
        "geometric_mean_ratio": r.geometric_mean_ratio, "median_ratio": r.median_ratio,
        **({"ratio_undefined": r.ratio_undefined} if r.ratio_undefined else {}),
        **({"undefined": r.undefined} if r.undefined else {}),
        **({"note": r.note} if r.note else {}),
    }


def _report(args: argparse.Namespace) -> int:
    column, names, a, b = read_measures(args.times, args.measure)
    times = column == "time_s"
    test = args.test or ("auto" if times else "wilcoxon")
    r = paired_tests(a, b, names=names, log=times and not args.raw, test=test, zero_method=args.zeros)
    if args.json:
        print(dumps(_doc(column, r)))
        return 0
    what = ("log time" if r.log else "time") if times else "accuracy"
    print(f"{names[0]} vs {names[1]}: {r.n} participants, compared on {what}; differences are {r.direction}")
    if math.isnan(r.normality_w):
        print("Shapiro-Wilk on the differences: undefined (they are all equal)")
    else:
        print(f"Shapiro-Wilk on the differences: W = {r.normality_w:.4f}, p = {p_text(r.normality_p)}")
    if r.note:
        print(f"({r.note})")
    if r.undefined:
        print(f"{r.test}: undefined: {r.undefined}")
    elif r.test == "paired t":
        print(f"paired t ({r.direction}): t = {r.statistic:.4f}, df = {r.df:g}, p = {p_text(r.p)}; "
              f"Cohen's d_z = {r.effect_size:+.3f}")
    else:
        zeros = r.n - r.ranked
        dropped = f"; {zeros} zero difference{'s' if zeros != 1 else ''} {'dropped' if r.zero_method == 'wilcox' else 'ranked, then dropped'}" if zeros else ""
        print(f"Wilcoxon signed-rank ({r.direction}): W+ = {r.statistic:g} over {r.ranked} ranked{dropped}; "
              f"p = {p_text(r.p)} (normal approximation, continuity correction); r = {r.effect_size:+.3f}")
    unit = "" if r.log or not times else " s"
    scale = "log time" if r.log else what
    print(f"mean difference {r.mean_difference:+.4g}{unit}, median difference {r.median_difference:+.4g}{unit} "
          f"(on {scale}, {r.direction})")
    if r.ratio_undefined:
        print(f"ratios {names[1]} / {names[0]}: undefined ({r.ratio_undefined.split(': ')[0]})")
    else:
        print(f"{names[1]} / {names[0]}: geometric mean of the ratios {num_text(r.geometric_mean_ratio)}x, "
              f"median of the ratios {num_text(r.median_ratio)}x")
    return 0


def run(args: argparse.Namespace) -> int:
    try:
        return _report(args)
    except ValueError as exc:       # a file that is not a study's measures: one line, status 2
        print(f"shadowless study paired: {exc}", file=sys.stderr)
        return 2
