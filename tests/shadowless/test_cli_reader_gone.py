"""The entry point ends every command quietly when stdout's reader has gone, also a command that
catches OSError around its printing (a BrokenPipeError is one): the failed write is not an OSError
the command could take for its own failure, so it neither prints "[Errno 32] Broken pipe" nor gets
a traceback at the interpreter's exit. A real process into `head -1`."""
from __future__ import annotations

import subprocess
import sys

COMMAND = """
import sys, types
from shadowless import cli

def run(args):
    try:
        for i in range(200000):          # more than the pipe and head take
            print("line", i)
    except OSError as exc:               # what a command does around a file it writes
        print(f"shadowless careless: {exc}", file=sys.stderr)
        return 2
    return 0

mod = types.ModuleType("careless")
mod.configure, mod.run = (lambda p: None), run
sys.modules["careless"] = mod
cli.COMMANDS["careless"] = ("careless", "prints a lot and catches OSError")
sys.exit(cli.main(["careless"]))
"""


def test_a_command_catching_oserror_still_ends_quietly_into_head():
    first = subprocess.Popen([sys.executable, "-c", COMMAND], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    head = subprocess.Popen(["head", "-1"], stdin=first.stdout, stdout=subprocess.PIPE)
    first.stdout.close()
    out, _ = head.communicate(timeout=120)
    err = first.stderr.read().decode()
    first.stderr.close()
    assert out == b"line 0\n"
    assert first.wait(timeout=120) == 1 and err == "", err
