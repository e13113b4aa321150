"""`shadowless study run SCHEDULE.csv --rig-dir RIG --participant K`: one participant's trials on the rig."""
from __future__ import annotations

import argparse
import asyncio
import re
import sys
from pathlib import Path

from rigctl.client import OperatorError, add_connection_args
from rigctl.commands import read_image
from coordinator.errors import RigError
from coordinator.rig import parse_config
from rigctl.rig_target import open_client
from coordinator.schema import read_text
from studies.configurations import load_configurations
from studies.ratings_log import RatingsLog
from studies.runner import QUESTIONS, RunSettings, run_trials
from studies.schedule import read_schedule
from protos import auth, cli_types

EPILOG = """\
each trial: the picture on both halves of the table, the left half lit by the left configuration's
projectors, the right half by the right one's (a projector in both lights both, one in neither is
dark). Each trial asks every question in turn (default: the paper's two, below); the operator
reads it out and types the participant's answer and Enter:
  -2 clearly left   -1 slightly left   0 equal   1 slightly right   2 clearly right
  r  show the trial again (same question)   q  stop (the same command resumes where it stopped)
Each answer is on disk (appended, fsync) before the next is asked: RATINGS gets
participant,first,second,score,image,trial,answer,question with first = left, second = right,
score = -answer and the question's key, what `shadowless study scheffe RATINGS` reads (one
analysis per question).

default questions (--question KEY=TEXT, repeated, replaces them):
{questions}

left and right are the participant's at the table's near edge (the content's bottom row); one
standing at the far edge needs --mirror.

examples:
  shadowless study run schedule.csv --rig-dir rig --participant 3 --ratings q1.csv
  shadowless study run schedule.csv --rig-dir rig --participant 3 --surround 0.15 \\
      --question "sop=Which side looks more like a pattern of the surface itself?" --ratings sop.csv"""


def configure(p: argparse.ArgumentParser) -> None:
    p.description = ("Run one participant's trials of a schedule (from `shadowless study schedule`) on the rig: "
                     "each pair of configurations side by side on the two halves of the table, the answer typed at "
                     "this terminal and appended to the ratings file at once.")
    p.epilog = EPILOG.format(questions="\n".join(f"  {key:<8}{text}" for key, text in QUESTIONS))
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("schedule", type=cli_types.existing_file, help="the schedule CSV")
    p.add_argument("--participant", type=cli_types.int_range(1), required=True, metavar="K", help="whose trials")
    p.add_argument("--ratings", type=Path, default=Path("ratings.csv"), metavar="CSV",
                   help="append the answers here (default ./ratings.csv; created with its header)")
    p.add_argument("--configurations", type=cli_types.existing_file, metavar="TOML",
                   help="the configurations file (default: the 5x5 rig's P1, P9D, P9W, P13, P17, P20, P25)")
    p.add_argument("--image-dir", type=cli_types.existing_dir, metavar="DIR",
                   help="where the schedule's images are (default: as named, else beside the schedule)")
    p.add_argument("--question", type=_question, action="append", metavar="KEY=TEXT",
                   help="a question each trial asks: its key (a word, stored with each answer) and its words; "
                        "repeat for several (default: the two below)")
    p.add_argument("--surround", type=cli_types.number(0, 1), default=0.0, metavar="LEVEL",
                   help="level around the picture on each half, 0..1 (default 0: black)")
    p.add_argument("--margin", type=cli_types.number(0, 0.45), default=0.05, metavar="FRACTION",
                   help="free border around each picture, a fraction of its half (default 0.05)")
    p.add_argument("--gap", type=cli_types.number(0, 60), default=1.0, metavar="SECONDS",
                   help="black between trials and before a repeat (default 1)")
    p.add_argument("--mirror", action="store_true", help="the participant stands at the far edge of the table")
    add_connection_args(p)


def _question(text: str) -> tuple[str, str]:
    key, sep, words = text.partition("=")
    key = key.strip()
    if not sep or not re.fullmatch(r"[A-Za-z][A-Za-z0-9_-]*", key) or not words.strip():
        raise argparse.ArgumentTypeError(f"{text!r} is not KEY=TEXT with KEY a word, e.g. "
                                         f"\"projected=Which side looks more like a projected pattern?\"")
    return key, words.strip()


def _image_loader(args: argparse.Namespace):
    def load(name: str):
        for p in ([args.image_dir / name] if args.image_dir else [Path(name), args.schedule.parent / name]):
            if p.is_file():
                return read_image(str(p))
        where = args.image_dir or f"this folder or {args.schedule.parent}"
        raise OperatorError(f"image {name!r} of the schedule is not in {where} (see --image-dir)")
    return load


async def _run(args: argparse.Namespace) -> int:
    questions = tuple(args.question or QUESTIONS)
    if len({key for key, _ in questions}) != len(questions):
        raise OperatorError("each --question needs a key of its own")
    if not args.rig_dir:
        raise OperatorError("--rig-dir is needed: the rig's content size places the two halves")
    try:
        cfg = parse_config(read_text(Path(args.rig_dir) / "rig.toml"), source=str(Path(args.rig_dir) / "rig.toml"))
        configs = load_configurations(args.configurations)
        trials = [t for t in read_schedule(args.schedule) if t.participant == args.participant]
        log = RatingsLog(args.ratings)
    except (RigError, ValueError) as exc:
        raise OperatorError(str(exc)) from None
    if not trials:
        raise OperatorError(f"{args.schedule} has no trials of participant {args.participant}")
    unknown = sorted({c for t in trials for c in (t.left, t.right)} - configs.keys())
    if unknown:
        raise OperatorError(f"the schedule names configuration(s) {', '.join(unknown)}, which "
                            f"{args.configurations or 'the default configurations file'} does not define")
    absent = sorted({s for t in trials for c in (t.left, t.right) for s in configs[c]} - set(cfg.slots))
    if absent:
        more = f" and {len(absent) - 8} more" if len(absent) > 8 else ""
        raise OperatorError(f"configuration slot(s) {', '.join(absent[:8])}{more} are not slots of rig {cfg.name!r} "
                            f"(slots: {', '.join(cfg.slots)}); give --configurations for this rig")
    if log.repaired:
        print(f"{log.path}: cut off a torn last line ({log.repaired} bytes); its trial is asked again", file=sys.stderr)
    load = _image_loader(args)
    for name in sorted({t.image for t in trials}):     # every picture found before the first trial
        load(name)
    settings = RunSettings((cfg.content_width, cfg.content_height), margin=args.margin, surround=args.surround,
                           mirror=args.mirror, gap_s=args.gap, questions=questions)
    async with await open_client(args) as c:
        await run_trials(c, sorted(trials, key=lambda t: t.trial), log, configs, settings, load=load, ask=input)
    return 0


def run(args: argparse.Namespace) -> int:
    try:
        return asyncio.run(_run(args))
    except (OperatorError, auth.TokenError) as exc:     # a refused call too (CallRefused)
        raise SystemExit(f"shadowless study run: {exc}") from None
