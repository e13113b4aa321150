"""`shadowless bench venue --quick` on a tiny venue: 2 nodes on 100 Mbit/s links, a 1-second 320x180
video, played by timeline, then looped while one node is killed and restarted, then looped while the
coordinator is killed and restarted 2.5 s later (--quick: the shows around the kills shortened);
then 2 s of live frames.

Checks that the JSON document has every figure and that they agree with each other (every node
live and ready, times measured from the right origins, the ideal from the link rate, the show's
counts within their bounds, the coordinator's traffic far below raw frames), never an upper bound
on time or skew (a busy machine is slower, never faster), and that no namespace of the
benchmark's venue is left. With ``CI=true`` it must run (namespaces can be built as root);
elsewhere it skips only when :func:`shadowless.netns.available` says venues cannot be built.

Where CPU budgets can be made (root, a cgroup cpu controller) it runs with ``--node-cpu 0.5``: every
node, its rasterizer's threads, the coordinator and the benchmark each had a group of their own
that measured what ran in it (restarted processes included), the nodes' groups weighing more than
the coordinator's and allowed a burst, and no group is left afterwards.
"""
from __future__ import annotations

import argparse
import json
import os
import re

import pytest

from bench import cli as bench_cli
from shadowless.cpu_budget import groups_of, host_hierarchy, unavailable
from shadowless.netns import namespaces as netns_names, parse_rate




