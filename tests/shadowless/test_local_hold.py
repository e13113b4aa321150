"""`shadowless local --hold`: a rig that stays up for an operator. It gives its nodes poses (their
snapshots show the test card, not black), serves the console on 127.0.0.1 and says where and how to
log in, and on Ctrl-C stops every process it started and removes its temporary directory, token
included. Real processes, one node, a small output."""
from __future__ import annotations

import re
import signal
import subprocess
import sys
import urllib.request
from pathlib import Path

import cv2
import psutil
from procs import stop
from waits import wait_until


def test_local_hold_stays_up_serves_the_console_and_cleans_up_on_ctrl_c(tmp_path):
    err = tmp_path / "stderr.txt"
    with open(err, "wb") as f:
        proc = subprocess.Popen([sys.executable, "-m", "shadowless", "local", "--nodes", "1", "--size", "64x36",
                                 "--seconds", "0.2", "--fps", "10", "--hold"], stdout=subprocess.DEVNULL, stderr=f)
    try:
        text = wait_until(lambda: err.read_text(), lambda t: "stays up until Ctrl-C" in t or proc.poll() is not None,
                          what="the rig held up", timeout=180)
        assert proc.poll() is None, text
        url = re.search(r"operator console: (http://127\.0\.0\.1:\d+/)", text).group(1)
        token = Path(re.search(r"paste the contents of (\S+/token)", text).group(1))
        workdir = token.parent.parent
        assert token.is_file() and workdir.name.startswith("shadowless-local-"), text
        assert "poses: the identity on 1 node " in text, text
        with urllib.request.urlopen(url, timeout=30) as page:
            assert page.status == 200
        # the node writes its snapshot after the swap, off the critical instant: wait for the card in it
        wait_until(lambda: cv2.imread(str(workdir / "snapshots" / "r0c0.png")),
                   lambda img: img is not None and img.mean() > 20, what="the posed node's snapshot of the card")
        children = psutil.Process(proc.pid).children(recursive=True)
        assert len(children) >= 2, children          # the coordinator and the node (and their helpers)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=120) == 0, err.read_text()
    finally:
        stop(proc)        # a failed check: SIGTERM still stops what it started
    gone, alive = psutil.wait_procs(children, timeout=30)
    assert not alive, alive
    assert not workdir.exists(), "the temporary directory, token included, is removed"
    assert "SIGINT: stopping the rig" in err.read_text()
