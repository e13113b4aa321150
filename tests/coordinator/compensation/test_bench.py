"""`shadowless bench compensation` on a tiny rig: one JSON document with every figure."""
from __future__ import annotations

import argparse
import json

from bench import compensation, compensation_room


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


def test_room_bench_runs_the_jobs_and_reports_the_comparison(capsys, tmp_path):
    """`shadowless bench compensation_room` on a small room: the coordinator's jobs end to end, in-process."""
    parser = argparse.ArgumentParser()
    compensation_room.configure(parser)
    args = parser.parse_args(["--projector-scale", "0.14", "--camera-scale", "0.09", "--content-size", "96x48",
                              "--video-frames", "2", "--eval-frames", "2", "--max-iter", "100", "--out", str(tmp_path)])
    assert compensation_room.run(args) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["benchmark"] == "compensation_room" and doc["parameters"]["camera_size"] == [233, 175]
    r25, t = doc["rigs"]["25"], doc["targets"]
    # L costs the same captures for 1 or 25 projectors; the baseline's L_i cost N times as many
    assert t["transport_captures_25_vs_1"][0] == t["transport_captures_25_vs_1"][1] == r25["transport"]["captures"]
    # (L's captures: the patterns, the black, and the first pattern and the black for the dots' longer exposure)
    assert r25["compensate"]["baseline"]["captures"] == 25 * (r25["transport"]["captures"] - 3) + 1
    assert r25["transport"]["relative_error"] < 0.1
    assert t["baseline_25_over_ours_25_solve"] > 5
    # with the room's true transport both methods sharpen, ours the most
    o = t["quality_order_oracle"]
    assert o["ours"] > o["baseline"] > o["none"] + 1.0, o
    assert r25["sequence"]["frames"] == 2 and r25["sequence"]["ms_per_frame_mean"] > 0
    assert (tmp_path / "quality.png").exists() and json.loads((tmp_path / "quality.json").read_text())["ours"]
