"""`shadowless bench show_control`, small: every part reports, and the MIDI timecode chase behaves as
docs/show-control.md says: it seeks onto MTC that starts 3 s ahead, and once MTC stops the show plays
on by itself with no further seek."""
from __future__ import annotations

import argparse
import json
import math

import bench.show_control


def test_the_bench_reports_logins_osc_and_the_mtc_chase(capsys, tmp_path):
    parser = argparse.ArgumentParser()
    bench.show_control.configure(parser)
    args = parser.parse_args(["--rounds", "10", "--logins", "1", "--slots", "4", "--mtc-seconds", "3",
                              "--keep", str(tmp_path / "run")])
    assert bench.show_control.run(args) == 0
    doc = json.loads(capsys.readouterr().out)
    f = doc["figures"]
    assert doc["benchmark"] == "show_control" and doc["parameters"]["mtc_seconds"] == 3.0
    assert f["login"]["checks"] == 1 and f["osc"]["rounds"] == 10 and f["osc"]["slots"] == 4
    mtc = f["mtc"]
    # the 3 s jump is corrected by a seek (a loaded machine may add one more while the sender lags)
    assert mtc["seeks"] >= 1 and 2000 < mtc["first_seek_drift_ms"] < 3100, mtc
    assert mtc["seeks_after_mtc_stopped"] == 0 and mtc["show_still_playing_after"] is True, mtc
    assert mtc["samples_settled"] > 0, mtc
    errors = (mtc["abs_error_ms_p50"], mtc["abs_error_ms_p99"], mtc["abs_error_ms_max"])
    assert all(math.isfinite(e) and e >= 0 for e in errors) and errors == tuple(sorted(errors)), mtc
