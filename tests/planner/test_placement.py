"""`shadowless plan --placement`: the object's placement searched, written, pictured, and checked
by the coverage tool; the search's count against a brute-force ray cast."""
from __future__ import annotations

import contextlib
import io
import json
import math
import tomllib

import cv2
import numpy as np
import pytest

from planner.placement import Placement, Score, area_quantile, fits, search

SMALL = ["--seconds", "4", "--rounds", "1", "--step", "400", "--turns", "2", "--search-texture", "32x32", "--search-resolution", "160x100",
         "--texture", "48x48", "--check-resolution", "160x100", "--shadow-scale", "1"]


@pytest.fixture(scope="module")
def placed(tmp_path_factory):
    """One small `shadowless plan --placement --json` run: (its JSON, its directory)."""
    from shadowless.cli import main

    d = tmp_path_factory.mktemp("placement")
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["plan", "--placement", "--json", "--layout", str(d / "placed.toml"), "--picture", str(d / "placed.png"), *SMALL])
    assert code == 0, err.getvalue()
    assert "placement: searched" in err.getvalue()              # progress while it searches
    return json.loads(out.getvalue()), d


def test_the_chosen_placement_is_written_pictured_and_no_worse_than_the_default(placed):
    doc, d = placed
    assert doc["min_coverage_chosen"] >= doc["min_coverage_default"] >= 1
    c, dflt = doc["chosen"], doc["default"]
    assert (dflt["x_mm"], dflt["y_mm"], dflt["yaw_deg"]) == (0.0, 0.0, 0.0)
    key = lambda s: Score(s["count_min"], s["unlit_pct"], s["hand_shadow_pct"], s["count_mean"], s["count_p5"]).key
    assert key(c) >= key(dflt)
    assert doc["evaluated"] >= 2 and doc["cpu_seconds"] > 0
    layout = tomllib.loads((d / "placed.toml").read_text())
    assert layout["mesh"]["position"] == [c["x_mm"], c["y_mm"], 0.0]
    assert layout["mesh"]["yaw_deg"] == pytest.approx(c["yaw_deg"], abs=0.05)
    assert len(layout["projector"]) == 25 and {p["slot"] for p in layout["projector"]} == {f"r{r}c{k}" for r in range(5) for k in range(5)}
    img = cv2.imread(str(d / "placed.png"))
    assert img is not None and img.shape[1] > 2 * img.shape[0]      # two table panels side by side and the colour bar


def test_the_coverage_tool_reports_the_same_coverage_for_the_written_placement(placed, shadowless_main, tmp_path):
    doc, d = placed
    rig = tmp_path / "rig"
    code, out, err = shadowless_main("rig", "init", str(rig), "--layout", str(d / "placed.toml"), "--resolution", "160x100")
    assert code == 0, err
    code, out, err = shadowless_main("coverage", "--rig-dir", str(rig), "--planned", "--json", "--texture", "48x48",
                                     "--shadow-scale", "1", "--view", "0,90", "--panel", "96x96")
    assert code == 0, err
    tool = json.loads(out)
    c = doc["chosen"]
    assert tool["slots"] == 25
    assert tool["count_min"] == c["count_min"] and tool["count_p5"] == c["count_p5"]
    assert tool["lit_pct"] == pytest.approx(100.0 - c["unlit_pct"], abs=0.05)
    assert tool["count_mean"] == pytest.approx(c["count_mean"], abs=0.01)


def _ray_hits(origin: np.ndarray, targets: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """(n,) bool: whether the segment from ``origin`` to each target crosses a triangle (F, 3, 3)
    before it (Moller-Trumbore, every triangle, in float64)."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    out = np.zeros(len(targets), bool)
    for k, X in enumerate(targets):
        v = X - origin
        dist = np.linalg.norm(v)
        d = v / dist
        p = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, p)
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = origin - tri[:, 0]
        u = np.einsum("ij,ij->i", s, p) * inv
        q = np.cross(s, e1)
        w = (q @ d) * inv
        t = np.einsum("ij,ij->i", e2, q) * inv
        hit = ok & (u >= 0) & (w >= 0) & (u + w <= 1) & (t > 1e-6) & (t < dist - 2.0)   # 2 mm: the point's own surface
        out[k] = bool(hit.any())
    return out


def test_the_search_counts_as_a_brute_force_ray_cast_does():
    from shadowless.placement import Judge, load_room

    room = load_room(None)
    judge = Judge(room, resolution=(160, 100), texture=(32, 32), shadow_scale=2)
    p = Placement(150.0, -60.0, 70.0)
    count, E = judge.coverage(p)
    rng = np.random.default_rng(3)
    pick = rng.choice(len(judge.points), 12, replace=False)
    X = p.to_room(judge.points[pick])
    N = p.normals_to_room(judge.normals[pick])
    tri = p.to_room(room.vertices.astype(np.float64))[room.faces.astype(np.int64)]
    brute = np.zeros(len(pick), int)
    for _, dev in judge.devices:
        c = dev.center
        uvw = (dev.K @ (dev.R @ X.T + dev.t[:, None])).T
        u, v = uvw[:, 0] / uvw[:, 2], uvw[:, 1] / uvw[:, 2]
        w, h = dev.size
        inside = (uvw[:, 2] > 0) & (u >= -0.5) & (u <= w - 0.5) & (v >= -0.5) & (v <= h - 0.5)
        facing = np.einsum("ij,ij->i", N, c - X) > 0
        brute += inside & facing & ~_ray_hits(c, X, tri)
    # shadow maps and ray casts part only at grazing rays and silhouettes: a projector at most
    assert np.abs(count[pick] - brute).max() <= 1
    assert np.sum(count[pick] == brute) >= 10
    assert count[pick].max() >= 10 and brute.min() >= 0                    # the picked points see many projectors


def test_the_search_finds_the_best_of_a_known_score_and_keeps_the_object_on_the_table():
    foot = np.array([[-100.0, -50.0, 0.0], [100.0, -50.0, 0.0], [100.0, 50.0, 0.0], [-100.0, 50.0, 0.0]])
    assert fits(foot, Placement(0, 0, 0), (1200, 600))
    assert not fits(foot, Placement(520, 0, 0), (1200, 600))          # over the right edge
    assert fits(foot, Placement(0, 190, 0), (1200, 600)) and not fits(foot, Placement(0, 190, 90), (1200, 600))

    def score(p: Placement) -> Score:
        assert fits(foot, p, (1200, 600))                               # never judged off the table
        far = math.hypot(p.x - 230.0, p.y + 60.0) + 2.0 * abs(((p.yaw_deg - 45.0 + 180.0) % 360.0) - 180.0)
        return Score(1, 0.0, 0.0, 100.0 - far / 10.0)

    said = []
    got = search(score, foot, (1200, 600), step_mm=200.0, yaws=4, rounds=4, seconds=60.0, progress=said.append)
    assert abs(got.best.x - 230.0) <= 40 and abs(got.best.y + 60.0) <= 40 and abs(got.best.yaw_deg % 360 - 45.0) <= 12
    assert not got.stopped_early and said and said[-1].startswith("fine 4/4")
    assert area_quantile(np.array([1, 5, 9, 9]), np.array([1.0, 1.0, 1.0, 97.0]), 0.05) == 9


def test_an_unreadable_room_is_refused_in_one_line(shadowless_main, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[[projector]]\nslot = 'a'\n")      # no position
    code, out, err = shadowless_main("plan", "--placement", "--room", str(bad), "--layout", str(tmp_path / "x.toml"))
    assert code not in (0, None) and "position" in str(code) + err
    assert not (tmp_path / "x.toml").exists()