@pytest.mark.slow
def test_venue_bench_discovers_and_distributes_to_every_node(ns, capsys, tmp_path):
    parser = argparse.ArgumentParser()
    bench_cli.configure(parser)
    keep = tmp_path / "run"
    budgets = not unavailable()
    args = parser.parse_args(["venue", "--nodes", "2", "--link", "100mbit", "--size", "320x180", "--fps", "30",
                              "--seconds", "1", "--output-size", "160x90", "--quick", "--keep", str(keep)]
                             + (["--node-cpu", "0.5"] if budgets else []))
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
    assert p["quick"] and p["only"] == ["timeline", "rejoin", "restart", "live"]
    assert "live_frames" not in doc           # the live figures are the `live` section (below)

    slots = set(doc["ready_s"])
    assert len(slots) == 2 and set(doc["live_s"]) == slots and set(doc["node_cpu_s"]) == slots
    # every node went live, after the processes started; discovery ends with the last one
    assert all(t > 0 for t in doc["live_s"].values())
    assert doc["discovery_s"] == max(doc["live_s"].values())
    # every node got the asset, after the first node was live; distribution ends with the last one
    assert all(t >= 0 for t in doc["ready_s"].values())   # a node may be seen live and ready in one poll
    assert doc["distribution_s"] > 0 and doc["distribution_s"] == max(doc["ready_s"].values())

    size = doc["asset_bytes"]
    assert size > 1000
    ideal = 2 * size * 8 / parse_rate("100mbit")
    assert doc["distribution_ideal_s"] == pytest.approx(ideal, abs=1e-4)
    # distribution_s is rounded to the millisecond, the ratio computed before rounding
    assert abs(doc["distribution_ratio"] - doc["distribution_s"] / ideal) <= 0.0006 / ideal + 0.001
    assert doc["distribution_ratio"] > 0.5          # never faster than the links allow
    assert doc["throughput_mbit_s"] == pytest.approx(2 * size * 8 / doc["distribution_s"] / 1e6,
                                                     rel=0.02 + 0.0006 / doc["distribution_s"])
    assert doc["coordinator_cpu_s"] >= 0 and all(v >= 0 for v in doc["node_cpu_s"].values())

    # the work directory is kept: the rig's store and every node's cache hold the video's bytes
    assert doc["workdir"] == str(keep)
    blobs = [f for f in (keep / "rig" / "assets" / "blobs").rglob("*") if f.is_file()]
    assert len(blobs) == 1 and blobs[0].stat().st_size == size
    for slot in slots:
        assert any(f.stat().st_size == size for f in (keep / "caches" / slot).rglob("*") if f.is_file()), slot

    # the timeline show: every tick accounted for, nothing out of order, no frame data sent
    tl = doc["timeline"]
    assert tl["nodes"] == 2 and tl["frames_expected"] == 30       # 1 s at 30 fps, not looped
    assert tl["tracked_before_show"] == 0                          # the tracker's figures are the show's
    assert 0 <= tl["late_fraction"] <= 1
    assert tl["late_fraction"] == pytest.approx(tl["late"] / (2 * 30), abs=1e-4)
    assert 0 <= tl["frames_shown_by_all"] <= tl["frames_expected"]
    assert tl["out_of_order"] == 0
    if tl["frames_shown_by_all"] > 0:
        assert tl["skew_source"] == "host-clock"
        assert 0 <= tl["skew_p50_ms"] <= tl["skew_p99_ms"] <= tl["skew_max_ms"]
    assert tl["frame_bytes_sent"] == 0 and tl["coordinator_bytes_sent"] > 0
    assert tl["raw_bytes_per_s_per_node"] == 320 * 180 * 3 * 30
    assert 0 < tl["coordinator_bytes_per_s_per_node"] < tl["raw_bytes_per_s_per_node"] / 100
    assert tl["coordinator_bytes_per_s_per_node"] == pytest.approx(
        tl["coordinator_bytes_sent"] / tl["interval_s"] / 2, rel=0.01)
    assert set(tl["node_cpu_share"]) == slots and doc["decode_ms_per_frame"] > 0

    # the rejoin: the restarted node came back on the show's ticks, after its restart
    rj = doc["rejoin"]
    assert rj["node"] in slots and rj["s"] > 0
    assert rj["ticks_compared"] > 0 and 0 <= rj["ticks_missed"] <= rj["ticks_compared"]
    assert 0 <= rj["frame_agreement"] <= 1 and 0 <= rj["peer_agreement"] <= 1
    assert 0 < rj["joined_s"] <= rj["asset_passed_s"]     # the log's steps of the rejoin, in order
    assert rj["frame_agreement"] == pytest.approx(1 - rj["ticks_missed"] / rj["ticks_compared"], abs=1e-4)
    assert rj["show_s"] >= 4 and rj["out_of_order"] == 0

    # the coordinator killed mid-show and restarted: every node played on alone and was taken back
    cr = doc["coordinator_restart"]
    assert cr["show_taken_back"] and cr["outage_s"] >= 2.5 and cr["back_s"] > 0
    assert cr["ticks_during_outage"] > 0 and set(cr["ticks_swapped_alone"]) == slots
    assert all(0 < n <= cr["ticks_during_outage"] for n in cr["ticks_swapped_alone"].values())
    assert cr["frames_missed"] == sum(cr["frames_missed_by_node"].values())
    assert 0 <= cr["frames_missed"] <= 2 * cr["ticks_in_window"]
    assert cr["out_of_order"] == 0
    assert all(a >= 2_000 for a in cr["alone_ms"].values())      # each node says it went on alone
    # the restart's own share: the misses from the kill on, less the nodes' rate before it (--quick: 0.5 s of it)
    bg = cr["background"]
    assert bg["ticks"] > 0 and 0 <= bg["missed"] <= bg["ticks"] and bg["per_tick"] == round(bg["missed"] / bg["ticks"], 5)
    assert cr["frames_missed_after_kill"] == sum(p["outage"] + p["after_restart"]
                                                 for p in cr["frames_missed_by_phase"].values())
    assert 0 < cr["ticks_after_kill"] < cr["ticks_in_window"] * len(slots)
    assert cr["frames_missed_restart_share"] <= cr["frames_missed_after_kill"]
    if budgets:
        assert cr["throttle_sampler"]["samples"] > 0 and cr["throttle_sampler"]["cpu_ms"] > 0
    # where the missed ticks fell, and what each node did and spent while it rejoined
    for s in slots:
        phases, around = cr["frames_missed_by_phase"][s], cr["missed_around_join"][s]
        assert sum(phases.values()) == cr["frames_missed_by_node"][s]
        assert sum(around.values()) == phases["after_restart"]
        assert 0 <= cr["frames_missed_late_drops"][s] <= cr["frames_missed_by_node"][s]
        # each missed tick has one cause; the late drops are those with a logged drop
        causes = cr["frames_missed_causes"][s]
        assert sum(causes.values()) == cr["frames_missed_by_node"][s]
        assert causes["not_dropped"] == cr["frames_missed_by_node"][s] - cr["frames_missed_late_drops"][s]
        if budgets:
            assert cr["throttles_per_s"][s] >= 0
        steps = cr["rejoin_stages_ms"][s]
        assert 0 < steps["joined"] <= steps["clock"] and steps["joined"] <= steps["wanted"]
        assert "assignment" not in steps and "show" not in steps     # nothing changed: nothing re-applied
        for when in ("alone", "rejoining"):
            assert cr["cpu_ms_per_tick"][when]["link"][s] >= 0 and cr["cpu_ms_per_tick"][when]["node"][s] > 0
    assert set(cr["link_cpu_ms_first_s_after_join"]) == slots     # None where this process's samples were starved
    rt = cr["restart_timeline"]
    assert rt["bin_s"] > 0 and len(rt["missed"]) == len(rt["coordinator_cpu_ms"]) and set(rt["joined_s"]) == slots
    assert sum(rt["missed"]) <= cr["frames_missed"]
    assert cr["skew_p99_ms_before"] == tl["skew_p99_ms"]

    # live frames: the natural sequence went as video, encoded once, far below raw frames
    lv = doc["live"]
    assert lv["size"] == "320x180" and lv["nodes"] == 2 and lv["fps"] == 30
    assert lv["frames"] == lv["frames_sent"] == 60                # --live-seconds 2 at 30 fps
    assert lv["raw_bytes_per_frame"] == 320 * 180 * 3
    assert 0 < lv["bytes_per_frame"] <= lv["raw_bytes_per_frame"] / 20
    assert lv["bytes_per_frame"] == pytest.approx(lv["frame_bytes_sent"] / (60 * 2), abs=1)
    assert lv["ratio"] == pytest.approx(lv["raw_bytes_per_frame"] / lv["bytes_per_frame"], rel=0.01)
    assert lv["video_bytes_per_frame"] <= lv["bytes_per_frame"] * 1.2   # the packets carry the pictures
    # 1080p natural video must reach 38 dB (tests/coordinator/test_live_video.py); at 320x180 the same
    # pan holds far more detail per pixel and 4:2:0 chroma bounds it near 34 dB
    assert lv["psnr_db_min"] >= 30 and lv["psnr_db_mean"] >= lv["psnr_db_min"]
    assert lv["encode_ms_per_frame"] > 0 and lv["encode_ms_per_frame_here"] > 0
    assert 0 <= lv["frames_shown"] <= lv["frames_sent"]
    assert doc["parameters"]["live_seconds"] == 2

    # CPU budgets: a group each, measuring what ran in it; none left afterwards
    if not budgets:
        assert doc["node_cpu_limit"] is None
        return
    assert doc["node_cpu_limit"] == 0.5 and doc["node_gpu_limit"] is None
    assert doc["coordinator_cpu_limit"] == max(0.5, doc["machine"]["cpus"] - 2 * 0.5)
    cb = doc["cpu_budget"]
    assert cb["period_ms"] == 10 and cb["rasterizer"].startswith("in a group of their own")
    # the nodes come first (ten times the coordinator's weight) and may burst by their quota, 5 ms a period
    assert cb["node_weight"] == 1000 and cb["coordinator_weight"] is None
    assert set(cb["node_burst_us"]) == slots and set(cb["node_burst_us"].values()) <= {0, 5000}
    groups = cb["groups"]
    assert set(groups) == {"bench", "coordinator"} | {f"{k} {s}" for k in ("node", "rasterizer") for s in slots}
    assert groups["coordinator"]["limit"] == doc["coordinator_cpu_limit"] and groups["bench"]["limit"] is None
    for s in slots:
        assert groups[f"node {s}"]["limit"] == 0.5 and groups[f"node {s}"]["cpu_s"] > 0
        # the rasterizer's thread (LP_NUM_THREADS=1) of every presenter it ran, the restarted node's too
        assert groups[f"rasterizer {s}"]["threads"] >= (2 if s == doc["rejoin"]["node"] else 1)
        assert groups[f"rasterizer {s}"]["cpu_s"] > 0
    assert groups["coordinator"]["cpu_s"] > 0 and groups["bench"]["cpu_s"] > 0
    assert all(g["throttled_s"] >= 0 for g in groups.values())
    assert all(tl["cpu_budget"][f"node {s}"]["cpu_s"] > 0 for s in slots)    # the show's share of it
    assert groups_of(os.getpid()) == []                    # this process went back to the root group
    hierarchy, _ = host_hierarchy()
    assert not [d.name for d in hierarchy.root.iterdir() if d.name.startswith("shadowless-")
                and f"-{os.getpid()}-" in d.name], "every group the run made is removed"
