"""The one `shadowless` command. Subcommands live in the package that owns them
and are imported only when used, so an edge node that installed only
``shadowless[node]`` can run ``shadowless node`` without the coordinator's stack.

Each subcommand module exposes ``configure(parser)`` and ``run(args) -> int``.
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys

from protos.logging_setup import add_verbosity_args, level_from_args, setup
from shadowless import __version__

#: commands that run for long and say what they do at INFO by default (the others: warnings only)
INFO_BY_DEFAULT = {"coordinator", "node"}

#: name -> (module, one-line summary). Order is the order of `--help`.
COMMANDS: dict[str, tuple[str, str]] = {
    "coordinator": ("coordinator.cli", "run the coordinator: holds the rig, serves nodes and operators"),
    "node": ("node.cli", "run one node (one per projector, on its edge computer)"),
    "rig": ("shadowless.rig", "create or inspect a rig directory (slots, token; or from a planned layout)"),
    "status": ("rigctl.commands", "show the rig's nodes and sync figures (--json for scripts)"),
    "show": ("rigctl.commands", "show an image on every projector"),
    "play": ("rigctl.commands", "play a sequence of images, or a generated test sequence"),
    "stop": ("rigctl.commands", "stop what plays: the rig's content (or black) comes back"),
    "blackout": ("rigctl.commands", "black on every projector until the next show"),
    "configure": ("rigctl.commands", "set a slot's pose, LUT, gain or output size by hand"),
    "pattern": ("rigctl.slot_cli", "a test pattern (white, grid, crosshair, colour bars) on some projectors"),
    "solo": ("rigctl.slot_cli", "only some projectors keep the picture, the others black (--end ends it)"),
    "content": ("rigctl.content_commands", "add, list, remove and verify content assets (stills, sequences, videos)"),
    "cue": ("rigctl.cue_cli", "the show's cue list: add, list, move; GO, back, jump (crossfades, auto-follow)"),
    "local": ("shadowless.local", "run a coordinator and N nodes on this machine (offscreen) and report sync"),
    "swarm": ("shadowless.swarm", "load-test a coordinator: N protocol-level nodes in one process (no rendering)"),
    "calibrate": ("rigctl.calibration_cli", "calibrate the projectors with the camera (poses pushed to the nodes)"),
    "alignment": ("rigctl.calibration_cli", "measure each projector's residual misalignment; heat map over the table"),
    "coverage": ("rigctl.coverage_cli", "how many projectors reach each point of the object (from the poses and mesh); heat map"),
    "response": ("rigctl.compensation_cli", "measure each projector's luminance response; LUTs, brightness match"),
    "transport": ("rigctl.compensation_cli", "measure the rig's light transport (dot grids, all projectors at once)"),
    "compensate": ("rigctl.compensation_cli", "compensate the rig's blur for an image (shown) or a video (a new 16-bit asset)"),
    "blend": ("rigctl.blend_cli", "blend the rig: per-pixel gain and black maps so every projector's light adds up evenly"),
    "room": ("sim.cli", "run the virtual room (simulated projectors, camera, table, hands)"),
    "demo": ("shadowless.demo", "the whole rig in the virtual room: what `make demo` runs"),
    "study": ("shadowless.study", "studies: Scheffé paired comparison, paired task times; in the room: a moving hand (motion), "
                                  "shadow proxies of the layouts (proxies, pointwise)"),
    "plan": ("shadowless.placement", "choose projector positions that keep a hand's shadow least visible (layout, picture, curve); --placement: where to put the object"),
    "bench": ("bench.cli", "benchmarks that print JSON (sync, venue, room, calibration, compensation, node, console, motion, plan, …)"),
}

EPILOG = """\
a rig in three steps:
  shadowless rig init rigs/table --grid 5x5 --resolution 1920x1080
  shadowless coordinator --rig rigs/table               # on the coordinator machine
  shadowless node --slot r0c0 --token-file /etc/shadowless/token   # on each edge computer

try it on one machine:
  shadowless local --nodes 4          # coordinator + 4 offscreen nodes, prints sync figures
  shadowless demo                     # the full virtual room (what `make demo` runs)

