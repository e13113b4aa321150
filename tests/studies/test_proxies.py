"""SoP proxies: shadow polygons against ray tests, proxies against closed forms, one CLI run."""
from __future__ import annotations

import argparse
import json
import math

import numpy as np
import pytest
from scipy import ndimage

from studies import proxies_cli as sop_cli
from sim.geometry import Pinhole, intrinsics, look_at
from sim.hand import Hand
from sim.occluders import Sphere, segment_blocked
from sim.optics import irradiance_factor
from studies.proxies import (
    UMBRA_WEIGHT,
    PoseSet,
    ShadowRasters,
    Viewing,
    edge_per_arcmin,
    orderings,
    point_proxies,
    umbra_weight_interval,
)
from sim.sop_shadows import (
    Grid,
    Source,
    rasterize,
    resample,
    shadow_polygons,
    table_irradiance,
)


def _source(name, pos) -> Source:
    R, t = look_at(np.asarray(pos, float), np.zeros(3))
    return Source(name, Pinhole(intrinsics((1280, 800), focal=1100.0), R, t, (1280, 800)))


def test_hand_shadow_polygons_match_ray_tests():
    hand = Hand(position=(60.0, -40.0), height=150.0, yaw_deg=20.0)
    source = np.array([250.0, 120.0, 1400.0])
    grid = Grid(-250.0, -350.0, 1.0, (500, 500))
    mask = rasterize(shadow_polygons(source, hand.primitives()), grid)
    truth = segment_blocked(grid.points(), source, hand.primitives()).reshape(grid.shape)
    assert truth.sum() > 10000  # a real shadow inside the window
    assert not (truth & ~mask).any()  # nothing in the shadow is missed
    extra = mask & ~truth  # OpenCV fills the samples the outline passes through
    outline = ndimage.binary_dilation(truth) & ~truth
    assert not (extra & ~outline).any()
    assert extra.sum() < 0.6 * outline.sum()


def test_sphere_shadow_is_the_closed_form_disc():
    r, zc, H = 40.0, 300.0, 1400.0
    poly = shadow_polygons(np.array([0.0, 0.0, H]), [Sphere((0, 0, zc), r)])[0]
    radius = H * math.tan(math.asin(r / (H - zc)))
    assert np.linalg.norm(poly, axis=1).max() == pytest.approx(radius, rel=1e-3)
    grid = Grid(-80.0, -80.0, 0.25, (641, 641))
    area = rasterize([poly], grid).sum() * grid.cell_area
    assert area == pytest.approx(math.pi * radius**2, rel=0.01)


