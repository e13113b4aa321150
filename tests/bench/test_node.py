"""`shadowless bench node`: both profiles run, on the contexts they claim, and render the same
picture; the node's install is measured and holds no SciPy, OpenCV or scikit-image; what blend maps
cost (render time with and without, resident memory) is measured in the same run."""
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
    blend = d["blend"]
    assert blend["maps"] == [24, 16], "a quarter of the output's resolution"
    assert blend["render_ratio"] == blend["profiles"]["default"]["render_ratio"] > 0
    assert blend["rss_delta_mb"] == blend["profiles"]["default"]["rss_delta_mb"]
    for p in blend["profiles"].values():
        assert p["render_ms_p50_with"] > 0 and p["render_ms_p50_without"] > 0 and p["frames"] >= 12
        assert abs(p["median_ratio"] - p["render_ms_p50_with"] / p["render_ms_p50_without"]) <= 0.01
        assert p["render_ratio"] > 0 and p["blocks"] >= 1
        assert abs(p["rss_delta_mb"] - p["rss_shader_variant_mb"] - p["rss_maps_mb"]) <= 0.011
    install = d["node_install"]
    assert install["forbidden_present"] == []
    assert {"numpy", "grpcio", "moderngl", "av"} <= set(install["distributions"])
    assert install["total_mb"] > 10


def test_every_ablation_still_applies_to_the_shader():
    # `bench node --ablate`'s ablations are text edits of pipeline.glsl: one that no longer matches
    # would measure nothing (the bench refuses it); checked here without drawing, so it costs nothing
    from bench.node_ablation import ABLATIONS, ablated
    from node.render.shaders import load_shader

    base = load_shader("pipeline.glsl")
    for name in ABLATIONS:
        assert (ablated(base, name) == base) == (name == "whole"), name


def test_bench_node_video_memory_only_measures_the_presenter_by_part_and_mapping_and_after_the_stop():
    done = subprocess.run([sys.executable, "-m", "shadowless", "bench", "node", "--video", "--memory-only", "--size",
                           "96x64", "--content", "96x64", "--video-frames", "20"], capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    v = json.loads(done.stdout)["video"]
    assert "paths" not in v, "no CPU part"
    m = v["memory"]
    a = m["after"]
    assert a["rss_mb"] > 0 and 0 < a["rss_mb_after_stop"] and a["split_mb"]["imports"] > 0
    # the mappings add up to the process's resident memory (read a frame apart, rounded to 0.1 MB each)
    assert abs(sum(a["by_mapping_mb"].values()) - a["rss_mb"]) <= 3.0, a["by_mapping_mb"]
    assert a["by_mapping_mb"].get("llvmpipe: libLLVM", 0) > 0 < a["by_mapping_mb"].get("PyAV and FFmpeg", 0)
    node = m["node_processes"]["node_process"]
    assert node["by_mapping_mb"].get("the interpreter", 0) > 0 and "llvmpipe: libLLVM" not in node["by_mapping_mb"]
    assert "by mapping while playing" in done.stderr


def test_memory_only_needs_video():
    done = subprocess.run([sys.executable, "-m", "shadowless", "bench", "node", "--memory-only"], capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 2 and "--memory-only goes with --video" in done.stderr
