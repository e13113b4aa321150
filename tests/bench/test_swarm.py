"""`shadowless bench swarm` at a small node count: one JSON document with the figures per node count
(the coordinator's CPU per node and second during timeline playback, per live frame, its memory)
and the swarm's own account (it kept up, it used CPU). Values are checked for sanity, not speed."""
from __future__ import annotations

import json
import math
import subprocess
import sys


def test_bench_swarm_prints_the_figures(tmp_path):
    r = subprocess.run([sys.executable, "-m", "shadowless", "bench", "swarm", "--nodes", "3,4", "--fps", "30",
                        "--seconds", "0.5", "--warmup", "0", "--size", "64x48", "--live-fps", "20",
                        "--keep", str(tmp_path)], capture_output=True, text=True, timeout=240, check=False)
    assert r.returncode == 0, r.stderr[-3000:]
    doc = json.loads(r.stdout)
    assert doc["benchmark"] == "swarm" and doc["parameters"]["nodes"] == [3, 4]
    assert [run["nodes"] for run in doc["runs"]] == [3, 4]
    for run in doc["runs"]:
        for key in ("timeline_cpu_ms_per_node_per_s", "live_cpu_ms_per_frame", "idle_cpu_ms_per_node_per_s"):
            assert math.isfinite(run[key]) and run[key] >= 0, (key, run[key])
        assert 10 < run["rss_mb"] < 4000 and run["rss_peak_mb"] >= run["rss_mb"]
        phases = run["phases"]
        assert set(phases) == {"idle", "timeline_large_30fps", "timeline_small_30fps", "live"}
        for name in ("timeline_large_30fps", "timeline_small_30fps"):
            ph = phases[name]
            assert ph["swarm_live"] == run["nodes"]
            assert ph["swarm_swaps"] + ph["swarm_woke_late"] > 0         # the nodes followed the timeline
            due = ph["swarm_swaps"] + ph["swarm_woke_late"]
            assert ph["swarm_on_time_fraction"] == round(ph["swarm_swaps"] / due, 4)   # of the swaps due, those on time
            assert ph["swarm_cpu_s"] >= 0
        assert phases["live"]["frames_sent"] == 10                      # --live-fps 20 for --seconds 0.5
        assert run["swarm"]["errors"] == 0 and run["swarm"]["joins"] == run["nodes"]
    assert set(doc["per_node_ratio"]) == {"nodes", "timeline", "live_per_frame"}
