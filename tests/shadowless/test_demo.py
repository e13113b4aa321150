"""`shadowless demo` end to end (with the room's poses and without its blur compensation, to keep
it short; `make demo` calibrates and compensates): room + coordinator + 26 node processes, the
image on every projector, the hand 0.2 m above the table. The demo's compensation step runs the
response, transport and compensate jobs, which tests/coordinator/compensation/test_job_end_to_end.py
runs through nodes, the coordinator and the room service the same way. With --serve the rig then
stays up with its console until Ctrl-C, and every process it started stops with it."""
from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import urllib.request

import cv2
import psutil
from procs import stop
from waits import wait_until


def test_demo_writes_the_comparison_shows_the_papers_observation_and_serves_its_console(tmp_path):
    out = tmp_path / "demo"
    log = tmp_path / "demo.txt"
    with open(log, "wb") as f:
        proc = subprocess.Popen([sys.executable, "-m", "shadowless", "demo", "--poses", "truth", "--no-compensate",
                                 "--out", str(out), "--serve"], stdout=f, stderr=subprocess.STDOUT)
    try:
        text = wait_until(log.read_text, lambda t: "stays up until Ctrl-C" in t or proc.poll() is not None,
                          what="the demo's rig held up", timeout=600)
        assert proc.poll() is None, text[-3000:]
        assert "ground truth" in text, "the demo must say when poses were not calibrated"
        report = json.loads((out / "report.json").read_text())
        p1, p25 = report["light_drop"]["P1"], report["light_drop"]["P25"]
        assert p1["umbra_mm2"] > 1000 and p1["max"] > 0.99        # one projector: a hard shadow
        assert p25["umbra_mm2"] == 0 and p25["max"] < 0.6         # 25 projectors: no umbra at all
        teaser = cv2.imread(str(out / "teaser.png"))
        assert teaser is not None and teaser.shape[0] > 400 and teaser.shape[1] > 800
        small = cv2.imread(str(out / "teaser.jpg"))          # the README's copy (docs/teaser.jpg)
        assert small is not None and all(abs(s - 0.75 * t) <= 1 for s, t in zip(small.shape[:2], teaser.shape[:2]))
        light_drop = cv2.imread(str(out / "light_drop.png"))     # two 1200 x 600 mm maps at 2 mm a pixel, with axes
        assert light_drop is not None and light_drop.shape[1] > 2 * 600 and light_drop.shape[0] > 300
        assert (out / "report.md").read_text().startswith("# shadowless demo")
        assert "compensation" not in report and not (out / "compensation.png").exists()
        url = re.search(r"operator console: (http://127\.0\.0\.1:\d+/)", text).group(1)
        assert f"paste the contents of {out / 'rig' / 'rig' / 'token'}" in text
        with urllib.request.urlopen(url, timeout=30) as page:
            assert page.status == 200
        children = psutil.Process(proc.pid).children(recursive=True)
        assert len(children) >= 28, len(children)       # the room, the coordinator and 26 nodes
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=180) == 0, log.read_text()[-3000:]
    finally:
        stop(proc)        # a failed check: SIGTERM still stops what it started
    _, alive = psutil.wait_procs(children, timeout=30)
    assert not alive, alive
    assert "SIGINT: stopping the rig" in log.read_text()
    assert "shadowless demo --serve" not in log.read_text(), "the hint to serve is for a plain demo only"
