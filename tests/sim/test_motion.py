"""The motion study's numerics: paths, figures against closed forms, per-frame drops against the room's truth."""
from __future__ import annotations

import math

import numpy as np
import pytest

from bench.room import _pixel_areas
from sim.motion import (
    THRESHOLDS,
    MotionResult,
    WavePath,
    drop_figures,
    gesture,
    overbright_figures,
    reach_path,
    run_motion,
    table_pixel_area,
    touch_path,
)
from sim.precompute import TABLE
from sim.reactive import ReactiveSpec
from sim.room import Room
from sim.scene import SUBSETS, reference_scene


@pytest.fixture(scope="module")
def room():
    r = Room(reference_scene(camera_scale=0.1, seed=0), seed=0, noise=False)
    r.prepare()
    return r


def test_wave_path_is_the_sine_it_states():
    p = WavePath(center=(10.0, -20.0), amplitude=250.0, period=1.0, height=200.0)
    for t in (0.0, 0.1, 0.25, 0.6, -0.1):
        h = p.hand_at(t)
        assert h.position == pytest.approx((10.0 + 250.0 * math.sin(2 * math.pi * t), -20.0))
        assert h.lowest_z() == pytest.approx(200.0)


def test_reach_and_touch_paths():
    r = reach_path(height=200.0)
    assert r.hand_at(0.0).position[1] == pytest.approx(-520.0) and r.hand_at(1.5).lowest_z() == pytest.approx(200.0)
    t = touch_path()
    down = t.hand_at(0.5)
    assert down.pose == "point" and down.lowest_z() == pytest.approx(0.0) and down.position == pytest.approx((-250.0, -40.0))
    assert t.hand_at(1.2 + 0.5).position == pytest.approx((200.0, 80.0)) and t.hand_at(0.0).lowest_z() == pytest.approx(150.0)
    assert gesture("wave", height=120.0).hand_at(0.0).lowest_z() == pytest.approx(120.0)
    with pytest.raises(ValueError, match="no gesture"):
        gesture("clap")


def test_pixel_area_closed_form_matches_finite_differences(room):
    view = room.view()
    closed = table_pixel_area(room.truth.table_to_camera_homography(), view.roi)
    surf = room.truth.surface()
    x0, y0, x1, y1 = view.roi
    diffs = _pixel_areas(surf.points)[y0:y1, x0:x1]  # the benchmark's own estimate, from neighbouring surface points
    table = view.kind == TABLE
    inner = table.copy()  # forward differences need the next pixel right and below on the table too
    inner[:-1] &= table[1:]
    inner[:, :-1] &= table[:, 1:]
    inner[-1, :] = inner[:, -1] = False
    np.testing.assert_allclose(closed[inner], diffs[inner], rtol=1e-3)
    # The pixels that see the table cover it (1200 x 600 mm), to within the half-pixel rim.
    assert closed[view.kind == TABLE].sum() == pytest.approx(1200 * 600, rel=0.01)


def test_figures_of_known_maps():
    yy, xx = np.mgrid[0:200, 0:300]
    r = np.hypot(xx - 150.0, yy - 100.0).ravel()
    area = np.full(r.shape, 4.0)
    area[:300] = 0.0  # off the table: never counted
    drop = np.clip(1.0 - r / 50.0, 0.0, 1.0)  # a cone: drop >= th within r <= 50 (1 - th)
    drop[0] = 1.0
    f = drop_figures(drop, area)
    assert f["max_drop"] == pytest.approx(1.0, abs=0.03)
    for th in THRESHOLDS:
        assert f[f"area_above_{round(100 * th)}_mm2"] == pytest.approx(math.pi * (50 * (1 - th)) ** 2 * 4.0, rel=0.05)
    assert f["deficit_mm2"] == pytest.approx(math.pi * 50**2 / 3 * 4.0, rel=0.02)  # the cone's volume
    light = 1.0 + 0.3 * (r <= 20)
    o = overbright_figures(light, area)
    assert o["max_overbright"] == pytest.approx(0.3)
    assert o["area_overbright_above_10_mm2"] == pytest.approx(math.pi * 400 * 4.0, rel=0.03)
    assert o["surplus_mm2"] == pytest.approx(0.3 * o["area_overbright_above_10_mm2"])
    with pytest.raises(ValueError):
        drop_figures(drop, area[:10])


