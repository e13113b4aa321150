"""The planner: cached evaluation against brute force, the search against exhaustive search, the command's files."""
from __future__ import annotations

import argparse
import itertools
import json

import cv2
import numpy as np
import pytest

from sim.hand import Hand
from sim.occluders import segment_blocked
from sim.optics import irradiance_factor
from planner import cli as plan_cli
from planner.candidates import (
    ProjectorModel,
    ceiling_grid,
    from_file,
    source_for,
    walls,
)
from planner.evaluate import PLAN_PROXIES, Evaluator, proxy_of
from planner.search import knee, plan
from planner.surface import irradiance, table_surface
from sim.scene import load_layout, reference_scene
from studies.proxies import point_proxies

HANDS = [Hand(position=(-150.0, 0.0), height=150.0), Hand(position=(200.0, 80.0), height=250.0, yaw_deg=30.0)]


def _evaluator(cols=3, rows=3, *, pitch=25.0, proxy="max_drop", hands=HANDS):
    surface = table_surface((1200.0, 600.0), pitch=pitch)
    sources = [source_for(c, surface.target, surface.corners, ProjectorModel()) for c in ceiling_grid(cols, rows)]
    return Evaluator(surface, sources, irradiance(surface, sources), hands, proxy=proxy)


def test_ceiling_grid_is_the_reference_rig_and_fitted_images_cover_the_table():
    ref = reference_scene(jitter=False)
    grid = {c.name: c.position for c in ceiling_grid(5, 5)}
    for p in ref.projectors:
        if p.slot.startswith("r"):
            r, c = int(p.slot[1]), int(p.slot[3])
            np.testing.assert_allclose(grid[f"g{r}_{c}"], p.native.center, atol=1e-9)
    ev = _evaluator(5, 5, pitch=50.0)
    assert (ev.E > 0).all()  # every candidate lights every table sample
    assert len(walls(3, heights=(700.0,))) == 12


def test_candidates_file(tmp_path):
    f = tmp_path / "c.csv"
    f.write_text("# x,y,z,name\n0,0,1400,centre\n\n100, 50, 1300\n")
    got = from_file(f)
    assert [c.name for c in got] == ["centre", "c1"] and got[1].position == (100.0, 50.0, 1300.0)
    f.write_text("0,0\n")
    with pytest.raises(ValueError, match=r"c.csv:1"):
        from_file(f)


def test_cached_drop_matches_brute_force_ray_tests():
    ev = _evaluator(pitch=25.0)
    subset = [0, 4, 8, 2]
    pts = ev.surface.points
    up = np.array([0.0, 0.0, 1.0])
    vals = []
    for hand in HANDS:
        tot = blk = 0.0
        for i in subset:
            s = ev.sources[i]
            e = irradiance_factor(s.device.center, s.device.axis, pts, up)
            tot = tot + e
            blk = blk + e * segment_blocked(pts, s.center, hand.primitives())
        vals.append((blk / tot).max())
    # the raster may add outline samples, so the cached maximum is at least the exact one, and close
    got = ev.value(subset)
    assert np.mean(vals) - 1e-9 <= got <= np.mean(vals) + 0.1
    with_each = ev.with_each(subset[:3])
    assert with_each[2] == pytest.approx(ev.value(subset[:3] + [2]), abs=1e-6)


def test_planner_proxies_are_the_sop_module_s():
    """Every proxy the planner minimises is :func:`studies.proxies.point_proxies`' figure of the same drop map."""
    rng = np.random.default_rng(4)
    drop = np.concatenate([np.zeros(50), np.full(30, 0.005), rng.uniform(0, 1, 400), np.ones(20), np.full(10, 0.9)])
    area = rng.uniform(1, 3, drop.size)
    ref = point_proxies(drop, area)
    for name in PLAN_PROXIES:
        assert float(proxy_of(drop.astype(np.float32)[None], area.astype(np.float32), name)[0]) == pytest.approx(ref[name], rel=1e-5), name


def test_the_plan_is_swap_optimal_by_exhaustive_check():
    ev = _evaluator(3, 3, pitch=40.0, proxy="area_above_10_mm2")
    res = plan(ev, 3)
    assert res.value == pytest.approx(ev.value(res.chosen))
    for pos, c in itertools.product(range(3), range(ev.candidates)):
        if c not in res.chosen:
            swapped = res.chosen[:pos] + [c] + res.chosen[pos + 1:]
            assert ev.value(swapped) >= res.value - 1e-6
    every = sorted(ev.value(list(s)) for s in itertools.combinations(range(ev.candidates), 3))
    assert res.value <= every[len(every) // 10]  # among the best tenth of all 84 choices
    assert res.value <= res.curve[-1] + 1e-9 and len(res.curve) == 3
    with pytest.raises(ValueError):
        plan(ev, 10)


def test_coverage_comes_first():
    ev = _evaluator(3, 3, pitch=50.0)
    ev.E[4, : ev.surface.size // 2] = 0.0  # the centre candidate lights only half the table
    res = plan(ev, 1, k=1)
    assert res.chosen != [4] and res.uncovered == 0.0


def test_knee():
    assert knee([1.0, 0.6, 0.45, 0.44, 0.435, 0.434], 0.5) == 3
    assert knee([1.0, 0.9, 0.8], 0.5) is None


def test_plan_command_writes_a_layout_the_room_reads_and_a_picture(tmp_path, capsys):
    parser = argparse.ArgumentParser()
    plan_cli.configure(parser)
    layout, png = tmp_path / "p.toml", tmp_path / "p.png"
    args = parser.parse_args(["--grid", "4x4", "--budget", "3", "--pitch", "50", "--heights", "200", "--yaws", "0",
                              "--layout", str(layout), "--picture", str(png), "--json"])
    assert plan_cli.run(args) == 0
    doc = json.loads(capsys.readouterr().out)
    scene = load_layout(layout)
    assert [p.slot for p in scene.projectors] == [c["slot"] for c in doc["chosen"]]
    for p, c in zip(scene.projectors, doc["chosen"]):
        np.testing.assert_allclose(p.native.center, c["position_mm"], atol=0.1)
    assert len(doc["curve"]) == 3 and doc["curve"][0] == 1.0 and doc["uncovered_mm2"] == 0.0
    img = cv2.imread(str(png))
    assert img is not None and img.shape[0] >= 300
    with pytest.raises(SystemExit, match="exceeds"):
        plan_cli.run(parser.parse_args(["--grid", "2x2", "--budget", "5"]))
