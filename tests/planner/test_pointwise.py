"""Pointwise proxies: band weights as a planner objective, the linear programme, the search with the planner."""
from __future__ import annotations

import json

import numpy as np
import pytest

from shadowless.cli import main
from sim.hand import Hand
from planner.candidates import ProjectorModel, ceiling_grid, source_for
from planner.evaluate import Evaluator
from planner.pointwise import BEHIND, BandWeights, conflict, fit, reference_evaluator, search
from planner.search import plan
from planner.surface import irradiance, table_poses, table_surface
from sim.scene import SUBSETS, reference_scene
from studies.proxies import ORDERINGS, PoseSet, orderings
from sim.sop_shadows import Source

HANDS = [Hand(position=(-150.0, 0.0), height=150.0), Hand(position=(200.0, 80.0), height=250.0, yaw_deg=30.0)]
SURFACE = table_surface((1200.0, 600.0), pitch=25.0)


@pytest.fixture(scope="module")
def worlds():
    """(candidates' evaluator: a 4 x 4 ceiling grid, the reference rig's evaluator, SUBSETS as its indices)."""
    cands = [source_for(c, SURFACE.target, SURFACE.corners, ProjectorModel()) for c in ceiling_grid(4, 4)]
    ev = Evaluator(SURFACE, cands, irradiance(SURFACE, cands), HANDS)
    ref = [Source.from_spec(p) for p in reference_scene(jitter=False).projectors]
    rev = Evaluator(SURFACE, ref, irradiance(SURFACE, ref), HANDS)
    names = [s.name for s in ref]
    return ev, rev, {k: [names.index(x) for x in v] for k, v in SUBSETS.items()}


def test_band_weights_judge_like_the_named_proxies_they_spell(worlds):
    ev, _, _ = worlds
    shadow = BandWeights(np.array([1e-6, 0.01, 0.9, 1.0 + 1e-9]), np.array([0.0, 1.0, 10.0]))
    umbra = BandWeights(np.array([1e-6, 0.9, 1.0 + 1e-9]), np.array([0.0, 1.0]))
    for subset in ([0], [0, 15], [1, 5, 6, 10], list(range(16))):
        want = ev.using("shadow_mm2").value(subset)
        assert want > 0
        assert ev.using(shadow).value(subset) == pytest.approx(want, rel=1e-5)
        assert ev.using(umbra).value(subset) == pytest.approx(ev.using("umbra_mm2").value(subset), rel=1e-5, abs=1e-6)
        # the histogram times the weights is the value
        assert shadow.histogram(ev, subset) @ shadow.weights == pytest.approx(want, rel=1e-5)
    # judged by each candidate added, as the planner asks
    np.testing.assert_allclose(ev.using(shadow).with_each([3]), ev.using("shadow_mm2").with_each([3]), rtol=1e-5)
    assert ev.proxy == "max_drop"  # using() leaves the evaluator it copies alone


def test_band_weights_refuse_what_is_not_a_nondecreasing_weight():
    with pytest.raises(ValueError, match="nondecreasing"):
        BandWeights.bands(3, np.array([0.0, 2.0, 1.0]))
    with pytest.raises(ValueError, match="edges"):
        BandWeights(np.array([0.0, 0.5, 1.1]), np.array([1.0, 1.0]))
    w = BandWeights.bands(4, np.array([0.0, 1.0, 1.0, 3.0]))
    np.testing.assert_array_equal(w(np.array([0.0, 0.1, 0.25, 0.6, 1.0])), [0.0, 0.0, 1.0, 1.0, 3.0])


# Hand-made histograms over four bands (drop 0-25, 25-50, 50-75, 75-100 %), mm^2.
REFERENCE = {
    "P1": np.array([0.0, 0.0, 0.0, 100.0]),
    "P9D": np.array([40.0, 30.0, 5.0, 1.0]),
    "P9W": np.array([150.0, 20.0, 0.0, 0.0]),
    "P13": np.array([120.0, 10.0, 0.0, 0.0]),
    "P17": np.array([120.0, 8.0, 0.0, 0.0]),
    "P20": np.array([118.0, 8.0, 0.0, 0.0]),
    "P25": np.array([119.0, 9.0, 0.0, 0.0]),
}
EDGES = BandWeights.bands(4).edges


def _values(w: BandWeights, hist: dict) -> dict:
    return {k: float(h @ w.weights) for k, h in hist.items()}


def test_fit_finds_weights_that_reproduce_the_orderings_and_rank_small_layouts_behind():
    w = fit(REFERENCE, edges=EDGES)
    assert w is not None and np.all(np.diff(w.weights) >= 0) and w.weights[-1] == pytest.approx(1.0)
    assert all(orderings(_values(w, REFERENCE)).values())  # checked by the study's own function
    small = np.array([0.0, 60.0, 20.0, 0.0])  # two deep copies: behind P25 only if the deep bands weigh enough
    w2 = fit(REFERENCE, [small], edges=EDGES)
    assert w2 is not None and all(orderings(_values(w2, REFERENCE)).values())
    assert small @ w2.weights > REFERENCE["P25"] @ w2.weights