def test_irradiance_is_the_room_model_and_resamples_smoothly():
    s = _source("a", (300.0, -200.0, 1400.0))
    coarse = Grid.covering((1200.0, 600.0), 10.0)
    e = table_irradiance(coarse, s)
    pts = coarse.points()
    ref = irradiance_factor(s.device.center, s.device.axis, pts, np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(e.ravel(), ref, rtol=1e-12)
    fine = Grid(-100.25, 50.5, 0.5, (40, 60))
    got = resample(e, coarse, fine)
    direct = irradiance_factor(s.device.center, s.device.axis, fine.points(), np.array([0.0, 0.0, 1.0])).reshape(fine.shape)
    np.testing.assert_allclose(got, direct, rtol=2e-3)


def test_point_proxies_of_a_known_map():
    yy, xx = np.mgrid[0:200, 0:200]
    r = np.hypot(xx - 100, yy - 100)
    drop = np.where(r <= 20, 1.0, np.where(r <= 50, 0.3, np.where(r <= 70, 0.05, 0.0)))
    p = point_proxies(drop, 4.0)   # 2 mm samples
    count = lambda m: float(m.sum()) * 4.0
    assert p["max_drop"] == 1.0
    assert p["umbra_mm2"] == count(r <= 20)
    assert p["area_above_10_mm2"] == count(r <= 50)
    assert p["penumbra_mm2"] == count((r > 20) & (r <= 70))
    assert p["umbra_mm2"] == pytest.approx(math.pi * 40**2, rel=0.03)
    assert p["shadow_mm2"] == p["penumbra_mm2"] + UMBRA_WEIGHT * p["umbra_mm2"]


def test_umbra_weight_interval_is_where_every_ordering_holds():
    """Made-up areas whose orderings bound w by hand: P1 worst needs 100 w > 180 (w > 1.8), P9D
    before P9W needs 100 + 20 w < 160 (w < 3); P17, P20, P25 alike and P20 <= P25 hold for any w."""
    umbra = {"P1": 100.0, "P9D": 20.0, "P9W": 0.0, "P13": 0.0, "P17": 0.0, "P20": 0.0, "P25": 0.0}
    pen = {"P1": 0.0, "P9D": 100.0, "P9W": 160.0, "P13": 170.0, "P17": 180.0, "P20": 180.0, "P25": 180.0}
    results = {k: {"umbra_mm2": umbra[k], "penumbra_mm2": pen[k]} for k in umbra}
    lo, hi = umbra_weight_interval(results, weights=np.linspace(0, 10, 10001))
    assert lo == pytest.approx(1.8, abs=2e-3) and hi == pytest.approx(3.0, abs=2e-3)
    assert umbra_weight_interval(dict(results, P9D={"umbra_mm2": 20.0, "penumbra_mm2": 200.0})) is None


def test_edge_gradient_of_a_step_is_its_height_over_the_blur():
    viewing = Viewing(distance_mm=800.0, edge_sigma_mm=1.0, pitch_mm=0.25)
    grid = Grid(0.0, 0.0, 0.25, (80, 160))
    x, _ = grid.xy()
    drop = np.where(x > 20.1, 0.3, 0.0)
    per_mm = 0.3 / (math.sqrt(2 * math.pi) * 1.0)
    assert viewing.mm_per_arcmin == pytest.approx(800 * math.tan(math.radians(1 / 60)))
    assert edge_per_arcmin(drop, grid, viewing) == pytest.approx(per_mm * viewing.mm_per_arcmin, rel=0.03)


def test_drop_of_a_subset_matches_brute_force_at_samples():
    sources = {n: _source(n, p) for n, p in {"a": (-250, 0, 1400), "b": (250, 0, 1400), "c": (0, 250, 1400)}.items()}
    rasters = ShadowRasters(sources, (1200.0, 600.0), Viewing(pitch_mm=1.0, edge_sigma_mm=2.0))
    hand = Hand(position=(0.0, 0.0), height=120.0)
    pose = rasters.pose(hand)
    rng = np.random.default_rng(1)
    rows = rng.integers(0, pose.grid.shape[0], 300)
    cols = rng.integers(0, pose.grid.shape[1], 300)
    x, y = pose.grid.xy()
    pts = np.column_stack([x[rows, cols], y[rows, cols], np.zeros(300)])
    up = np.array([0.0, 0.0, 1.0])
    tot = blk = 0.0
    for s in sources.values():
        e = irradiance_factor(s.device.center, s.device.axis, pts, up)
        tot = tot + e
        blk = blk + e * segment_blocked(pts, s.center, hand.primitives())
    want = blk / tot
    e = {n: pose.irradiance[n][rows, cols] for n in sources}
    got = sum(e[n] * pose.masks[n][rows, cols] for n in sources) / sum(e.values())
    # the same except at samples on a shadow outline
    assert np.mean(np.abs(got - want) < 1e-3) > 0.97
    assert rasters.proxies(pose, list(sources))["max_drop"] == pytest.approx(1.0)  # a hand 120 mm up blocks all three at its centre


def test_orderings_on_made_up_values():
    good = {"P1": 1.0, "P9D": 0.5, "P9W": 0.6, "P13": 0.5, "P17": 0.42, "P20": 0.40, "P25": 0.41}
    assert all(orderings(good).values())
    bad = dict(good, P9D=0.7, P20=0.45, P17=0.6)
    assert orderings(bad) == {"p1_worst": True, "dense_beats_wide_9": False, "p17_p20_p25_alike": False, "p20_not_worse_than_p25": False}
    with pytest.raises(ValueError):
        orderings({"P1": 1.0})


def test_study_proxies_command(capsys):
    parser = argparse.ArgumentParser()
    sop_cli.configure(parser)
    assert "--edge-sigma" in parser.format_help()
    args = parser.parse_args(["--xs", "0", "--ys", "0", "--heights", "200", "--yaws", "0", "--json"])
    assert sop_cli.run(args) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["poses"]["count"] == 1 and doc["chosen"] == "max_drop"
    v = doc["proxies"]
    assert v["P1"]["max_drop"] == 1.0 and v["P1"]["copies"] == 1.0
    assert v["P25"]["max_drop"] < v["P9D"]["max_drop"] < 1.0
    assert doc["orderings"]["max_drop"]["p1_worst"] is True
    assert doc["umbra_weight_interval"] is None or doc["umbra_weight_interval"][0] <= doc["umbra_weight_interval"][1]
    assert v["P25"]["shadow_mm2"] == pytest.approx(v["P25"]["penumbra_mm2"] + UMBRA_WEIGHT * v["P25"]["umbra_mm2"], abs=1e-3)
    with pytest.raises(SystemExit, match="half"):
        sop_cli.run(parser.parse_args(["--pitch", "1", "--edge-sigma", "1"]))


def test_pose_set_counts_every_combination():
    ps = PoseSet(xs=(0.0, 1.0), ys=(0.0,), heights=(100.0, 200.0, 300.0), yaws=(0.0, 30.0))
    assert len(ps.hands()) == ps.describe()["count"] == 12
