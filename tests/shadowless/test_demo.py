"""`shadowless demo` end to end (with the room's poses and without its blur compensation, to keep
it short; `make demo` calibrates and compensates): room + coordinator + 26 node processes, the
image on every projector, the hand 0.2 m above the table. The demo's compensation step runs the
response, transport and compensate jobs, which tests/coordinator/compensation/test_job_end_to_end.py
runs through nodes, the coordinator and the room service the same way."""
from __future__ import annotations

import json
import subprocess
import sys

import cv2


def test_demo_writes_the_comparison_and_shows_the_papers_observation(tmp_path):
    out = tmp_path / "demo"
    r = subprocess.run([sys.executable, "-m", "shadowless", "demo", "--poses", "truth", "--no-compensate", "--out", str(out)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "ground truth" in r.stdout, "the demo must say when poses were not calibrated"
    report = json.loads((out / "report.json").read_text())
    p1, p25 = report["light_drop"]["P1"], report["light_drop"]["P25"]
    assert p1["umbra_mm2"] > 1000 and p1["max"] > 0.99        # one projector: a hard shadow
    assert p25["umbra_mm2"] == 0 and p25["max"] < 0.6         # 25 projectors: no umbra at all
    teaser = cv2.imread(str(out / "teaser.png"))
    assert teaser is not None and teaser.shape[0] > 400 and teaser.shape[1] > 800
    assert (out / "light_drop.png").exists() and (out / "report.md").read_text().startswith("# shadowless demo")
    assert "compensation" not in report and not (out / "compensation.png").exists()
