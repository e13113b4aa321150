"""A node writes files through the project's one atomic write (protos/atomic_files.py), and its
network process can do so without loading NumPy (tests/node/test_node_process_imports.py checks
the running process; this checks the modules it would write through)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np

import protos.atomic_files as atomic_files
from node.image_files import atomic_write_bytes, read_png, write_png


def test_the_node_process_modules_and_the_atomic_writes_import_no_numpy(tmp_path):
    target = tmp_path / "known" / "rig"
    probe = ("import sys\nimport node.cli, node.app, node.targets, node.asset_cache, protos.atomic_files\n"
             f"protos.atomic_files.atomic_write_text({str(target)!r}, 'rig-1\\n')\n"
             "print(sorted(m for m in sys.modules if m == 'numpy' or m.startswith('numpy.')))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.strip().splitlines()[-1] == "[]"
    assert target.read_text() == "rig-1\n"


def test_png_writes_go_through_the_shared_atomic_write(tmp_path):
    assert atomic_write_bytes is atomic_files.atomic_write_bytes
    image = np.arange(4 * 5 * 3, dtype=np.uint8).reshape(4, 5, 3)
    path = tmp_path / "r0c0.png"
    write_png(path, image)
    write_png(path, image[::-1].copy())
    np.testing.assert_array_equal(read_png(path), image[::-1])
    assert [p.name for p in tmp_path.iterdir()] == ["r0c0.png"], "no temp file left behind"
    assert (path.stat().st_mode & 0o777) == 0o644, "readable like every other file the project writes"
