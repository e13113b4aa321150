"""`bench node --video`'s measuring tools: the per-thread CPU clock counts the other threads' CPU
and lets go of an ended thread's files; the software GPU's resident pages are found in smaps."""
from __future__ import annotations

import os
import subprocess
import sys
import threading

from waits import wait_until

from bench.node_video import _thread_cpu_ns


def _busy(ns: int) -> None:
    import time

    end = time.thread_time_ns() + ns
    while time.thread_time_ns() < end:
        pass


def test_thread_clock_counts_another_threads_cpu_and_closes_an_ended_threads_files():
    before, _ = _thread_cpu_ns()
    fds = len(os.listdir("/proc/self/fd"))
    go, done = threading.Event(), threading.Event()

    def work() -> None:
        _busy(60_000_000)
        go.set()
        done.wait(30)

    t = threading.Thread(target=work)
    t.start()
    assert go.wait(30)
    during, raster = _thread_cpu_ns()           # the worker is seen, idle now
    assert during - before >= 60_000_000 and raster == 0
    done.set()
    t.join()
    # once the thread is gone from /proc, a reading closes its files
    wait_until(lambda: (_thread_cpu_ns(), len(os.listdir("/proc/self/fd")))[1], lambda n: n == fds,
               what="the ended thread's files closed")


def test_software_gpu_pages_are_part_of_the_resident_memory_once_a_context_exists():
    code = ("from node.render import Renderer; from bench.node_video_memory import software_gpu_mb, rss_mb; "
            "before = software_gpu_mb(); r = Renderer.standalone(32, 16); r.render(None); r.ctx.finish(); "
            "print(before, software_gpu_mb(), rss_mb()); r.release()")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    before, gpu, rss = (float(v) for v in done.stdout.split())
    assert before == 0 and 0 < gpu < rss
