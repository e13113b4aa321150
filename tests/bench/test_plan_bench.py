"""`shadowless bench plan --quick`: one JSON document with the fields the report reads."""
from __future__ import annotations

import argparse
import json

from bench import plan as plan_bench
from bench.cli import BENCHMARKS


def test_quick_plan_benchmark_prints_one_json_document(capsys):
    assert "plan" in BENCHMARKS
    parser = argparse.ArgumentParser()
    plan_bench.configure(parser)
    assert plan_bench.run(parser.parse_args(["--quick", "--pitch", "25"])) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["benchmark"] == "plan" and "cpus" in doc["machine"]
    assert len(doc["curve"]) == 12 and doc["curve"][0] == 1.0 and doc["curve"][-1] < 0.8
    ref = doc["reference"]
    assert set(ref) == {"P1", "P9D", "P9W", "P13", "P17", "P20", "P25"} and ref["P1"] == 1.0
    assert doc["dense_beats_wide_9"] == (ref["P9D"] < ref["P9W"])
    assert doc["centre_free_20_not_worse"] == (ref["P20"] <= ref["P25"])
    assert doc["p1_to_p25_improvement"] == round(ref["P1"] - ref["P25"], 4)
    assert doc["knee_projectors"] is None or 1 <= doc["knee_projectors"] < 12
    pw = doc["pointwise"]  # the search ran on the same world and says whether some weighting exists
    assert pw["most"] == 3 and isinstance(pw["exists"], bool) and pw["rounds"] >= 1
    assert all(1 <= len(layout) <= 3 for layout in pw["small_layouts_ahead"])
    assert bool(pw["must_give"]) == (not pw["exists"])  # no weights: the orderings that must give, with how much
    assert doc["plan_seconds"] > 0 and doc["targets"]["plan_25_of_100_under_60_s"] is None and "bust" not in doc
