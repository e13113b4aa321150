"""`shadowless study scheffe RATINGS.csv`: Scheffé's paired comparison (Nakaya's modification) of a
study's ratings, as a table (or JSON for scripts) and a bar chart of the scale values."""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from studies.chart import scale_chart_svg
from studies.scheffe import ratings_array, read_ratings, scheffe_nakaya


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("ratings", type=Path, help="CSV: participant,first,second,score")
    p.add_argument("--image", metavar="NAME", help="ratings with an image column (`study run` writes one): this "
                   "image's only (default: every image, each participant on each image one judge)")
    p.add_argument("--chart", type=Path, metavar="SVG", help="write the scale values as a bar chart here")
    p.add_argument("--json", action="store_true", help="print JSON for scripts")


def _num(x: float) -> float | None:
    return None if math.isnan(x) else round(x, 6)


def _report(args: argparse.Namespace) -> int:
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


def run(args: argparse.Namespace) -> int:
    try:
        return _report(args)
    except ValueError as exc:       # a file that is not a study's ratings: one line, status 2
        print(f"shadowless study scheffe: {exc}", file=sys.stderr)
        return 2
