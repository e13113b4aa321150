"""`shadowless study schedule`: write a balanced, randomized pair schedule for a perception study."""
from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from studies.configurations import load_configurations
from studies.schedule import DESIGNS, make_schedule, write_schedule
from protos import cli_types

EPILOG = """\
designs:
  nakaya    every participant judges every unordered pair once per image (what `study scheffe`
            analyses). Sides are balanced within a participant (each configuration on the left
            about half of its trials) and across participants (couples see each pair both ways)
  ordered   every ordered pair: each pair both ways round for every participant, twice the trials
            (Scheffé's original design; `study scheffe` analyses Nakaya's design only)

examples:
  shadowless study schedule --participants 17 --images parrot.png,splash.png,wood.png -o schedule.csv
  shadowless study schedule --participants 4 --images card.png --only P1,P9D,P25 --blocked --seed 7 -o s.csv
then, for each participant K: shadowless study run schedule.csv --rig-dir RIG --participant K"""


def configure(p: argparse.ArgumentParser) -> None:
    p.description = ("Write a study's schedule as CSV (participant, trial, image, left, right): for P participants, "
                     "every pair of configurations on every image, each participant's trials in a random order, the "
                     "sides counterbalanced.")
    p.epilog = EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("--participants", type=cli_types.int_range(1, 10_000), required=True, metavar="P",
                   help="how many participants (numbered 1 .. P)")
    p.add_argument("--images", type=cli_types.names, required=True, metavar="A,B,C",
                   help="the pictures shown, joined by commas (file names, as `study run` will find them)")
    p.add_argument("--configurations", type=cli_types.existing_file, metavar="TOML",
                   help="the configurations file (default: the 5x5 rig's P1, P9D, P9W, P13, P17, P20, P25)")
    p.add_argument("--only", type=cli_types.names, metavar="A,B,C", help="compare these configurations only")
    p.add_argument("--design", choices=DESIGNS, default="nakaya", help="see below (default nakaya)")
    p.add_argument("--blocked", action="store_true",
                   help="one image after another (their order rotated per participant) instead of all mixed")
    p.add_argument("--seed", type=cli_types.int_range(0, 2**63 - 1), metavar="N",
                   help="random seed (default: a fresh one, printed, so the schedule can be made again)")
    p.add_argument("-o", "--out", type=Path, required=True, metavar="CSV", help="where to write the schedule")


def run(args: argparse.Namespace) -> int:
    try:
        configs = load_configurations(args.configurations)
    except ValueError as exc:
        raise SystemExit(f"shadowless study schedule: {exc}") from None
    names = list(configs)
    if args.only:
        unknown = [n for n in args.only if n not in configs]
        if unknown:
            raise SystemExit(f"shadowless study schedule: --only: no configuration {', '.join(unknown)} "
                             f"(configurations: {', '.join(configs)})")
        names = list(dict.fromkeys(args.only))
    if not args.out.parent.is_dir():
        raise SystemExit(f"shadowless study schedule: --out {args.out}: no such folder {args.out.parent}")
    seed = args.seed if args.seed is not None else int(np.random.SeedSequence().entropy % 2**63)
    try:
        trials = make_schedule(args.participants, names, args.images, design=args.design, blocked=args.blocked,
                               seed=seed)
    except ValueError as exc:
        raise SystemExit(f"shadowless study schedule: {exc}") from None
    write_schedule(args.out, trials)
    per = Counter(t.participant for t in trials)[1]
    print(f"{args.out}: {args.participants} participant(s) x {per} trials ({len(names)} configurations, "
          f"{len(args.images)} image(s), design {args.design}, seed {seed})", file=sys.stderr)
    return 0
