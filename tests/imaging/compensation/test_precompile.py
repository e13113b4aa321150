"""`python -m imaging.compensation.precompile` (run by `make setup`) compiles every kernel
signature a stencil solve uses into Numba's cache, so that a solve later compiles nothing."""
from __future__ import annotations

import json
import subprocess
import sys

# prints, per kernel of stencil_kernels, the signatures this process compiled or loaded
_SIGNATURES = """
import json
from numba.core.registry import CPUDispatcher
from imaging.compensation import stencil_kernels as k
def signatures():
    return {n: sorted(map(str, f.signatures)) for n, f in vars(k).items() if isinstance(f, CPUDispatcher)}
"""

_PRECOMPILED = _SIGNATURES + """
from imaging.compensation.precompile import precompile
for storage in ("float32", "uint16"):
    precompile(storage)
print(json.dumps(signatures()))
"""

# a solve as the jobs and benches run them: both storages, one and three channels, two threads
_SOLVED = _SIGNATURES + """
import numpy as np
from imaging.compensation.solver import TransportOperator, solve
from imaging.compensation.synthetic import synthetic_rig, synthetic_transport
rig = synthetic_rig(4, content_shape=(24, 32), radius=2, seed=1)
L = synthetic_transport(rig, scale=0.25, footprint_samples=1, workers=1)
rng = np.random.default_rng(0)
for storage in ("float32", "uint16"):
    for shape in ((24, 32), (24, 32, 3)):
        op = TransportOperator(L, threads=2, storage=storage)
        assert op.stencil is not None, "the synthetic rig's transport is a stencil"
        solve(op, rng.uniform(0.1, 0.8, shape).astype(np.float32), threads=2, max_iter=5)
print(json.dumps(signatures()))
"""


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=600)


def test_each_storage_is_reported_ready():
    r = _run("-m", "imaging.compensation.precompile", "--storage", "uint16", "--storage", "float32")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert [line.split(":")[0] for line in lines] == ["solver kernels, uint16 weights", "solver kernels, float32 weights"]
    assert all(" ready in " in line and line.endswith(" s") for line in lines), lines


def test_a_solve_uses_no_signature_the_precompile_left_out():
    pre = _run("-c", _PRECOMPILED)
    solved = _run("-c", _SOLVED)
    assert pre.returncode == 0 and solved.returncode == 0, (pre.stderr, solved.stderr)
    compiled, used = json.loads(pre.stdout), json.loads(solved.stdout)
    assert used["sweep_rows"] and used["extract_rows"], used  # the solve went through the kernels
    missing = {name: sorted(set(sigs) - set(compiled[name])) for name, sigs in used.items()}
    assert not any(missing.values()), missing


def test_help_and_a_wrong_storage():
    h = _run("-m", "imaging.compensation.precompile", "--help")
    assert h.returncode == 0 and "Numba's cache" in h.stdout and "--storage" in h.stdout
    bad = _run("-m", "imaging.compensation.precompile", "--storage", "int8")
    assert bad.returncode == 2 and "invalid choice: 'int8'" in bad.stderr and "Traceback" not in bad.stderr