def test_summary_integrates_frames_of_one_over_fps():
    frames = {"max_drop": np.array([0.2, 0.5]), "area_above_10_mm2": np.array([100.0, 300.0]),
              "area_above_50_mm2": np.array([0.0, 50.0]), "area_above_90_mm2": np.array([0.0, 10.0]), "deficit_mm2": np.array([4.0, 6.0])}
    res = MotionResult(fps=20.0, times=np.array([0.0, 0.05]), frames={"X": frames}, projectors={"X": 3}, reactive={}, table_mm2=1.0)
    s = res.summary()["X"]
    assert s["integrated_area_above_10_mm2_s"] == pytest.approx(20.0) and s["integrated_deficit_mm2_s"] == pytest.approx(0.5)
    assert s["max_drop"] == 0.5 and s["umbra_visible_s"] == pytest.approx(0.05) and s["peak_area_above_10_mm2"] == 300.0


def test_passive_drops_are_the_rooms_truth(room):
    path = WavePath(amplitude=200.0, period=1.0)
    seen = []
    run_motion(room, path, duration=0.2, fps=10, subsets=["P1", "P9D", "P25", "P2"], on_frame=seen.append)
    assert [f.time for f in seen] == pytest.approx([0.0, 0.1])
    x0, y0, x1, y1 = room.view().roi
    f = seen[1]
    room.set_occluders([path.hand_at(f.time)])
    try:
        for name, slots in [("P1", SUBSETS["P1"]), ("P9D", SUBSETS["P9D"]), ("P25", SUBSETS["P25"]), ("P2", ["r2c0", "r2c4"])]:
            room.set_active(slots)
            truth = room.truth.light_drop()[y0:y1, x0:x1].ravel()
            np.testing.assert_allclose(1.0 - f.light[name], truth, atol=1e-5)
        assert f.hand.reshape(f.shape).sum() == room.truth.occluder_mask()[y0:y1, x0:x1].sum() > 0
    finally:
        room.set_active(room.slots)
        room.set_occluders([])


def test_reactive_lags_a_moving_hand_and_restores_a_still_one(room):
    specs = [ReactiveSpec(0.1), ReactiveSpec(0.1, subset="P2", suppress=True), ReactiveSpec(0.0)]
    still = run_motion(room, WavePath(amplitude=0.0), duration=0.2, fps=20, subsets=["P25"], reactive=specs).summary()
    assert still["P25"]["max_drop"] > 0.3  # the passive soft shadow
    assert still["reactive_100ms"]["max_drop"] == pytest.approx(0.0, abs=1e-5)
    assert still["reactive_100ms"]["max_overbright"] == pytest.approx(0.0, abs=1e-5)
    # Through the middle of the wave the hand moves ~150 mm in 100 ms: shadow where it is, ghost where it was.
    moving = run_motion(room, WavePath(amplitude=250.0), duration=0.1, fps=20, subsets=["P25"], reactive=specs).summary()
    lag = moving["reactive_100ms"]
    assert lag["max_drop"] > 0.3 and lag["max_overbright"] > 0.3 and lag["integrated_area_overbright_above_10_mm2_s"] > 0
    assert lag["max_drop"] <= moving["P25"]["max_drop"] + 1e-6  # boosting never darkens below passive
    assert moving["reactive_0ms"]["max_drop"] == pytest.approx(0.0, abs=1e-5)
    assert moving["P25"]["integrated_area_above_90_mm2_s"] == 0
    assert moving["reactive_100ms_P2_suppress"]["integrated_area_above_90_mm2_s"] > 0  # the lagging umbra
    assert lag["latency_frames"] == 2 and lag["rig"] == "P25" and lag["projectors"] == 25


def test_bad_arguments(room):
    with pytest.raises(ValueError, match="no rig"):
        run_motion(room, WavePath(), duration=0.1, fps=10, subsets=["P7"])
    with pytest.raises(ValueError, match="positive"):
        run_motion(room, WavePath(), duration=0.0, fps=10)
    with pytest.raises(ValueError, match="same name"):
        run_motion(room, WavePath(), duration=0.1, fps=10, reactive=[ReactiveSpec(0.1), ReactiveSpec(0.11)])
