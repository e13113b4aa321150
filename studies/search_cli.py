"""`shadowless study search --rig-dir RIG --participant K`: the paper's first study on the rig."""
from __future__ import annotations

import argparse
import asyncio
import re
from pathlib import Path

from coordinator.errors import RigError
from coordinator.rig import parse_config
from coordinator.schema import read_text
from protos import auth, cli_types
from rigctl.client import OperatorError, add_connection_args
from rigctl.rig_target import open_client
from studies.configurations import load_configurations
from studies.search_log import SearchLog
from studies.search_runner import Keyboard, ScriptedParticipant, SearchSettings, run_search, search_schedule

EPILOG = """\
the task: ten A5 sheets lie on the table without overlapping; seven carry printed text, three
are blank and the rig projects text on them, grey everywhere else. The participant finds the
three projected sheets as fast as they can while staying accurate, walking round the table and
blocking light with their body but not touching the sheets.

each trial: black for --gap seconds, then the trial's content lit by the condition's projectors
only (the others black). Before it shows, the blank sheets' numbers are printed and the layout's
picture (sheets numbered 0-9 as seen from the participant's side, the projected ones marked P)
written to --pictures: lay the sheets out as it shows (printed sheets on the white places, blank
ones on the P places) and press Enter to show the trial. When the participant has chosen, type
their three numbers and Enter (e.g. "2 5 7"):
  r  show the trial again (its time starts again)   q  stop (the same command resumes)

timing is the rig clock's: from the instant the last of the condition's projectors reported the
trial's frame on screen to the instant the answer is entered. Each trial is on disk (appended,
fsync) before the next one: RESULTS gets participant,condition,trial,seed,time_s,accuracy,
chosen,projected,frame_id,onset_s,answer_s; analyse it with
  shadowless study paired RESULTS --measure time_s       (log times, paired t or Wilcoxon)
  shadowless study paired RESULTS --measure accuracy     (Wilcoxon, zero differences dropped)

a dry run: --participant scripted:SEED answers by itself after a time drawn per condition
(--scripted-times) and names a printed sheet instead of a projected one with --scripted-miss.
The room's table has no texture, so the printed sheets are not rendered in a dry run; they are
in the layout, and the scripted participant chooses among all ten.

examples:
  shadowless study search --rig-dir rig --participant 3 --results study1.csv --pictures layouts/
  shadowless study search --rig-dir rig --participant scripted:7 --conditions P1,P25 --trials 2 \\
      --scripted-times P1=6,P25=5 --gap 0 --results dry.csv"""


def configure(p: argparse.ArgumentParser) -> None:
    p.description = ("Run one participant's trials of the search task (the paper's first study) on the rig: find "
                     "the three sheets with projected text among ten, in each condition; time on the rig clock, "
                     "accuracy from the three sheet numbers typed at this terminal.")
    p.epilog = EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("--participant", type=_participant, required=True, metavar="K|scripted:SEED",
                   help="whose trials: a participant number, or scripted:SEED for a scripted dry run")
    p.add_argument("--conditions", type=_names, default=("P25", "P1"), metavar="A,B",
                   help="the configurations compared (default P25,P1: the 25 projectors and the single bright one; "
                        "their brightness must be matched on the rig)")
    p.add_argument("--configurations", type=cli_types.existing_file, metavar="TOML",
                   help="the configurations file (default: the 5x5 rig's, with P1 and P25)")
    p.add_argument("--trials", type=cli_types.int_range(1, 100), default=10, metavar="N",
                   help="trials per condition (default 10, the paper's)")
    p.add_argument("--order", type=cli_types.int_range(0), default=None, metavar="K",
                   help="which condition comes first, turned by K (default: the participant number, so "
                        "alternate participants alternate orders)")
    p.add_argument("--seed", type=cli_types.int_range(0), default=0, metavar="S",
                   help="the study's seed: layouts come from it and the participant (default 0)")
    p.add_argument("--results", type=Path, default=Path("search.csv"), metavar="CSV",
                   help="append each trial here (default ./search.csv; created with its header)")
    p.add_argument("--pictures", type=Path, metavar="DIR", help="write each trial's layout picture here (PNG)")
    p.add_argument("--table", type=_size, default=(1200.0, 800.0), metavar="W,D",
                   help="the table the content covers, width and depth in mm (default 1200,800)")
    p.add_argument("--grey", type=cli_types.number(0, 1), default=0.5, metavar="LEVEL",
                   help="the level projected around the sheets, 0..1 (default 0.5)")
    p.add_argument("--blur", type=cli_types.number(0, 20), default=0.7, metavar="PX",
                   help="blur of the projected text (a Gaussian's sigma in content pixels; default 0.7), to match "
                        "the printed sheets' sharpness")
    p.add_argument("--gap", type=cli_types.number(0, 60), default=1.0, metavar="SECONDS",
                   help="black before each trial (default 1)")
    p.add_argument("--scripted-times", type=_times, default=None, metavar="COND=S,...",
                   help="a scripted participant's median time per condition in seconds (default: 6 s in the "
                        "first condition, 8 s in the second)")
    p.add_argument("--scripted-miss", type=cli_types.number(0, 1), default=0.1, metavar="P",
                   help="the chance a scripted participant names a printed sheet for a projected one (default 0.1)")
    add_connection_args(p)


