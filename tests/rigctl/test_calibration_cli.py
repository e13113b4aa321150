"""`shadowless calibrate` / `alignment` argument handling and reports (the job itself is tested
against the room; the command end to end in test_end_to_end)."""
from __future__ import annotations

import json

import pytest

from rigctl.calibration_cli import alignment_params, alignment_report, calibrate_params, calibrate_report
from shadowless.cli import build_parser


def parse(argv):
    return build_parser(argv[0]).parse_args(argv)


def test_local_files_travel_with_the_job_and_options_map_to_parameters(tmp_path):
    pts = {"frame": "world", "points": [{"xy": [0, 0], "pixel": [1, 2]}]}
    (tmp_path / "marks.json").write_text(json.dumps(pts))
    (tmp_path / "board.toml").write_text('squares_x = 9\nsquares_y = 6\nsquare_mm = 60.0\nmarker_mm = 45.0\n')
    (tmp_path / "bust.obj").write_text("v 0 0 0\n")
    args = parse(["calibrate", "--rig-dir", str(tmp_path), "--mode", "sequential", "--slots", "r0c0, r0c1",
                  "--table-mm", "1000x500", "--table-points", str(tmp_path / "marks.json"), "--charuco", str(tmp_path / "board.toml"),
                  "--mesh", str(tmp_path / "bust.obj"), "--camera", "room://127.0.0.1:7700", "--settle", "0.2",
                  "--force", "--stop-on-error", "--no-table", "--record", "rec"])
    p = calibrate_params(args)
    assert p["mode"] == "sequential" and p["slots"] == ["r0c0", "r0c1"] and p["table_mm"] == [1000.0, 500.0]
    assert p["table_points"] == pts and p["charuco"]["squares_x"] == 9
    assert p["mesh"] == str(tmp_path / "bust.obj") and p["cameras"] == ["room://127.0.0.1:7700"]
    assert p["settle_s"] == 0.2 and p["force"] and p["keep_going"] is False and p["use_table"] is False
    assert p["record"].endswith("/rec") and p["record"].startswith("/")
    assert calibrate_params(parse(["calibrate", "--rig-dir", str(tmp_path)])) == {}
    with pytest.raises(SystemExit):
        parse(["calibrate", "--table-mm", "wide"])
    with pytest.raises(SystemExit, match="cannot read table points"):
        calibrate_params(parse(["calibrate", "--table-points", str(tmp_path / "none.json")]))
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(SystemExit, match="not valid JSON"):
        calibrate_params(parse(["calibrate", "--landmarks", str(tmp_path / "bad.json")]))
    a = alignment_params(parse(["alignment", "--slots", "r0c0", "--rounds", "3", "--camera-index", "1"]))
    assert a == {"slots": ["r0c0"], "rounds": 3, "camera": 1}


def test_reports_are_tables_an_operator_can_read():
    text = calibrate_report({"run": "r1", "mode": "multiplexed", "surface": "table", "captures": 26, "wall_s": 8.1,
                             "slots": {"r0c0": {"rms_px": 0.0123, "max_px": 0.05, "points": 160},
                                       "r0c1": {"rms_px": 0.02, "max_px": 0.07, "points": 150, "resumed": True}},
                             "failed": {}})
    lines = text.splitlines()
    assert "multiplexed mode" in lines[0] and "26 captures" in lines[0]
    assert lines[2].split()[:4] == ["r0c0", "0.012", "0.050", "160"] and "earlier part of this run" in lines[3]
    text = alignment_report({"slots": {"r0c0": {"rms_px": 0.1, "p95_px": 0.2, "max_px": 0.3, "dots": 40, "worst_at_mm": [10, -20]}},
                             "worst_slot": "r0c0", "worst_rms_px": 0.1, "heatmap": "/rig/calibration/alignment.png"})
    assert "(10, -20)" in text and "worst: r0c0" in text and "alignment.png" in text
