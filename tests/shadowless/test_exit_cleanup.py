"""A process running a local rig that is terminated (SIGTERM, as a CI timeout or a service stop
sends) takes its coordinator and nodes with it: nothing is left orphaned."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap

from waits import wait_until

SCRIPT = textwrap.dedent(
    """
    import signal, sys
    from pathlib import Path
    from shadowless.local import LocalRig

    rig = LocalRig(["r0c0"], Path(sys.argv[1]), output_size=(32, 24), content_size=(32, 24))
    rig.create()
    rig.start_coordinator()
    rig.start_node("r0c0")
    print(rig.coordinator.pid, rig.nodes["r0c0"].pid, flush=True)
    signal.pause()      # until the test's SIGTERM
    """
)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:   # a zombie of ours would still answer: it has exited all the same
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def test_a_terminated_parent_stops_the_rig_it_started(tmp_path):
    parent = subprocess.Popen([sys.executable, "-c", SCRIPT, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    children: list[int] = []
    try:
        children = [int(v) for v in parent.stdout.readline().split()]
        assert len(children) == 2, "the script did not start its rig"
        parent.send_signal(signal.SIGTERM)
        assert parent.wait(60) == -signal.SIGTERM     # it still dies of the signal
        wait_until(lambda: [p for p in children if _alive(p)], lambda alive: not alive,
                   what="the rig's processes to end with the process that started them")
    finally:
        for pid in children + [parent.pid]:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        if parent.poll() is None:
            parent.wait(10)