def _participant(text: str) -> str:
    if re.fullmatch(r"[1-9][0-9]*", text) or re.fullmatch(r"scripted:[0-9]+", text):
        return text
    raise argparse.ArgumentTypeError(f"{text!r} is not a participant number (1, 2, ...) or scripted:SEED")


def _names(text: str) -> tuple[str, ...]:
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if len(names) != 2 or names[0] == names[1]:
        raise argparse.ArgumentTypeError(f"{text!r} is not two configuration names A,B")
    return names


def _size(text: str) -> tuple[float, float]:
    try:
        w, d = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not W,D in mm, e.g. 1200,800") from None
    if not (100 <= w <= 20000 and 100 <= d <= 20000):
        raise argparse.ArgumentTypeError(f"{text!r}: width and depth are 100..20000 mm")
    return w, d


def _times(text: str) -> dict[str, float]:
    out = {}
    for part in text.split(","):
        name, sep, value = part.partition("=")
        try:
            v = float(value)
        except ValueError:
            v = -1.0
        if not sep or not name.strip() or not 0 < v <= 600:
            raise argparse.ArgumentTypeError(f"{part!r} is not COND=SECONDS with 0 < SECONDS <= 600, e.g. P1=8")
        out[name.strip()] = v
    return out


async def _run(args: argparse.Namespace) -> int:
    if not args.rig_dir:
        raise OperatorError("--rig-dir is needed: the rig's content size places the sheets")
    try:
        cfg = parse_config(read_text(Path(args.rig_dir) / "rig.toml"), source=str(Path(args.rig_dir) / "rig.toml"))
        configs = load_configurations(args.configurations)
    except (RigError, ValueError) as exc:
        raise OperatorError(str(exc)) from None
    unknown = [c for c in args.conditions if c not in configs]
    if unknown:
        raise OperatorError(f"condition(s) {', '.join(unknown)} are not in "
                            f"{args.configurations or 'the default configurations file'} "
                            f"(it has {', '.join(configs)})")
    absent = sorted({s for c in args.conditions for s in configs[c]} - set(cfg.slots))
    if absent:
        raise OperatorError(f"slot(s) {', '.join(absent[:8])} of the conditions are not slots of rig {cfg.name!r}; "
                            f"give --configurations for this rig")
    scripted = args.participant.startswith("scripted:")
    number = int(args.participant.split(":")[1]) if scripted else int(args.participant)
    if scripted:
        times = args.scripted_times or {args.conditions[0]: 6.0, args.conditions[1]: 8.0}
        missing = [c for c in args.conditions if c not in times]
        if missing:
            raise OperatorError(f"--scripted-times gives no time for {', '.join(missing)}")
        participant = ScriptedParticipant(number, times, miss=args.scripted_miss)
    else:
        participant = Keyboard()
    trials = search_schedule(args.participant, args.conditions, args.trials, seed=args.seed,
                             order=number if args.order is None else args.order)
    settings = SearchSettings((cfg.content_width, cfg.content_height), table_mm=args.table, grey=args.grey,
                              blur_px=args.blur, gap_s=args.gap, pictures=args.pictures)
    try:
        from studies.search_stimulus import make_layout
        make_layout(trials[0].seed, args.table)      # a table too small, said before anything is shown
    except ValueError as exc:
        raise OperatorError(str(exc)) from None
    try:
        log = SearchLog(args.results)
    except ValueError as exc:
        raise OperatorError(str(exc)) from None
    async with await open_client(args) as c:
        await run_search(c, trials, log, configs, settings, participant)
    return 0


def run(args: argparse.Namespace) -> int:
    try:
        return asyncio.run(_run(args))
    except (OperatorError, auth.TokenError, TimeoutError) as exc:    # TimeoutError: a frame never reported
        raise SystemExit(f"shadowless study search: {exc}") from None
