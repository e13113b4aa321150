"""`shadowless bench venue` on a tiny venue: 2 nodes on 100 Mbit/s links, a 1-second 320x180 video.

Checks that the JSON document has every figure and that they agree with each other (every node
live and ready, times measured from the right origins, the ideal from the link rate), never an
upper bound on time (a busy machine is slower, never faster), and that no namespace of the
benchmark's venue is left. With ``CI=true`` it must run (namespaces can be built as root);
elsewhere it skips only when :func:`shadowless.netns.available` says venues cannot be built.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess

import pytest

from bench import cli as bench_cli
from shadowless.netns import available, parse_rate


@pytest.fixture
def ns():
    ok, reason = available()
    if not ok:
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"CI must be able to build venue networks: {reason}")
        pytest.skip(reason)


def netns_names() -> set[str]:
    out = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, check=True).stdout
    return {line.split()[0] for line in out.splitlines() if line.strip()}


@pytest.mark.slow
def test_venue_bench_discovers_and_distributes_to_every_node(ns, capsys, tmp_path):
    parser = argparse.ArgumentParser()
    bench_cli.configure(parser)
    keep = tmp_path / "run"
    args = parser.parse_args(["venue", "--nodes", "2", "--link", "100mbit", "--size", "320x180", "--fps", "30",
                              "--seconds", "1", "--output-size", "160x90", "--keep", str(keep)])
    assert bench_cli.run(args) == 0
    out = capsys.readouterr()
    doc = json.loads(out.out)

    # no namespace of the venue it built is left
    prefix = re.search(r"venue (sl[0-9a-f]{6}):", out.err)
    assert prefix, out.err[-2000:]
    assert not {n for n in netns_names() if n.startswith(prefix.group(1) + "-")}

    assert doc["benchmark"] == "venue" and doc["machine"]["cpus"] >= 1
    p = doc["parameters"]
    assert (p["nodes"], p["link"], p["coordinator_link"], p["size"], p["output_size"]) == \
        (2, "100mbit", "100mbit", "320x180", "160x90")
    assert p["fps"] == 30 and p["seconds"] == 1 and p["codec"]
    for absent in ("timeline", "live_frames", "rejoin"):     # later steps add these
        assert absent not in doc

    slots = set(doc["ready_s"])
    assert len(slots) == 2 and set(doc["live_s"]) == slots and set(doc["node_cpu_s"]) == slots
    # every node went live, after the processes started; discovery ends with the last one
    assert all(t > 0 for t in doc["live_s"].values())
    assert doc["discovery_s"] == max(doc["live_s"].values())
    # every node got the asset, after the first node was live; distribution ends with the last one
    assert all(t > 0 for t in doc["ready_s"].values())
    assert doc["distribution_s"] > 0 and doc["distribution_s"] == max(doc["ready_s"].values())

    size = doc["asset_bytes"]
    assert size > 1000
    ideal = 2 * size * 8 / parse_rate("100mbit")
    assert doc["distribution_ideal_s"] == pytest.approx(ideal, abs=1e-4)
    assert doc["distribution_ratio"] == pytest.approx(doc["distribution_s"] / ideal, rel=0.01)
    assert doc["distribution_ratio"] > 0.5          # never faster than the links allow
    assert doc["throughput_mbit_s"] == pytest.approx(2 * size * 8 / doc["distribution_s"] / 1e6, rel=0.02)
    assert doc["coordinator_cpu_s"] >= 0 and all(v >= 0 for v in doc["node_cpu_s"].values())

    # the work directory is kept: the rig's store and every node's cache hold the video's bytes
    assert doc["workdir"] == str(keep)
    blobs = [f for f in (keep / "rig" / "assets" / "blobs").rglob("*") if f.is_file()]
    assert len(blobs) == 1 and blobs[0].stat().st_size == size
    for slot in slots:
        assert any(f.stat().st_size == size for f in (keep / "caches" / slot).rglob("*") if f.is_file()), slot
