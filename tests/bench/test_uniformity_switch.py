"""`python -m bench.uniformity_switch`: real node processes join a coordinator, which switches their blend
maps at common instants; the JSON reads each switch's way from the nodes' own logs and charges the
presenters' redraws to them. A switch that no node showed would leave ``switches_read`` short."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

ROOT = Path(__file__).resolve().parents[2]


def test_two_nodes_show_every_switch_and_their_redraws_are_counted(tmp_path):
    out = tmp_path / "switch.json"
    run = subprocess.run([sys.executable, "-m", "bench.uniformity_switch", "--nodes", "2", "--switches", "2",
                          "--period-s", "0.6", "--work", str(tmp_path / "work"), "--json", str(out)],
                         cwd=ROOT, capture_output=True, text=True, timeout=240)
    assert run.returncode == 0, run.stderr[-3000:]
    got = json.loads(out.read_text())
    assert (got["nodes"], got["switches"]) == (2, 2)
    assert got["way"]["switches_read"] == 2, got["way"]
    for way in got["switch_ways"]:
        assert way["nodes"] == 2, way
        assert sorted(way["set_to_received_by_slot"]) == ["r0c0", "r0c1"], way
        assert way["set_to_received_by_slot"]["r0c0"] >= 0, way
    # each switch draws the still again on every presenter: CPU a node with no switch does not spend
    assert got["per_switch_per_node_ms"]["presenter"] > 0, got["per_switch_per_node_ms"]
    assert got["busy"]["presenters"] > 0 and got["idle"]["span_ms"] > 0, (got["busy"], got["idle"])
