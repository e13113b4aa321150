"""`shadowless study scheffe RATINGS.csv` and `shadowless study paired TIMES.csv`: the analyses of
the perception studies, as tables (or JSON for scripts) and a chart."""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from studies.chart import scale_chart_svg
from studies.paired import paired_tests, read_times
from studies.scheffe import ratings_array, read_ratings, scheffe_nakaya


def configure(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Analyse a perception study.\n\n"
        "  scheffe RATINGS.csv   Scheffé's paired comparison, Nakaya's modification: columns\n"
        "                        participant,first,second,score (every participant rates every pair\n"
        "                        once; score > 0 prefers first, e.g. -2..2). Prints the ANOVA table,\n"
        "                        the scale values, the yardsticks at p < .05 and .01 and letter groups.\n"
        "                        With an image column (`study run` writes one) each participant on\n"
        "                        each image is one judge (--image NAME: that image only).\n"
        "  paired TIMES.csv      task times in two conditions: columns participant,condition,time_s.\n"
        "                        Shapiro-Wilk on the log-time differences, then a paired t test (with\n"
        "                        Cohen's d_z) or Wilcoxon's signed-rank test (with r).")
    p.epilog = ("examples:\n"
                "  shadowless study scheffe study2.csv --chart sop.svg\n"
                "  shadowless study paired study1.csv --json")
    sub = p.add_subparsers(dest="analysis", metavar="ANALYSIS", required=True)
    s = sub.add_parser("scheffe", help="Scheffé's paired comparison (Nakaya's modification)")
    s.add_argument("ratings", type=Path, help="CSV: participant,first,second,score")
    s.add_argument("--image", metavar="NAME", help="ratings with an image column (`study run` writes one): this "
                   "image's only (default: every image, each participant on each image one judge)")
    s.add_argument("--chart", type=Path, metavar="SVG", help="write the scale values as a bar chart here")
    s.add_argument("--json", action="store_true", help="print JSON for scripts")
    t = sub.add_parser("paired", help="paired test of task times (log scale)")
    t.add_argument("times", type=Path, help="CSV: participant,condition,time_s")
    t.add_argument("--raw", action="store_true", help="compare the times themselves, not their logarithms")
    t.add_argument("--json", action="store_true", help="print JSON for scripts")


def _num(x: float) -> float | None:
    return None if math.isnan(x) else round(x, 6)


def _scheffe(args: argparse.Namespace) -> int:
    x, items, people = ratings_array(read_ratings(args.ratings, image=args.image))
    res = scheffe_nakaya(x, items, people)
    if args.chart:
        args.chart.write_text(scale_chart_svg(res, title=f"Scale values ({args.ratings.name})"))
    if args.json:
        print(json.dumps({
            "items": list(items), "participants": len(people),
            "scale": {k: round(float(v), 6) for k, v in zip(items, res.scale)},
            "anova": [{"source": r.source, "ss": _num(r.ss), "df": r.df, "ms": _num(r.ms), "f": _num(r.f),
                       "p": _num(r.p)} for r in res.anova],
            "yardstick": {f"{k:g}": round(v, 6) for k, v in res.yardstick.items()},
            "letters": {f"{k:g}": dict(zip(items, v)) for k, v in res.letters.items()},
        }, indent=2))
        return 0
    print(f"{len(items)} configurations, {len(people)} participants\n")
    print(f"{'source':<24}{'SS':>10}{'df':>6}{'MS':>10}{'F':>9}{'p':>10}")
    for r in res.anova:
        f = "" if math.isnan(r.f) else f"{r.f:.2f}"
        pv = "" if math.isnan(r.p) else f"{r.p:.4f}"
        ms = "" if math.isnan(r.ms) else f"{r.ms:.3f}"
        print(f"{r.source:<24}{r.ss:>10.3f}{r.df:>6}{ms:>10}{f:>9}{pv:>10}")
    print()
    print(f"{'configuration':<16}{'scale':>8}  groups .05  .01")
    for k in sorted(range(len(items)), key=lambda k: -res.scale[k]):
        print(f"{items[k]:<16}{res.scale[k]:>8.3f}  {res.letters[0.05][k]:<10} {res.letters[0.01][k]}")
    print(f"\nyardstick Y(.05) = {res.yardstick[0.05]:.3f}, Y(.01) = {res.yardstick[0.01]:.3f}")
    if args.chart:
        print(f"chart: {args.chart}")
    return 0


def _paired(args: argparse.Namespace) -> int:
    names, a, b = read_times(args.times)
    r = paired_tests(a, b, names=names, log=not args.raw)
    if args.json:
        print(json.dumps({"conditions": list(names), "n": r.n, "log": r.log, "shapiro_w": round(r.normality_w, 6),
                          "shapiro_p": round(r.normality_p, 6), "test": r.test, "statistic": round(r.statistic, 6),
                          "df": _num(r.df), "p": round(r.p, 6), r.effect: round(r.effect_size, 6),
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
        return _scheffe(args) if args.analysis == "scheffe" else _paired(args)
    except ValueError as exc:
        print(f"shadowless study {args.analysis}: {exc}", file=sys.stderr)
        return 2
