"""The node's presenter process: started on its own (no third process beside it), and gone with the
node process however that ends."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from waits import wait_until

# A node process in miniature: it starts its presenter, waits until it is ready, says what runs
# under it, then dies without a word (SIGKILL: no stop message, no atexit).
NODE = """
import os, signal
from pathlib import Path
from node.presenter_process import PresenterProcess, PresenterSettings

p = PresenterProcess(PresenterSettings(slot="r0c0", output_spec="offscreen", clock_offset_ns=0,
                                       clock_drift_ppm=0.0, clock_anchor_ns=0))
p.start()
assert p.wait_ready(120.0), p.failed
kids = Path(f"/proc/{os.getpid()}/task/{os.getpid()}/children").read_text().split()
print(f"{p.pid}|{' '.join(kids)}", flush=True)
os.kill(os.getpid(), signal.SIGKILL)
"""


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state != "Z"


def test_the_presenter_is_the_node_process_only_child_and_ends_when_the_node_process_is_killed():
    node = subprocess.Popen([sys.executable, "-c", NODE], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    pid = None
    try:
        out, err = node.communicate(timeout=300)
        assert node.returncode == -signal.SIGKILL, err[-3000:]
        first, kids = out.strip().split("|")
        pid = int(first)
        assert kids.split() == [first], f"one child, the presenter ({pid}), expected under the node process: {kids}"
        # its parent died without a word: the node's end of the pipe closed, and the presenter stops
        wait_until(lambda: _alive(pid), lambda alive: not alive, what="the orphaned presenter to end", timeout=60)
    finally:
        if node.poll() is None:
            node.kill()
            node.wait()
        if pid is not None and _alive(pid):
            os.kill(pid, signal.SIGKILL)
