"""`shadowless bench motion --quick`: one JSON document with the figures the issue asks for."""
from __future__ import annotations

import argparse
import json

import bench.motion
from bench.cli import BENCHMARKS


def test_quick_benchmark_prints_the_systems_figures(capsys):
    assert "motion" in BENCHMARKS
    parser = argparse.ArgumentParser()
    bench.motion.configure(parser)
    assert bench.motion.run(parser.parse_args(["--quick"])) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["benchmark"] == "motion" and doc["machine"]["cpus"] >= 1
    assert doc["parameters"]["frames"] == 6 and doc["parameters"]["latency_ms"] == [0.0, 50.0, 100.0]
    systems = doc["systems"]
    for name in ("P1", "P25", "reactive_100ms"):
        for key in ("integrated_area_above_90_mm2_s", "integrated_area_above_50_mm2_s", "max_drop"):
            assert key in systems[name], (name, key)
    assert systems["P1"]["integrated_area_above_90_mm2_s"] > 0 and systems["P1"]["max_drop"] == 1.0
    assert systems["reactive_100ms"]["latency_frames"] == 2
    assert {"reactive_0ms", "reactive_50ms", "reactive_100ms_suppress", "reactive_100ms_P2_suppress", "P2", "P9D"} <= set(systems)
    t = doc["targets"]
    assert t["p25_integrated_umbra_is_0"] and t["reactive_0ms_restores_every_point"] and t["reactive_100ms_shows_ghosts"]
    assert doc["comparison"]["reactive_100ms_vs_P25"]["integrated_deficit_mm2_s"] < 1.0
    assert doc["seconds"]["per_frame"] > 0
