"""`shadowless bench compensation`: the current and the new solver side by side, and the bandwidth probe."""
from __future__ import annotations

import argparse
import json

import pytest

from bench import compensation
from bench.machine import streaming_bandwidth


def run_bench(capsys, argv):
    parser = argparse.ArgumentParser()
    compensation.configure(parser)
    args = parser.parse_args(argv)
    assert compensation.run(args) == 0
    return json.loads(capsys.readouterr().out)


def test_streaming_bandwidth_measures_a_copy_and_a_read():
    bw = streaming_bandwidth(mib=64, threads=2, repeats=3)
    assert 0 < bw["gb_per_s_median"] <= bw["gb_per_s"] and bw["threads"] == 2 and len(bw["load"]) == 3
    assert bw["read_gb_per_s"] > 0 and bw["read_over_copy"] == pytest.approx(bw["read_gb_per_s"] / bw["gb_per_s"], rel=0.01)


def test_current_and_new_side_by_side(capsys):
    doc = run_bench(capsys, ["--quick", "--size", "none", "--paper-size", "96x64", "--paper-channels", "3",
                             "--video-size", "80x48", "--video-frames", "5", "--video-new-iterations", "6",
                             "--paper-reference-seconds", "2"])
    assert doc["per_projectors"] == [] and doc["video_more"] == []
    p = doc["paper_size"]
    cur, new, u16, plain = p["current"], p["new"], p["new_uint16"], p["new_target_start"]
    assert (cur["storage"], new["storage"], u16["storage"], plain["storage"]) == ("csr", "float32", "uint16", "float32")
    assert new["fused"] and not cur["fused"]
    # the same problem from the same start to the same stopping rule: the same iterations, objectives within rounding
    assert plain["iterations"] == cur["iterations"] > 3
    assert plain["objective"] == pytest.approx(cur["objective"], rel=1e-4)
    # from the deconvolved start: fewer iterations to the same rule
    assert new["iterations"] < plain["iterations"]
    assert p["new_over_new_target_start"]["iterations"] == round(new["iterations"] / plain["iterations"], 3)
    for s in (cur, new, u16, plain):
        assert 0 <= s["relative_gap_to_reference"] <= 0.01
        assert s["bandwidth_fraction"] > 0 and s["solver_peak_memory_mib"] > 0
        # the iterations alone, and the solve's time before the first of them (a part of the solve's)
        assert s["loop_seconds_per_iteration"] > 0 and 0 <= s["start_seconds"] <= s["solve_seconds"] + 1e-3
        assert s["loop_bandwidth_fraction"] == pytest.approx(
            s["bytes_per_iteration"] / s["loop_seconds_per_iteration"] / (p["streaming_bandwidth"]["before"]["gb_per_s"] * 1e9),
            rel=0.01)
    # 25 float32 weights (once per iteration) against 2 x 25 x (value + index) bytes per pixel
    assert u16["bytes_per_iteration"] < new["bytes_per_iteration"] < cur["bytes_per_iteration"] / 2
    assert p["new_over_current"]["bytes_per_iteration"] == pytest.approx(
        new["bytes_per_iteration"] / cur["bytes_per_iteration"], abs=1e-3)
    assert p["streaming_bandwidth"]["before"]["gb_per_s"] > 0
    frac = doc["targets"]["paper_size_bandwidth_fraction"]
    assert frac["iterations_alone"] == new["loop_bandwidth_fraction"]
    assert frac["read_only_ceiling"] == p["streaming_bandwidth"]["before"]["read_over_copy"] > 0
    v = doc["video"]
    assert v["iterations_per_frame"] == {"current": 4, "new": 6}
    for clip in ("pan", "overlay"):
        c, n = v["current"][clip], v["new"][clip]
        assert c["storage"] == "csr" and n["storage"] == "float32"
        assert c["iterations_per_frame_mean"] == 4 and n["iterations_per_frame_mean"] == 6
        # the new warm start (deconvolved change + carried correction) stays within the target of converged
        assert n["psnr_short_of_converged_max_db"] <= min(0.5, c["psnr_short_of_converged_max_db"] + 0.02)
        assert v[clip]["ms_per_frame_mean"] == n["ms_per_frame_mean"] and v[clip]["new_over_current_ms_per_frame"] > 0
    assert "paper_size_rgb_solver_peak_gib" in doc["targets"] and "video_80x48" in doc["targets"]


def test_storage_names_are_checked(capsys):
    parser = argparse.ArgumentParser()
    compensation.configure(parser)
    with pytest.raises(SystemExit) as exc:
        parser.parse_args(["--paper-storage", "float16"])
    assert exc.value.code == 2
    assert "storages are float32, uint16" in capsys.readouterr().err
