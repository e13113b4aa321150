"""The side checks beside Nakaya's analysis: the side effect against closed forms (the mean score
of a balanced design; the pooled two-sample t test for one pair), a simulated side preference
found and a fair panel not flagged, and one-sided participants."""
from __future__ import annotations

import math
from itertools import combinations

import numpy as np
import pytest
from scipy import stats

from studies.schedule import make_schedule
from studies.side_checks import one_sided, side_effect, warnings


def test_one_pair_is_the_pooled_two_sample_t_test():
    rng = np.random.default_rng(0)
    u = np.round(rng.normal(1.0, 0.8, 7))       # A shown first, rated A over B
    w = np.round(rng.normal(-0.2, 0.8, 5))      # B shown first, rated B over A
    rows = [("p", "A", "B", float(v)) for v in u] + [("p", "B", "A", float(v)) for v in w]
    eff = side_effect(rows)
    ref = stats.ttest_ind(u, -w)                # A over B either way: the two orientations differ by 2 d
    assert eff.estimate == pytest.approx((u.mean() + w.mean()) / 2)
    assert eff.t == pytest.approx(ref.statistic) and eff.p == pytest.approx(ref.pvalue) and eff.df == 10
    assert (eff.pairs_both_ways, eff.pairs) == (1, 1)


def simulate(effects, participants, *, side=0.0, seed=0):
    """Ratings of a balanced `study schedule` (each pair each way round across couples)."""
    rng = np.random.default_rng(seed)
    rows = []
    for t in make_schedule(participants, list(effects), ["img"], seed=seed):
        v = effects[t.left] - effects[t.right] + side + rng.normal(0, 0.7)
        rows.append((str(t.participant), t.left, t.right, float(np.clip(np.round(v), -2, 2))))
    return rows


def test_a_balanced_design_s_side_effect_is_the_mean_score_and_is_found():
    effects = {"P1": -1.0, "P9D": 0.4, "P9W": 0.0, "P25": 0.6, "P20": 0.5}
    fair = simulate(effects, 20, seed=1)
    eff = side_effect(fair)
    assert eff.estimate == pytest.approx(np.mean([r[3] for r in fair]), abs=1e-12)   # orthogonal to the pairs
    assert eff.pairs_both_ways == eff.pairs == 10
    biased = simulate(effects, 20, side=0.6, seed=1)
    eff, said = warnings(biased, shown="left")
    assert eff.p < 1e-3 and eff.estimate > 0.3
    assert any("lean" in s and "toward the left one" in s and "Nakaya's analysis has no term" in s for s in said)
    flagged = sum(warnings(simulate(effects, 20, seed=s))[0].p < 0.05 for s in range(40))
    assert flagged <= 6          # about 5 % of fair panels (binomial: 6 or more of 40 has probability 0.14)


def test_a_pair_never_shown_both_ways_leaves_the_side_effect_undefined():
    rows = [(f"s{k}", a, b, 1.0) for k in range(4) for a, b in combinations("ABC", 2)]
    eff = side_effect(rows)
    assert math.isnan(eff.estimate) and "no pair was shown both ways round" in eff.undefined


def test_a_participant_always_choosing_one_side_is_flagged_from_six_ratings():
    rows = [("keen", a, b, 1.0) for a, b in combinations("ABCD", 2)]            # 6 ratings, all for the first
    rows += [("lazy", b, a, -2.0) for a, b in combinations("ABCD", 2)]           # all for the second
    rows += [("short", a, b, 1.0) for a, b in combinations("ABCD", 2)][:5]       # 5: cannot tell
    rows += [("fair", a, b, (-1.0) ** k) for k, (a, b) in enumerate(combinations("ABCD", 2))]
    assert one_sided(rows) == [("keen", "first", 6), ("lazy", "second", 6)]
    _, said = warnings(rows, shown="left")
    assert any("participant keen preferred the left one in all 6 ratings (1 in 32 by chance" in s for s in said)
    assert any("participant lazy preferred the right one in all 6" in s for s in said)
