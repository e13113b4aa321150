"""`shadowless study ANALYSIS`: the perception studies' analyses and the virtual room's studies, one command.

The statistical analyses (``scheffe``, ``paired``) belong to the coordinator
(:mod:`studies.cli`, which registers them itself); the studies that read
the virtual room's ground truth belong to ``sim`` (which the coordinator may not
import). This wiring offers both: the coordinator's subcommands as they are, and
one line of :data:`ANALYSES` per room study, whose module has ``configure(parser)``
and ``run(args) -> int`` like every command.

A room study's module (the room, OpenCV, SciPy: about a second to import) is
imported only when its subcommand is the one given, so the statistical analyses
start as fast as before.
"""
from __future__ import annotations

import argparse
import importlib

from studies import cli as coordinator_study

#: room studies: subcommand -> (module with configure(parser) and run(args), one-line summary)
ANALYSES: dict[str, tuple[str, str]] = {
    "schedule": ("studies.schedule_cli", "a balanced, randomized pair schedule for P participants (CSV)"),
    "run": ("studies.run_cli", "one participant's trials on the rig, side by side; answers appended to RATINGS"),
    "motion": ("sim.motion_cli", "a hand moving over the table: light drop per frame, synthetic aperture vs reactive compensation"),
    "proxies": ("studies.proxies_cli", "geometric proxies of the sense of projection per layout, against the paper's orderings"),
    "pointwise": ("planner.pointwise_cli", "whether any pointwise shadow proxy fits the paper's orderings and keeps few projectors behind 25"),
}


def _lazy(base: type[argparse.ArgumentParser], module: str) -> type[argparse.ArgumentParser]:
    """A parser class (of the command's own class, for its one-line errors) that configures
    itself from ``module`` when it first parses: argparse hands a subcommand's words to its parser."""

    class Lazy(base):
        def parse_known_args(self, args=None, namespace=None):
            if not getattr(self, "_study_configured", False):
                self._study_configured = True
                mod = importlib.import_module(module)
                mod.configure(self)
                self.set_defaults(_analysis=mod)
            return super().parse_known_args(args, namespace)

    return Lazy


def configure(p: argparse.ArgumentParser) -> None:
    coordinator_study.configure(p)
    sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
    base = sub._parser_class
    try:
        for name, (module, summary) in ANALYSES.items():
            sub._parser_class = _lazy(base, module)
            sub.add_parser(name, help=summary, description=summary, formatter_class=argparse.RawDescriptionHelpFormatter)
    finally:
        sub._parser_class = base
    p.description += "".join(f"\n  {name:<21} {summary}" for name, (_, summary) in ANALYSES.items())
    p.epilog += "".join(f"\n  shadowless study {name} --help" for name in ANALYSES)


def run(args: argparse.Namespace) -> int:
    mod = getattr(args, "_analysis", None)
    if mod is None:
        return coordinator_study.run(args)
    return int(mod.run(args) or 0)
