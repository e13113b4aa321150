"""``python -m bench.uniformity_profiled ARGS``: ``shadowless ARGS`` under cProfile, its profile written at exit
to ``$SHADOWLESS_PROFILE_DIR/<first arg>-<pid>.prof`` (a node stopped by SIGTERM exits normally).
:mod:`bench.uniformity_switch` starts the nodes' network sides this way."""
from __future__ import annotations

import atexit
import cProfile
import os
import sys
import time
from pathlib import Path


def main() -> int:
    from shadowless.cli import main as shadowless_main
    prof = cProfile.Profile(time.thread_time)      # CPU time of this (main) thread: waits count nothing
    command = (sys.argv[1:] or ["shadowless"])[0]
    out = Path(os.environ.get("SHADOWLESS_PROFILE_DIR") or ".") / f"{command}-{os.getpid()}.prof"

    def dump() -> None:
        prof.disable()
        prof.dump_stats(str(out))
    atexit.register(dump)
    prof.enable()
    return shadowless_main(sys.argv[1:])


if __name__ == "__main__":
    raise SystemExit(main())