def test_fit_proves_there_are_no_weights_when_a_layout_is_dominated_band_by_band():
    # Less area than P25 in every band: no nonnegative weights can put it behind P25.
    assert fit(REFERENCE, [REFERENCE["P25"] * 0.5], edges=EDGES) is None
    # P9D with at least P9W's area in every band cannot be the better of the two.
    assert fit(dict(REFERENCE, P9D=REFERENCE["P9W"] + 1.0), edges=EDGES) is None
    with pytest.raises(ValueError, match="P9W"):
        fit({k: v for k, v in REFERENCE.items() if k != "P9W"}, edges=EDGES)


def test_conflict_names_what_must_give_and_by_how_much():
    assert conflict(REFERENCE, edges=EDGES) == {}  # fit has weights: nothing must give
    # P9D = P9W + 1 mm^2 in every band: P1's value 1 puts 0.01 on the top band, and P9D - P9W is the
    # sum of the weights, least at (0, 0, 0, 0.01); with the 0.1 % margin P9D must give 0.011
    got = conflict(dict(REFERENCE, P9D=REFERENCE["P9W"] + 1.0), edges=EDGES)
    assert got.keys() == {"dense_beats_wide_9"} and got["dense_beats_wide_9"] == pytest.approx(0.011, rel=1e-6)
    # a small layout exactly as good as P25 can be behind it by nothing: it breaks the margin, whatever the weights
    got = conflict(REFERENCE, [REFERENCE["P25"]], edges=EDGES)
    assert got.keys() == {BEHIND} and got[BEHIND] == pytest.approx(1e-3, rel=1e-6)
    assert fit(REFERENCE, [REFERENCE["P25"]], edges=EDGES) is None


def _histograms(ev, rev, subsets, layouts, bands):
    grid = BandWeights.bands(bands)
    names = [s.name for s in ev.sources]
    ref = {k: grid.histogram(rev, s) for k, s in subsets.items()}
    return grid, ref, [grid.histogram(ev, [names.index(n) for n in layout]) for layout in layouts]


def test_search_returns_weights_the_planner_cannot_beat(worlds):
    ev, rev, subsets = worlds
    out = search(ev, rev, subsets, most=2, bands=40)
    assert out.exists and len(out.rounds) > 1 and out.layouts  # the planner beat the first fits
    assert all(1 <= len(layout) <= 2 for layout in out.layouts)
    grid, ref, behind = _histograms(ev, rev, subsets, out.layouts, 40)
    w = out.weights
    values = {k: float(h @ w.weights) for k, h in ref.items()}
    assert all(orderings(values).values())
    assert all(h @ w.weights > values["P25"] for h in behind)
    for n in (1, 2):  # nor does the planner find anything ahead of P25 now
        assert plan(ev.using(w), n).value >= values["P25"]


def test_search_proves_no_weights_exist_on_the_planner_s_hands():
    """The quick world of `study pointwise`: 6 x 6 candidates, the planner's 27 hands at 200 mm."""
    surface = table_surface((1200.0, 600.0), pitch=10.0)
    hands = table_poses(PoseSet(heights=(200.0,)))
    cands = [source_for(c, surface.target, surface.corners, ProjectorModel()) for c in ceiling_grid(6, 6)]
    ev = Evaluator(surface, cands, irradiance(surface, cands), hands)
    rev, subsets = reference_evaluator(surface, hands)
    out = search(ev, rev, subsets, most=3, bands=50)
    assert not out.exists and out.layouts and all(1 <= len(layout) <= 3 for layout in out.layouts)
    grid, ref_h, behind = _histograms(ev, rev, subsets, out.layouts, 50)
    assert fit(ref_h, behind, edges=grid.edges) is None
    # without the last round's layouts the orderings alone still have weights: those layouts are what rule them out
    last = len(out.rounds[-1]["added"])
    assert fit(ref_h, behind[:-last], edges=grid.edges) is not None
    assert conflict(ref_h, behind[:-last], edges=grid.edges) == {}
    # what must give is what the search reported: one of the paper's orderings, by a fraction of P1's value
    assert out.must_give and out.must_give == pytest.approx(conflict(ref_h, behind, edges=grid.edges))
    assert set(out.must_give) <= {*ORDERINGS, BEHIND} and all(0 < v < 1 for v in out.must_give.values())


def test_study_pointwise_command_proves_it_on_the_quick_world(capsys):
    assert main(["study", "pointwise", "--quick", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["exists"] is False and doc["weights"] is None
    assert doc["must_give"] and all(v > 0 for v in doc["must_give"].values())
    assert doc["small_layouts_ahead"] and all(1 <= len(x) <= 3 for x in doc["small_layouts_ahead"])
    assert doc["candidates"] == 36 and doc["bands"] == 50
