"""`shadowless study paired TIMES.csv`: a paired test of task times in two conditions (on the log
scale by default), as lines of text (or JSON for scripts)."""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from studies.paired import paired_tests, read_times


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("times", type=Path, help="CSV: participant,condition,time_s")
    p.add_argument("--raw", action="store_true", help="compare the times themselves, not their logarithms")
    p.add_argument("--json", action="store_true", help="print JSON for scripts")


def _report(args: argparse.Namespace) -> int:
    names, a, b = read_times(args.times)
    r = paired_tests(a, b, names=names, log=not args.raw)
    if args.json:
        df = None if math.isnan(r.df) else round(r.df, 6)
        print(json.dumps({"conditions": list(names), "n": r.n, "log": r.log, "shapiro_w": round(r.normality_w, 6),
                          "shapiro_p": round(r.normality_p, 6), "test": r.test, "statistic": round(r.statistic, 6),
                          "df": df, "p": round(r.p, 6), r.effect: round(r.effect_size, 6),
                          "ratio" if r.log else "difference": round(r.ratio, 6)}, indent=2))
        return 0
    what = "log time" if r.log else "time"
    print(f"{names[0]} vs {names[1]}: {r.n} participants, compared on {what}")
    print(f"Shapiro-Wilk on the differences: W = {r.normality_w:.4f}, p = {r.normality_p:.4f}")
    df = "" if math.isnan(r.df) else f", df = {r.df:g}"
    print(f"{r.test}: statistic = {r.statistic:.4f}{df}, p = {r.p:.4g}; {r.effect} = {r.effect_size:.3f}")
    if r.log:
        print(f"{names[1]} takes {r.ratio:.3f}x the time of {names[0]} (geometric mean of the ratios)")
    return 0


def run(args: argparse.Namespace) -> int:
    try:
        return _report(args)
    except ValueError as exc:       # a file that is not a study's times: one line, status 2
        print(f"shadowless study paired: {exc}", file=sys.stderr)
        return 2
