"""`shadowless bench uniformity --quick` on the smallest rigs: one JSON document with every figure the
issue names (null, with a note naming what is absent, for a part this build cannot run), and, where the
blend job exists, a table that is measurably more even after the blend than before (captures, not flags)."""
from __future__ import annotations

import argparse
import json

import pytest

from bench import uniformity
from coordinator.jobs import registry


def run_bench(capsys, argv):
    parser = argparse.ArgumentParser()
    uniformity.configure(parser)
    args = parser.parse_args(argv)
    assert uniformity.run(args) == 0
    return json.loads(capsys.readouterr().out)


def test_quick_table_and_wall(capsys):
    doc = run_bench(capsys, ["--quick", "--only", "table,wall"])
    assert doc["benchmark"] == "uniformity"
    for key in uniformity.FIGURES:                       # every figure the issue names is in the document
        assert key in doc, key
    for part in ("bust", "captures", "failover", "watchdog", "node"):
        assert doc["missing"][part] == "not run (--only)"
        assert all(doc[k] is None for k, (p, _, _) in uniformity.FIGURES.items() if p == part)
    if "blend" not in registry.JOBS:
        assert "blend job" in doc["missing"]["table"] and doc["table.before"] is None and doc["table.after"] is None
        pytest.skip("the blend job is not in this build: only the document's shape was checked")
    assert "table" not in doc["missing"], doc["missing"]
    table = doc["parts"]["table"]
    # the captured flat white is more even after the blend than before it, against the same target
    assert doc["table.before"] > doc["table.after"] >= 0, table
    assert doc["table.after"] < doc["table.before"] / 2, table
    assert 0 <= doc["table.colour_after"] < table["colour_before"], table
    assert table["maps_change_white_by"] > 0.01         # the maps changed what the camera saw
    assert doc["targets"]["table.after_below_before"]["met"] is True
    if "wall" not in doc["missing"]:
        # before the blend the wall's overlaps are about twice as bright: a large step at their edges
        wall = doc["parts"]["wall"]
        assert doc["wall.seam_before"] > 0.3 and doc["wall.seam_after"] is not None, wall


def test_bad_parts_are_refused_in_one_line(capsys):
    parser = argparse.ArgumentParser()
    uniformity.configure(parser)
    with pytest.raises(SystemExit):
        parser.parse_args(["--only", "table,colour"])
    assert "parts are table, wall, bust" in capsys.readouterr().err