`shadowless COMMAND --help` explains each command; -v/-q (any command) say more or less.
shell completion (bash, zsh): eval "$(register-python-argcomplete shadowless)"
"""


class Parser(argparse.ArgumentParser):
    """argparse's parser whose mistakes cost one line (not the usage block) and exit status 2.
    Every subcommand's parser is one too (argparse makes subparsers of the parent's class), and
    each keeps the actions that hold its subcommands' parsers (:attr:`subcommand_actions`)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.subcommand_actions: list[argparse.Action] = []

    def add_subparsers(self, **kwargs):
        action = super().add_subparsers(**kwargs)
        self.subcommand_actions.append(action)
        return action

    def error(self, message: str):
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    parser = Parser(
        prog="shadowless",
        description="Shadowless projection mapping with a synthetic-aperture projector rig.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"shadowless {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, summary) in COMMANDS.items():
        p = sub.add_parser(name, help=summary, description=summary, formatter_class=argparse.RawDescriptionHelpFormatter)
        if name == command:
            log_default = "info" if name in INFO_BY_DEFAULT else "warning"
            add_verbosity_args(p, default=log_default)
            try:
                mod = importlib.import_module(module)
            except ImportError as exc:
                raise SystemExit(
                    f"shadowless {name}: this install lacks what it needs ({exc.name or exc}); "
                    f"install the matching extra, e.g. pip install 'shadowless[all]'"
                ) from exc
            configure = getattr(mod, "configure_" + name, None) or mod.configure
            configure(p)
            _verbosity_everywhere(p, log_default)
            p.set_defaults(_module=mod)
            parser.command_parser = p
    return parser


def _verbosity_everywhere(p: argparse.ArgumentParser, default: str, seen: set[int] | None = None) -> None:
    """-v/-q/--log-level also after a sub-action (``shadowless content list -v``), once per parser
    (a parser with aliases is a choice under several names); ``default``, the command's log level,
    is what their help names (``shadowless rig board --help``)."""
    seen = set() if seen is None else seen
    for action in getattr(p, "subcommand_actions", ()):
        for sp in action.choices.values():
            if id(sp) not in seen:
                seen.add(id(sp))
                add_verbosity_args(sp, default, nested=True)
                _verbosity_everywhere(sp, default, seen)


def _command_of(words: list[str]) -> str | None:
    return next((a for a in words if not a.startswith("-")), None)


def _complete() -> None:
    """Shell completion (argcomplete): only when the shell asks (``$_ARGCOMPLETE``); exits."""
    import shlex

    import argcomplete

    try:
        words = shlex.split(os.environ.get("COMP_LINE", ""))[1:]
    except ValueError:
        words = []
    command = _command_of(words)
    argcomplete.autocomplete(build_parser(command if command in COMMANDS else None))


class ReaderGone(BaseException):
    """stdout's reader has gone. Not an OSError, so that no command's ``except OSError`` (a file it
    could not write, say) takes it for its own failure and prints one: it ends the command."""


class _Stdout:
    """sys.stdout for one command: a write or flush into a pipe whose reader has gone points the
    file at /dev/null (so the interpreter's last flush cannot fail again) and raises ReaderGone."""

    def __init__(self, stream):
        self._stream = stream

    def _gone(self) -> ReaderGone:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, self._stream.fileno())
        os.close(devnull)
        return ReaderGone()

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            raise self._gone() from None

    def flush(self) -> None:
        try:
            self._stream.flush()
        except BrokenPipeError:
            raise self._gone() from None

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


#: OpenBLAS's worker threads spin-wait 2**N CPU cycles for more work before they sleep. Its default
#: (N=28: about 0.1 s of a core) is paid by every process that imports NumPy, right at the import, and
#: again after each BLAS call that used the threads: a coordinator restarted in a show took it from the
#: nodes sharing its cores, and the test suite from its hundreds of processes. N=4 lets them sleep at
#: once; BLAS still runs on every core (a job's large products wake the threads), the results are the same.
BLAS_ENV = {"OPENBLAS_THREAD_TIMEOUT": "4"}


def main(argv: list[str] | None = None) -> int:
    """Run one command; its exit status. Output into a pipe whose reader has gone (``shadowless
    status | head -1``) ends the command quietly, as Python's documentation advises (its "Note on
    SIGPIPE"): stdout is pointed at /dev/null so the interpreter's last flush cannot fail again,
    and the exit status is 1, with nothing on stderr. This holds for every command, also one that
    catches OSError around its printing: the failed write raises :class:`ReaderGone` instead."""
    for name, value in BLAS_ENV.items():     # before the command imports NumPy; the children inherit it
        os.environ.setdefault(name, value)
    real = sys.stdout
    sys.stdout = _Stdout(real) if real is not None and not isinstance(real, _Stdout) else real
    try:
        code = _main(argv)
        sys.stdout.flush()        # what is still buffered fails here, not in the interpreter's exit
        return code
    except (ReaderGone, BrokenPipeError):
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, real.fileno())
            os.close(devnull)
        except (OSError, ValueError):
            pass
        return 1
    finally:
        sys.stdout = real


def _main(argv: list[str] | None) -> int:
    if "_ARGCOMPLETE" in os.environ:
        _complete()
    argv = list(sys.argv[1:] if argv is None else argv)
    command = _command_of(argv)
    parser = build_parser(command if command in COMMANDS else None)
    args, extra = parser.parse_known_args(argv)
    if extra:
        getattr(parser, "command_parser", parser).error(f"unrecognized arguments: {' '.join(extra)}")
    if not args.command:
        parser.print_help()
        return 2
    mod = args._module
    log_name = getattr(mod, "log_name", None)
    setup(level_from_args(args), name=log_name(args) if log_name else args.command)
    run = getattr(mod, "run_" + args.command, None) or mod.run
    try:
        return int(run(args) or 0)
    except SystemExit as exc:
        if isinstance(exc.code, str):      # a command's refusal of what it was given: one line, status 2
            print(exc.code if exc.code.startswith("shadowless") else f"shadowless {args.command}: {exc.code}",
                  file=sys.stderr)
            return 2
        raise
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
