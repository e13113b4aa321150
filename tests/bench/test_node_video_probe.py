"""`bench node --video`'s measuring tools: the per-thread CPU clock counts the other threads' CPU
and lets go of an ended thread's files; the software GPU's resident pages are found in smaps."""
from __future__ import annotations

import subprocess
import sys


# In a process of its own: a worker of the suite may hold a GL context from an earlier test, whose
# rasterizer threads the clock would rightly count.
PROBE = """
import os, threading, time
from bench.node_video import _thread_cpu_ns

def busy(ns):
    end = time.thread_time_ns() + ns
    while time.thread_time_ns() < end:
        pass

before, _ = _thread_cpu_ns()
fds = len(os.listdir("/proc/self/fd"))
go, done = threading.Event(), threading.Event()

def work():
    busy(60_000_000)
    go.set()
    done.wait(30)

t = threading.Thread(target=work)
t.start()
try:
    assert go.wait(30)
    during, raster = _thread_cpu_ns()           # the worker is seen, idle now
finally:
    done.set()
    t.join()
closed = False
for _ in range(300):                            # once the thread is gone from /proc, a reading closes its files
    _thread_cpu_ns()
    if len(os.listdir("/proc/self/fd")) == fds:
        closed = True
        break
    time.sleep(0.01)
print(during - before, raster, closed)
"""


def test_thread_clock_counts_another_threads_cpu_and_closes_an_ended_threads_files():
    done = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    seen, raster, closed = done.stdout.split()
    assert int(seen) >= 60_000_000, f"the other thread's 60 ms of CPU were not counted: {seen} ns"
    assert int(raster) == 0, f"no rasterizer thread exists here, yet {raster} ns were counted as one"
    assert closed == "True", "the ended thread's files stayed open"


def test_software_gpu_pages_are_part_of_the_resident_memory_once_a_context_exists():
    code = ("from node.render import Renderer; from bench.node_video_memory import software_gpu_mb, rss_mb; "
            "before = software_gpu_mb(); r = Renderer.standalone(32, 16); r.render(None); r.ctx.finish(); "
            "print(before, software_gpu_mb(), rss_mb()); r.release()")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    before, gpu, rss = (float(v) for v in done.stdout.split())
    assert before == 0 and 0 < gpu < rss


def test_the_memory_by_mapping_adds_up_to_the_resident_memory_and_names_the_interpreter():
    code = ("from bench.node_video_memory import mappings_mb, rss_mb; import json; "
            "m = mappings_mb(); print(json.dumps([m, rss_mb()]))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    import json

    groups, rss = json.loads(done.stdout)
    # read one after the other, a few pages apart at most; each group rounded to 0.1 MB
    assert abs(sum(groups.values()) - rss) <= 1.0 + 0.05 * len(groups), (groups, rss)
    assert groups.get("the interpreter", 0) > 0 and all(v >= 0 for v in groups.values())
