"""A coordinator (and a node) starts without the machinery it needs only later, nor idle BLAS spin.

Every test of the suite and every restart during a show pays a process's imports: what a job, a
room camera or mDNS needs is imported when it is first used, not at start. Each check runs in a
fresh interpreter (``python -c``), so it fails when someone adds back a top-level import.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys


def _loaded_after(code: str, names: tuple[str, ...]) -> list[str]:
    """Which of ``names`` (modules, or packages with their submodules) a fresh interpreter holds after ``code``."""
    probe = (f"import sys, json\n{code}\n"
             f"print(json.dumps(sorted(m for m in sys.modules if any(m == n or m.startswith(n + '.') "
             f"for n in {list(names)!r}))))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True, timeout=120)
    return json.loads(out.stdout.strip().splitlines()[-1])


#: not needed to serve: a job's numerics, mDNS (a coordinator with --no-mdns), the room camera's wire
LATER = ("scipy", "skimage", "zeroconf", "protos.discovery", "coordinator.wire.room_camera",
         "coordinator.calibration.options", "imaging.calibration", "coordinator.compensation",
         "coordinator.coverage_job", "coordinator.blending.blend_job", "imaging.blending.watchdog",
         "coordinator.console", "coordinator.osc.service", "aiohttp", "cv2")


def test_the_coordinator_composition_root_imports_no_job_machinery():
    assert _loaded_after("import coordinator.app", LATER) == []


def test_help_and_option_parsing_import_no_server_nor_node_runtime():
    code = ("from shadowless.cli import build_parser\n"
            "build_parser('coordinator').parse_args(['coordinator', '--rig', 'r'])\n"
            "build_parser('node').parse_args(['node', '--slot', 'r0c0'])")
    assert _loaded_after(code, ("coordinator.app", "coordinator.server", "coordinator.rig", "node.app",
                                "grpc", "zeroconf", "cv2")) == []


def _blas_timeout_after_main(env_value: str | None) -> str:
    code = ("import os\nfrom shadowless.cli import main\n"
            "try:\n    main(['--version'])\nexcept SystemExit:\n    pass\n"
            "print(os.environ.get('OPENBLAS_THREAD_TIMEOUT'))")
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_THREAD_TIMEOUT"}
    if env_value is not None:
        env["OPENBLAS_THREAD_TIMEOUT"] = env_value
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120, env=env)
    return out.stdout.strip().splitlines()[-1]


def test_every_shadowless_process_lets_idle_blas_threads_sleep_unless_told_otherwise():
    # OpenBLAS's default spin after NumPy's import cost each process about 0.1 s of a core
    assert _blas_timeout_after_main(None) == "4"
    assert _blas_timeout_after_main("20") == "20"


def test_a_node_told_its_coordinator_does_not_import_mdns():
    """A node given --coordinator never browses: zeroconf loads only in a node that looks for its rig."""
    assert _loaded_after("import node.app", ("zeroconf", "protos.discovery")) == []
