"""`shadowless study ANALYSIS`: the studies' subcommands (:mod:`studies.cli`) and the planner's
``pointwise`` analysis, one command.

The studies register their own subcommands from one table; the planner sits above the studies
(it plans with their proxies), so they may not name it. This wiring adds its line to their table.
"""
from __future__ import annotations

import argparse

from studies import cli as studies_cli

#: every subcommand of `shadowless study`: (module with configure(parser) and run(args), one-line summary)
ANALYSES: dict[str, tuple[str, str]] = {
    **studies_cli.STUDIES,
    "pointwise": ("planner.pointwise_cli", "whether any pointwise shadow proxy fits the paper's orderings and keeps "
                                           "few projectors behind 25"),
}


def configure(p: argparse.ArgumentParser) -> None:
    studies_cli.configure(p, ANALYSES)


def run(args: argparse.Namespace) -> int:
    return studies_cli.run(args)
