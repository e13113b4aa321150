"""The compensation jobs' memory estimates (imaging/compensation/memory_estimate.py) against the peak
resident memory of the real work: recovering ``L`` from dot-grid captures and building the ridge problem
over it, on a camera grid other than the content's (CSR operators, as on a real rig), each measured in a
subprocess of its own (``VmHWM`` reset through ``/proc/self/clear_refs`` before each step, the allocator
trimmed first so a step is not served from what an earlier one freed). Each estimate must lie between the
measured peak and twice it."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from imaging.compensation.memory_estimate import entries, measure_bytes, operator_bytes, ridge_bytes, transport_bytes

PROBE = r'''
"""Peak resident memory of recovering L from captures and of a ridge problem over it, against the estimates."""
import ctypes, gc, json, sys
import numpy as np

def status():
    d = {}
    for line in open('/proc/self/status'):
        k, _, v = line.partition(':')
        if k in ('VmRSS', 'VmHWM'):
            d[k] = int(v.split()[0]) * 1024
    return d

def peak_of(fn):
    gc.collect()
    ctypes.CDLL("libc.so.6").malloc_trim(0)  # what the allocator kept of earlier steps goes back: the step's own peak
    with open('/proc/self/clear_refs', 'w') as f:
        f.write('5')  # resets VmHWM to the present RSS
    before = status()['VmRSS']
    out = fn()
    return out, status()['VmHWM'] - before

from imaging.compensation.memory_estimate import measure_bytes, ridge_bytes
from imaging.compensation.ridge import RidgeProblem
from imaging.compensation.synthetic import camera_noise, simulate_captures, synthetic_rig, synthetic_transport
from imaging.compensation.transport import DotGrid, transport_from_captures

w, h = (int(v) for v in sys.argv[1].split('x'))
cam = (int(h * 1.1), int(w * 1.1))          # another camera grid than the content's: CSR operators, as a real rig
H = np.diag([1.1, 1.1, 1.0])
rig = synthetic_rig(4, content_shape=(h, w), camera_shape=cam, homography=H, radius=2, seed=0)
L = synthetic_transport(rig, scale=0.25, footprint_samples=1, workers=1)
grid = DotGrid(w, h, 6)
rng = np.random.default_rng(0)
black = camera_noise(np.zeros(cam, np.float32), read_noise=1e-4, rng=rng)
caps = simulate_captures(L, grid, cam, read_noise=1e-4, rng=rng)
Lm, measured = peak_of(lambda: transport_from_captures(caps, black, grid=grid, homography=H, radius=2))
del L
_, ridge = peak_of(lambda: RidgeProblem(Lm, 0.02))
n, m = w * h, cam[0] * cam[1]
print(json.dumps({"measure": [measured, measure_bytes(n, m, 2, channels=1)],
                  "ridge": [ridge, ridge_bytes(n, m, 2)]}))
'''


@pytest.mark.parametrize("size", ["324x243", "648x486"])
def test_measure_and_ridge_estimates_bound_the_measured_peak(size):
    out = subprocess.run([sys.executable, "-c", PROBE, size], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    figures = json.loads(out.stdout.strip().splitlines()[-1])
    for step, (peak, estimate) in figures.items():
        assert peak <= estimate <= 2 * peak, f"{size} {step}: estimate {estimate / 2**20:.0f} MiB, peak {peak / 2**20:.0f} MiB"


def test_the_paper_sizes_in_figures():
    # 5 MP camera and content, R = 2: 126 M window entries, 1 GB per stored L
    n = 2592 * 1944
    assert entries(n, 2) == n * 25
    assert transport_bytes(n, n, 2) == 8 * n * 25 + 4 * (n + 1)
    assert operator_bytes(n, n, 2, "uint16") * 4 == operator_bytes(n, n, 2, "csr") - 4 * n == 2 * operator_bytes(n, n, 2)
    assert 30 * 2**30 > ridge_bytes(n, n, 2) > 5 * 2**30 > measure_bytes(n, n, 2) > 3 * 2**30
    with pytest.raises(ValueError, match="storage must be one of"):
        operator_bytes(n, n, 2, "float16")
    with pytest.raises(ValueError, match="must be >= 0"):
        entries(-1, 2)
