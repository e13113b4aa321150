"""An edge node needs neither the coordinator nor SciPy/OpenCV/scikit-image."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

NODE = Path(__file__).resolve().parents[2] / "node"
FORBIDDEN = {"coordinator", "sim", "scipy", "cv2", "skimage", "bench"}


def test_node_sources_never_import_the_coordinator_or_heavy_libraries():
    for f in NODE.rglob("*.py"):
        tree = ast.parse(f.read_text(), filename=str(f))
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            for n in names:
                assert n.split(".")[0] not in FORBIDDEN, f"{f.relative_to(NODE.parent)} imports {n}"


def test_node_runs_with_the_heavy_packages_absent():
    blocker = f"""
import sys, importlib.abc
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split('.')[0] in {sorted(FORBIDDEN)!r}:
            raise ImportError('blocked for this test: ' + name)
sys.meta_path.insert(0, Block())
import node.app, node.cli, node.link, node.wire, node.presenter, node.presenter_process, node.outputs
import node.outputs.room_link, node.render.renderer, node.image_files, protos.discovery
from shadowless.cli import main
sys.argv = ['shadowless', 'node', '--help']
try:
    main()
except SystemExit as e:
    assert e.code == 0, e.code
print('ok')
"""
    r = subprocess.run([sys.executable, "-c", blocker], capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.strip().endswith("ok"), r.stderr
