"""Operator tables drawn with rich: `shadowless status` and `content list` keep every column and
fact, plain and uncut when not on a terminal, node states coloured on one."""
from __future__ import annotations

import json

import pytest

from coordinator.api import (AssetProgress, NodeShow, NodeShowState, NodeState, NodeStatus, RefusedPeer, RigStatus,
                             SyncSummary)
from rigctl.commands import status_dict, status_table
from rigctl.content_format import assets_table, print_assets
from protos.asset_manifest import Blob, Manifest

HOST = "projector-box-with-a-long-name.local"      # longer than the old 15-character cut


def rig_status() -> RigStatus:
    card = AssetProgress(asset_id="c" * 64, name="card", have_bytes=10, total_bytes=10, ready=True)
    clip = AssetProgress(asset_id="d" * 64, name="clip", have_bytes=4, total_bytes=30,
                         error="blob clip.mp4 failed its hash check 3 times")
    nodes = (
        NodeStatus(slot="r0c0", state=NodeState.LIVE, hostname=HOST, clock_offset_ms=1.2344, clock_drift_ppm=2.54,
                   clock_rtt_ms=0.3211, last_swap_frame=1234, frames_shown=100, frames_late=1, frames_dropped=2,
                   pose_kind="homography", assets_wanted=2, assets_ready=1, asset_bytes_have=14, asset_bytes_total=40,
                   assets=(card, clip), show=NodeShow(state=NodeShowState.PLAYING, last_frame=17, alone_ms=2500.0)),
        NodeStatus(slot="r0c1", state=NodeState.LOST, hostname="b"),
        NodeStatus(slot="r1c0", state=NodeState.EXPECTED),
    )
    return RigStatus(rig_id="rig-1", rig_name="hall", instance_id="i-9", uptime_s=61.0, showing="image logo",
                     nodes=nodes, sync=SyncSummary(frames=50, skew_p50_ms=0.25, skew_p99_ms=0.5, skew_max_ms=0.75,
                                                   skew_source="estimates", frames_late=3),
                     refusals=(RefusedPeer(peer="10.0.0.9", slot="r9c9", reason="not in the rig", age_s=4.0, count=2),))


def test_the_status_table_has_every_node_and_fact_in_plain_text():
    d = status_dict(rig_status())
    text = status_table(d)
    assert "\x1b" not in text and "\r" not in text
    lines = text.splitlines()
    assert lines[0] == "rig hall (rig-1)  instance i-9  up 1 min 1 s  showing: image logo"
    assert lines[1].split() == ["slot", "state", "host", "offset", "ms", "drift", "ppm", "rtt", "ms", "last", "swap",
                                "shown", "late", "drop", "pose", "show", "assets"]
    row = next(line for line in lines if line.startswith("r0c0"))
    assert row.split() == ["r0c0", "live", HOST, "1.234", "2.5", "0.321", "frame", "17", "100", "1", "2", "homography",
                           "playing", "17", "1/2", "35%!"]
    assert next(line for line in lines if line.startswith("r0c1")).split()[:3] == ["r0c1", "lost", "b"]
    assert next(line for line in lines if line.startswith("r1c0")).split()[:3] == ["r1c0", "expected", "-"]
    assert "r0c0: went on without the coordinator for 2.5 s (its last outage)" in lines
    assert f"r0c0: asset {'d' * 12} (clip): blob clip.mp4 failed its hash check 3 times" in lines
    assert ("sync: 50 frames, skew p50 0.250 ms, p99 0.500 ms, max 0.750 ms (estimates); late 3, dropped 0, "
            "out of order 0") in lines
    assert "refused 10.0.0.9 r9c9: not in the rig (2x, last 4 s ago)" in lines


def test_node_states_are_coloured_on_a_terminal(monkeypatch):
    monkeypatch.delenv("NO_COLOR", raising=False)
    monkeypatch.setenv("TERM", "xterm-256color")
    text = status_table(status_dict(rig_status()), tty=True)
    assert "\x1b[32mlive" in text and "\x1b[31mlost" in text and "\x1b[33mexpected" in text
    assert "r0c1" in text and "sync: 50 frames" in text


def test_the_status_json_is_unchanged_by_the_table():
    d = status_dict(rig_status())
    assert json.loads(json.dumps(d))["nodes"][0]["host"] == HOST and d["nodes"][0]["assets"]["percent"] == 35.0


def manifest(kind: str, name: str, sha: str, **kw) -> Manifest:
    return Manifest(kind=kind, name=name, blobs=(Blob(sha256=sha * 64, size=2_500_000, name="a.png"),), width=64,
                    height=48, channels=3, bit_depth=8, **kw)


def test_the_assets_table_lists_names_and_ids(capsys):
    long_name = "a still with a name longer than twenty-two characters"
    rows = [("e" * 64, manifest("still", long_name, "1", frames=1)),
            ("f" * 64, manifest("video", "clip", "2", frames=90, fps=29.97))]
    text = assets_table(rows)
    assert "\x1b" not in text
    lines = text.splitlines()
    assert lines[0].split() == ["id", "kind", "name", "frames", "size", "depth", "fps", "duration", "bytes"]
    still = next(line for line in lines if line.startswith("e" * 12))
    assert still.split() == ["e" * 12, "still", *long_name.split(), "1", "64x48", "3x8", "-", "-", "2.5", "MB"]
    clip = next(line for line in lines if line.startswith("f" * 12))
    assert clip.split() == ["f" * 12, "video", "clip", "90", "64x48", "3x8", "29.97", "3.00", "s", "2.5", "MB"]

    print_assets(rows, as_json=False)
    assert capsys.readouterr().out == text + "\n"
    print_assets(rows, as_json=True)
    assert [a["name"] for a in json.loads(capsys.readouterr().out)] == [long_name, "clip"]


@pytest.mark.parametrize("tty", [False, True])
def test_an_empty_store_says_how_to_add_an_asset(tty):
    text = assets_table([], tty=tty)
    assert "id" in text and text.endswith("(no assets; add one with `shadowless content add PATH`)")


def test_the_status_says_what_each_node_renders_with_and_runs():
    from dataclasses import replace

    st = rig_status()
    gl31, gl45 = "OpenGL 3.1, GLSL 1.40, V3D 4.2", "OpenGL 4.5, GLSL 3.30, llvmpipe"
    nodes = (replace(st.nodes[0], gl=gl31, software_version="0.2.0", output="kms"),
             replace(st.nodes[1], gl=gl45, software_version="0.2.0", output="window"), st.nodes[2])
    d = status_dict(replace(st, nodes=nodes))
    assert [(n["gl"], n["software"], n["output"]) for n in d["nodes"]] == [
        (gl31, "0.2.0", "kms"), (gl45, "0.2.0", "window"), ("", "", "")]
    lines = status_table(d).splitlines()
    assert f"renders with {gl31}: r0c0 (1)" in lines and f"renders with {gl45}: r0c1 (1)" in lines
    assert "runs shadowless 0.2.0: r0c0, r0c1 (2)" in lines
    same = status_table(status_dict(replace(st, nodes=tuple(replace(n, gl=gl31) for n in st.nodes)))).splitlines()
    assert f"every node renders with {gl31}" in same
