"""`shadowless study scheffe RATINGS.csv`: Scheffé's paired comparison (Nakaya's modification) of a
study's ratings, as a table (or JSON for scripts) and a bar chart of the scale values.

A file of several questions (`study run` asks two per trial) gets one analysis per question;
``--question KEY`` picks one. JSON: one question's analysis is one object; several are
``{"questions": {KEY: analysis, ...}}``. Undefined numbers are null with their reason beside
them, every number at full precision."""
from __future__ import annotations

import argparse
import math
import sys
import textwrap
from pathlib import Path

from studies.report import dumps, num_text, p_text
from studies.scheffe import (
    RUN_SCALE,
    ScheffeResult,
    parse_scale,
    ratings_array,
    read_questions,
    read_ratings,
    scale_text,
    scheffe_nakaya,
)
from studies.side_checks import DESIGN_NOTE, SideEffect, warnings as side_warnings

LEGACY_NOTE = ("written before `study run` asked two questions per trial (no question column): its one question "
               "is analysed as it was")


def _scale(text: str) -> tuple[float, float]:
    try:
        return parse_scale(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def configure(p: argparse.ArgumentParser) -> None:
    p.description = ("Scheffé's paired comparison (Nakaya's modification) of a study's ratings: the ANOVA table, the "
                     "scale values, the yardsticks at p < .05 and .01 and letter groups, per question. An F or a "
                     "yardstick over an error term of 0 is undefined and said to be (null in JSON), never infinite. "
                     "Beside the analysis: the side effect (a preference for the first-shown, left, one, which "
                     "Nakaya's model has no term for) and participants who chose one side every time, as warnings.")
    p.add_argument("ratings", type=Path, help="CSV: participant,first,second,score")
    p.add_argument("--image", metavar="NAME", help="ratings with an image column (`study run` writes one): this "
                   "image's only (default: every image, each participant on each image one judge)")
    p.add_argument("--question", metavar="KEY", help="a file of several questions (`study run` asks two): this "
                   "question only (default: each question, one analysis each)")
    p.add_argument("--scale", type=_scale, default=RUN_SCALE, metavar="MIN..MAX",
                   help=f"the rating scale (default {scale_text(RUN_SCALE)}, what `study run` records; e.g. -3..3): "
                        f"a score outside it, or a fraction, is refused naming its row")
    p.add_argument("--continuous", action="store_true", help="the scale is continuous: fractions are scores too")
    p.add_argument("--chart", type=Path, metavar="SVG", help="write the scale values as a bar chart here (one "
                   "question: this file; several: one per question, e.g. c.svg gives c.intrinsic.svg and c.projected.svg)")
    p.add_argument("--json", action="store_true", help="print JSON for scripts")


def _chart_path(chart: Path, key: str | None, several: bool) -> Path:
    return chart.with_name(f"{chart.stem}.{key}{chart.suffix}") if several and key else chart


def _analysis_doc(res: ScheffeResult, side: SideEffect, warns: list[str], note: str) -> dict:
    items = res.items
    return {
        "items": list(items), "participants": len(res.participants),
        "scale": {k: float(v) for k, v in zip(items, res.scale)},
        "anova": [{"source": r.source, "ss": r.ss, "df": r.df, "ms": r.ms, "f": r.f, "p": r.p,
                   **({"undefined": r.undefined} if r.undefined else {})} for r in res.anova],
        "yardstick": {f"{k:g}": v for k, v in res.yardstick.items()},
        "letters": {f"{k:g}": dict(zip(items, v)) for k, v in res.letters.items()},
        **({"undefined": res.undefined} if res.undefined else {}),
        "side_effect": {"estimate": side.estimate, "t": side.t, "df": side.df, "p": side.p,
                        "pairs_both_ways": side.pairs_both_ways, "pairs": side.pairs,
                        **({"undefined": side.undefined} if side.undefined else {}), "about": DESIGN_NOTE},
        "warnings": warns,
        **({"note": note} if note else {}),
    }


def _print_table(res: ScheffeResult, side: SideEffect, warns: list[str]) -> None:
    items = res.items
    print(f"{len(items)} configurations, {len(res.participants)} judges\n")
    print(f"{'source':<24}{'SS':>10}{'df':>6}{'MS':>10}{'F':>9}{'p':>10}")
    for r in res.anova:
        f = "-" if r.undefined else ("" if math.isnan(r.f) else f"{r.f:.2f}")
        pv = "-" if r.undefined else ("" if math.isnan(r.p) else p_text(r.p))
        ms = "" if math.isnan(r.ms) else f"{r.ms:.3f}"
        print(f"{r.source:<24}{r.ss:>10.3f}{r.df:>6}{ms:>10}{f:>9}{pv:>10}")
    for r in res.anova:
        if r.undefined:
            print(f"  {r.source}: F and p undefined: {r.undefined}")
    print()
    print(f"{'configuration':<16}{'scale':>8}  groups .05  .01")
    for k in sorted(range(len(items)), key=lambda k: -res.scale[k]):
        g05, g01 = (res.letters[lv][k] if lv in res.letters else "-" for lv in (0.05, 0.01))
        print(f"{items[k]:<16}{res.scale[k]:>8.3f}  {g05:<10} {g01}")
    if res.undefined:
        print(f"\nyardsticks undefined: {res.undefined}")
    else:
        print(f"\nyardstick Y(.05) = {num_text(res.yardstick[0.05])}, Y(.01) = {num_text(res.yardstick[0.01])}")
    if side.undefined:
        print(f"side effect: undefined: {side.undefined}")
    else:
        print(f"side effect (toward the first-shown one): {side.estimate:+.3f} scale steps, t = {side.t:.2f}, "
              f"df = {side.df}, p = {p_text(side.p)} ({side.pairs_both_ways} of {side.pairs} pairs shown both ways)")
    print(textwrap.fill(f"({DESIGN_NOTE})", 100, initial_indent="  ", subsequent_indent="   "))
    for w in warns:
        print(f"warning: {w}")


def _report(args: argparse.Namespace) -> int:
    questions, legacy = read_questions(args.ratings)
    if args.question is not None:
        if not questions:
            raise ValueError(f"{args.ratings}: no question column (one question per trial): leave out --question")
        if args.question not in questions:
            raise ValueError(f"{args.ratings}: no answers to question {args.question!r} (questions: "
                             f"{', '.join(questions)})")
        keys: tuple[str | None, ...] = (args.question,)
    else:
        keys = questions or (None,)
    note = LEGACY_NOTE if legacy else ""
    shown = "left" if legacy or questions else "first-shown"
    docs, several = {}, len(keys) > 1
    for key in keys:
        read = dict(question=key, scale=args.scale, continuous=args.continuous)
        x, items, people = ratings_array(read_ratings(args.ratings, image=args.image, **read))
        res = scheffe_nakaya(x, items, people)
        side, warns = side_warnings(read_ratings(args.ratings, image=args.image, judge_per_image=False, **read),
                                    shown=shown)
        if args.chart:
            title = f"Scale values ({args.ratings.name}{', ' + key if key else ''})"
            _chart_path(args.chart, key, several).write_text(_chart(res, title))
        if args.json:
            docs[key] = {**({"question": key} if key else {}), **_analysis_doc(res, side, warns, note)}
            continue
        if key:
            print(f"{'' if key == keys[0] else chr(10)}question {key}:")
        if note:
            print(f"note: {args.ratings} {note}")
        _print_table(res, side, warns)
        if args.chart:
            print(f"chart: {_chart_path(args.chart, key, several)}")
    if args.json:
        print(dumps({"questions": docs} if several else next(iter(docs.values()))))
    return 0


def _chart(res: ScheffeResult, title: str) -> str:
    from studies.chart import scale_chart_svg

    return scale_chart_svg(res, title=title)


def run(args: argparse.Namespace) -> int:
    try:
        return _report(args)
    except ValueError as exc:       # a file that is not a study's ratings: one line, status 2
        print(f"shadowless study scheffe: {exc}", file=sys.stderr)
        return 2
