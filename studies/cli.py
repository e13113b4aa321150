"""`shadowless study ANALYSIS`: every study's subcommand, registered from one table.

Each line of :data:`STUDIES` names a subcommand, the module that implements it (with
``configure(parser)`` and ``run(args) -> int``, like every command) and its one-line summary. A
subcommand's module is imported only when that subcommand is the one given: argparse hands a
subcommand's words to that subcommand's parser alone, and that parser fills itself in from its
module when it first parses. So the statistical analyses start without loading the virtual room
(the room, OpenCV and SciPy take about a second to import), and ``shadowless study --help`` loads
no study at all.

A caller may register more subcommands by passing its own table to :func:`configure` (the
command-line wiring adds the planner's ``pointwise`` analysis, which this package may not import).
"""
from __future__ import annotations

import argparse
import importlib
import re
import sys

#: subcommand -> (module with configure(parser) and run(args), one-line summary); the order of --help
STUDIES: dict[str, tuple[str, str]] = {
    "scheffe": ("studies.scheffe_cli", "Scheffé's paired comparison (Nakaya's modification)"),
    "paired": ("studies.paired_cli", "paired test of task times (log scale) or accuracies"),
    "schedule": ("studies.schedule_cli", "a balanced, randomized pair schedule for P participants (CSV)"),
    "run": ("studies.run_cli", "one participant's trials on the rig, side by side; answers appended to RATINGS"),
    "search": ("studies.search_cli", "the search task (study 1): one participant's trials on the rig, timed on the "
                                     "rig clock"),
    "motion": ("sim.motion_cli", "a hand moving over the table: light drop per frame, synthetic aperture vs reactive "
                                 "compensation"),
    "proxies": ("studies.proxies_cli", "geometric proxies of the sense of projection per layout, against the paper's "
                                       "orderings"),
}

#: what `study --help` says of a subcommand beyond its summary; the others get their summary on one line
DETAILS: dict[str, str] = {
    "scheffe": (
        "  scheffe RATINGS.csv   Scheffé's paired comparison, Nakaya's modification: columns\n"
        "                        participant,first,second,score (every participant rates every pair\n"
        "                        once; score > 0 prefers first; scale -2..2 unless --scale). Prints the\n"
        "                        ANOVA table, the scale values, the yardsticks at p < .05 and .01,\n"
        "                        letter groups and warnings of a side preference. With an image column\n"
        "                        (`study run` writes one) each participant on each image is one judge;\n"
        "                        with a question column, one analysis per question."),
    "paired": (
        "  paired FILE.csv       one measure in two conditions: participant,condition and time_s or\n"
        "                        accuracy. Differences second - first: a paired t test (with Cohen's\n"
        "                        d_z) or Wilcoxon's signed-rank test (with r), chosen by Shapiro-Wilk\n"
        "                        for times (on their log), Wilcoxon for accuracies (zeros welcome);\n"
        "                        --measure picks one in a file with both (`study search` writes both)."),
}

#: examples for the subcommands with DETAILS; the others point to their own --help
EXAMPLES = ("  shadowless study scheffe study2.csv --chart sop.svg\n"
            "  shadowless study scheffe sato.csv --scale -3..3 --json\n"
            "  shadowless study paired study1.csv --json\n"
            "  shadowless study paired search.csv --measure accuracy")


def _loading_parser(base: type[argparse.ArgumentParser]) -> type[argparse.ArgumentParser]:
    """A parser class derived from the command's own (so a mistake costs the same one line) whose
    parsers configure themselves from their study's module when they first parse."""

    class StudyParser(base):
        def __init__(self, *args, study_module: str, **kwargs):
            super().__init__(*args, **kwargs)
            self.study_module = study_module
            self.study_loaded = False

        def add_argument(self, *args, **kwargs):
            action = super().add_argument(*args, **kwargs)
            if kwargs.get("metavar") == "MIN..MAX":      # see _join_ranges
                self.range_options = getattr(self, "range_options", set()) | set(action.option_strings)
            return action

        def parse_known_args(self, args=None, namespace=None):
            if not self.study_loaded:
                self.study_loaded = True
                module = importlib.import_module(self.study_module)
                module.configure(self)
                self.set_defaults(study=module)
            return super().parse_known_args(_join_ranges(self, sys.argv[1:] if args is None else args), namespace)

    return StudyParser


_RANGE = re.compile(r"^-\d[\d.]*\.\.-?\d")


def _join_ranges(parser: argparse.ArgumentParser, args: list[str]) -> list[str]:
    """``--scale -3..3`` as ``--scale=-3..3``: argparse takes a word that starts with a dash and is
    not a plain number for an option, so a range with a negative MIN would need the ``=``."""
    options = getattr(parser, "range_options", set())
    out = list(args)
    k = 0
    while k < len(out) - 1:
        if out[k] in options and _RANGE.match(out[k + 1]):
            out[k:k + 2] = [f"{out[k]}={out[k + 1]}"]
        k += 1
    return out


def configure(p: argparse.ArgumentParser, studies: dict[str, tuple[str, str]] = STUDIES) -> None:
    """Add one subcommand per line of ``studies`` to the `study` command's parser ``p``."""
    p.description = "Analyse a perception study.\n\n" + "\n".join(
        DETAILS.get(name) or f"  {name:<21} {summary}" for name, (_, summary) in studies.items())
    p.epilog = "examples:\n" + EXAMPLES + "".join(
        f"\n  shadowless study {name} --help" for name in studies if name not in DETAILS)
    sub = p.add_subparsers(dest="analysis", metavar="ANALYSIS", required=True, parser_class=_loading_parser(type(p)))
    for name, (module, summary) in studies.items():
        sub.add_parser(name, help=summary, study_module=module)


def run(args: argparse.Namespace) -> int:
    return int(args.study.run(args) or 0)
