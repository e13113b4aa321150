"""Describe the machine a benchmark ran on (goes into every JSON document)."""
from __future__ import annotations

import os
import platform


def machine() -> dict:
    info = {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpus": os.cpu_count(),
    }
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    info["cpu"] = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        with open("/proc/meminfo") as f:
            info["mem_gib"] = round(int(f.readline().split()[1]) / 2**20, 1)
    except OSError:
        pass
    return info


def load() -> list[float]:
    """The 1, 5 and 15 minute load averages (how busy the machine was around a measurement)."""
    return [round(v, 2) for v in os.getloadavg()]


def streaming_bandwidth(*, mib: int = 512, threads: int = 2, repeats: int = 5) -> dict:
    """The machine's streaming bandwidth, measured as a benchmark's solver would see it.

    ``threads`` threads each copy their share of a ``mib`` MiB float32 array (far larger than
    any cache) with numpy, which releases the GIL; every repeat moves ``2 * mib`` MiB (each
    byte read once and written once, as STREAM's copy counts it). Returns the best and the
    median rate in GB/s (1e9 bytes) over ``repeats`` timed copies after one warm-up copy, and
    the load averages when it ran.

    Beside the copy, the same threads read the same array with a compiled loop (a float32 sum,
    vectorised): ``read_gb_per_s`` is its best rate and ``read_over_copy`` the ratio, what a
    loop that does nothing but read scores against the copy. Where the figures in docs/benchmarks.md were taken it
    is 0.55-0.58: the copy (glibc's memcpy) is counted at nearly twice the rate at
    which plain loads bring bytes in, so a solver that streams its matrix through loads meets
    that ceiling first.
    """
    import itertools
    import time
    from concurrent.futures import ThreadPoolExecutor

    import numpy as np

    n = (mib << 20) // 4
    src = np.ones(n, dtype=np.float32)
    dst = np.zeros(n, dtype=np.float32)
    cuts = np.linspace(0, n, threads + 1).astype(int)
    parts = [(src[a:b], dst[a:b]) for a, b in itertools.pairwise(cuts)]
    rates = []
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for k in range(repeats + 1):
            t = time.perf_counter()
            list(pool.map(lambda p: np.copyto(p[1], p[0]), parts))
            dt = time.perf_counter() - t
            if k:
                rates.append(2 * src.nbytes / dt / 1e9)
        reads = []
        halves = [a for a, _ in parts]
        _read(src[:1024])  # compiled (or loaded from Numba's cache) here, not in two threads at once
        for k in range(repeats + 1):
            t = time.perf_counter()
            list(pool.map(_read, halves))
            dt = time.perf_counter() - t
            if k:
                reads.append(src.nbytes / dt / 1e9)
    rates.sort()
    best = rates[-1]
    return {"gb_per_s": round(best, 2), "gb_per_s_median": round(rates[len(rates) // 2], 2),
            "read_gb_per_s": round(max(reads), 2), "read_over_copy": round(max(reads) / best, 3),
            "array_mib": mib, "threads": threads, "load": load()}


def _read(a) -> float:
    """Sum of a float32 array in a compiled loop that releases the GIL (compiled on first use)."""
    global _read_kernel
    if _read_kernel is None:
        import numpy as np
        from numba import njit

        @njit(nogil=True, cache=True, fastmath=True)
        def kernel(v):  # pragma: no cover - compiled
            s = np.float32(0.0)
            for i in range(v.shape[0]):
                s += v[i]
            return s

        _read_kernel = kernel
    return float(_read_kernel(a))


_read_kernel = None
