"""`shadowless bench room`: its statistics against closed forms, and one quick run."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sim.drop_figures import drop_statistics

ROOT = Path(__file__).resolve().parents[2]


def test_drop_statistics_of_known_maps():
    h, w = 200, 300
    on = np.ones((h, w), bool)
    area = np.full((h, w), 4.0)  # 2 mm pixels
    yy, xx = np.mgrid[0:h, 0:w]
    r = np.hypot(xx - 150, yy - 100)
    hard = (r <= 30).astype(np.float32)  # a black disc: a hard shadow
    s = drop_statistics(hard, on, area)
    assert s["max"] == 1.0 and s["max_step"] == 1.0 and s["mean"] == 1.0
    assert s["umbra_mm2"] == pytest.approx(np.pi * 30**2 * 4.0, rel=0.02)
    assert s["area_below_50_mm2"] == s["umbra_mm2"]
    assert s["transition_mm"] <= 2.0
    soft = np.clip(0.6 * (1 - (r - 10) / 40), 0, 0.6).astype(np.float32)  # 0.6 in the middle, fading over 40 px
    s = drop_statistics(soft, on, area)
    assert s["max"] == pytest.approx(0.6, abs=1e-6) and s["umbra_mm2"] == 0.0
    # from 10 % of max (r = 46) to 90 % of max (r = 14): 32 px of 2 mm
    assert s["transition_mm"] == pytest.approx(64.0, abs=3.0)
    assert s["max_step"] < 0.02
    assert s["area_below_50_mm2"] == pytest.approx(np.pi * (10 + 40 / 6) ** 2 * 4.0, rel=0.05)
    # the table's border is not a shadow edge
    half = on.copy()
    half[:, 150:] = False
    assert drop_statistics(soft, half, area)["max_step"] < 0.02


def test_quick_benchmark_prints_one_json_document():
    out = subprocess.run([sys.executable, "-m", "shadowless", "bench", "room", "--quick"], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout)
    assert doc["benchmark"] == "room" and "cpus" in doc["machine"]
    cap = doc["capture"]["default"]
    assert cap["camera"] == [648, 486] and set(cap["fresh"]) == {"1", "9", "25"}
    assert set(doc["light_drop"]) == {"P1", "P9D", "P9W", "P13", "P17", "P20", "P25"}
    assert doc["light_drop"]["P1"]["umbra_mm2"] > 0 and doc["light_drop"]["P25"]["umbra_mm2"] == 0
    assert doc["targets"]["p1_leaves_an_umbra"] and doc["targets"]["p25_leaves_no_umbra"]
