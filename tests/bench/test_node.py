"""`shadowless bench node`: both profiles run, on the contexts they claim, and render the same
picture; the node's install is measured and holds no SciPy, OpenCV or scikit-image."""
from __future__ import annotations

import json
import subprocess
import sys


def test_bench_node_measures_every_profile():
    done = subprocess.run([sys.executable, "-m", "shadowless", "bench", "node", "--size", "96x64", "--content",
                           "80x60", "--frames", "4"], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    d = json.loads(done.stdout)
    default, gl31 = d["profiles"]["default"], d["profiles"]["gl31"]
    assert default["context_version"] >= 330 and gl31["context_version"] == 310
    assert "GLSL 1.40" in gl31["gl"]
    gles, bare = d["profiles"]["gles"], d["profiles"]["gles30_bare"]
    assert gles["gl"].startswith("OpenGL ES 3.") and bare["gl"].startswith("OpenGL ES 3.0")
    assert d["same_picture"] and default["frame_mean_level"] > 0
    for p in (default, gl31, gles, bare):
        assert p["render_ms_p50"] > 0 and p["upload_ms_p50"] > 0 and p["rss_mb"] > p["rss_interpreter_mb"] > 0
        assert 0 < p["node_rss_mb"] <= p["rss_mb"]
    install = d["node_install"]
    assert install["forbidden_present"] == []
    assert {"numpy", "grpcio", "moderngl", "av"} <= set(install["distributions"])
    assert install["total_mb"] > 10
