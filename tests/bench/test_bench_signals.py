"""A benchmark stopped by SIGTERM unwinds: its temporary directory is removed (bench.cli.unwind_on_signals)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys

CHILD = """
import tempfile, time
from bench.cli import unwind_on_signals
unwind_on_signals()
with tempfile.TemporaryDirectory(prefix="bench-signal-test-") as tmp:
    open(tmp + "/capture.npy", "wb").write(b"x" * 1024)
    print(tmp, flush=True)
    time.sleep(120)
"""


def test_sigterm_unwinds_a_benchmark_and_removes_its_temporary_directory():
    proc = subprocess.Popen([sys.executable, "-c", CHILD], stdout=subprocess.PIPE, text=True)
    try:
        tmp = proc.stdout.readline().strip()
        assert tmp and os.path.isdir(tmp), tmp
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(60) == 128 + signal.SIGTERM, proc.returncode
        assert not os.path.exists(tmp), f"{tmp} left behind"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
