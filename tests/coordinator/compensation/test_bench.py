"""`shadowless bench compensation` on a tiny rig: one JSON document with every figure."""
from __future__ import annotations

import argparse
import json

from bench import compensation


def run_bench(capsys, argv):
    parser = argparse.ArgumentParser()
    compensation.configure(parser)
    args = parser.parse_args(argv)
    assert compensation.run(args) == 0
    return json.loads(capsys.readouterr().out)


def test_quick_bench_reports_every_figure(capsys, tmp_path):
    doc = run_bench(capsys, ["--quick", "--size", "64x48", "--projectors", "1,4", "--video-size", "80x48",
                             "--video-frames", "3", "--spacing", "5", "--out", str(tmp_path)])
    assert doc["benchmark"] == "compensation" and "cpus" in doc["machine"]
    assert doc["parameters"]["size"] == [64, 48] and doc["paper_size"] is None
    rows = {r["projectors"]: r for r in doc["per_projectors"]}
    assert set(rows) == {1, 4}
    for n, r in rows.items():
        assert r["captures"] == {"ours": 26, "baseline": n * 25 + 1}
        q = r["quality"]
        assert q["ours"]["psnr"] > q["none"]["psnr"] and q["baseline"]["psnr"] > q["none"]["psnr"]
        assert r["ours"]["iterations"] > 0 and r["baseline"]["iterations"] >= n
        assert r["picture"] and (tmp_path / r["picture"].split("/")[-1]).exists()
    # one projector: the baseline is the same problem as ours
    assert rows[1]["baseline"]["iterations"] == rows[1]["ours"]["iterations"]
    assert rows[1]["quality"]["ours"] == rows[1]["quality"]["baseline"]
    video = doc["video"]
    assert video["frames"] == 3 and video["pan"]["ms_per_frame_mean"] > 0
    assert video["overlay"]["psnr_warm_mean"] > video["overlay"]["psnr_none_mean"]
    assert doc["noise_sweep"] is None
