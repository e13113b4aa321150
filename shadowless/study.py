"""`shadowless study ANALYSIS`: the perception studies' analyses and the virtual room's studies, one command.

The statistical analyses (``scheffe``, ``paired``) belong to the coordinator
(:mod:`coordinator.study.cli`, which registers them itself); the studies that read
the virtual room's ground truth belong to ``sim`` (which the coordinator may not
import). This wiring offers both: the coordinator's subcommands as they are, and
one line of :data:`ANALYSES` per room study, whose module has ``configure(parser)``
and ``run(args) -> int`` like every command.
"""
from __future__ import annotations

import argparse
import importlib

from coordinator.study import cli as coordinator_study

#: room studies: subcommand -> (module with configure(parser) and run(args), one-line summary)
ANALYSES: dict[str, tuple[str, str]] = {
    "motion": ("sim.motion_cli", "a hand moving over the table: the synthetic aperture's light drop per frame against a reactive system with latency"),
}


def _subcommands(p: argparse.ArgumentParser) -> argparse._SubParsersAction:
    return next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))


def configure(p: argparse.ArgumentParser) -> None:
    coordinator_study.configure(p)
    sub = _subcommands(p)
    for name, (module, summary) in ANALYSES.items():
        sp = sub.add_parser(name, help=summary, description=summary, formatter_class=argparse.RawDescriptionHelpFormatter)
        mod = importlib.import_module(module)
        mod.configure(sp)
        sp.set_defaults(_analysis=mod)
    p.description += "".join(f"\n  {name:<21} {summary}" for name, (_, summary) in ANALYSES.items())
    p.epilog += "".join(f"\n  shadowless study {name} --help" for name in ANALYSES)


def run(args: argparse.Namespace) -> int:
    mod = getattr(args, "_analysis", None)
    if mod is None:
        return coordinator_study.run(args)
    return int(mod.run(args) or 0)
