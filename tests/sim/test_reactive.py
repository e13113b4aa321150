"""The reactive-compensation model against a brute-force sum over projectors and worked examples."""
from __future__ import annotations

import numpy as np
import pytest

from sim.reactive import PRIOR_RIGS, ReactiveSpec, reactive_light, rig_slots, shares
from sim.scene import SUBSETS


def _brute(share: np.ndarray, seen: np.ndarray, now: np.ndarray, cap: float, suppress: bool) -> np.ndarray:
    """The model's definition, point by point and projector by projector (seen, now: (n, P) bool)."""
    n, P = share.shape
    out = np.zeros(P)
    for x in range(P):
        if share[:, x].sum() == 0:
            continue
        lost = sum(float(share[i, x]) for i in range(n) if seen[i, x])
        boost = cap if lost >= 1 else min(cap, 1.0 / (1.0 - lost))
        for i in range(n):
            if now[i, x]:
                continue
            gain = (0.0 if suppress else 1.0) if seen[i, x] else boost
            out[x] += gain * float(share[i, x])
    return out


def _indices(mask: np.ndarray) -> list[np.ndarray]:
    return [np.flatnonzero(row) for row in mask]


@pytest.mark.parametrize("suppress", [False, True])
@pytest.mark.parametrize("cap", [1.0, 1.5, 2.0, 50.0])
def test_light_matches_the_brute_force_sum(cap, suppress):
    rng = np.random.default_rng(3)
    n, P = 6, 80
    w = rng.uniform(0.2, 1.0, (n, P)) * (rng.random((n, P)) > 0.15)
    w[:, :3] = 0.0  # points no projector lights
    s = shares(w)
    seen = rng.random((n, P)) < 0.3
    now = rng.random((n, P)) < 0.3
    seen[:, 5] = True  # a point every projector was blocked at
    got = reactive_light(s, _indices(seen), _indices(now), cap=cap, suppress=suppress)
    np.testing.assert_allclose(got, _brute(s, seen, now, cap, suppress), atol=1e-5)


def test_two_projectors_worked_example():
    """Equal shares: A blocked when the system looked; then the hand moves on to B, or away."""
    s = np.full((2, 1), 0.5, np.float32)
    a, none = [np.array([0]), np.array([], np.int64)], [np.array([], np.int64)] * 2
    b = [np.array([], np.int64), np.array([0])]
    # Hand moved from A's line of sight to B's: B was boosted but is blocked; A (gain 1, or 0) is all that's left.
    assert reactive_light(s, a, b) == pytest.approx([0.5])
    assert reactive_light(s, a, b, suppress=True) == pytest.approx([0.0])  # the lagging umbra
    # Hand gone: A back at 1 plus B at 2 is a ghost of 1.5; suppressed, A is off and B at 2 restores 1.
    assert reactive_light(s, a, none) == pytest.approx([1.5])
    assert reactive_light(s, a, none, suppress=True) == pytest.approx([1.0])
    # Hand still: restored; with a cap of 1.5 B reaches only 1.5 x 0.5 (A stays blocked).
    assert reactive_light(s, a, a) == pytest.approx([1.0])
    assert reactive_light(s, a, a, cap=1.5) == pytest.approx([0.75])


def test_boosting_never_gives_less_light_than_the_passive_rig():
    rng = np.random.default_rng(8)
    n, P = 25, 500
    s = shares(rng.uniform(0.5, 1.0, (n, P)))
    for _ in range(5):
        seen = rng.random((n, P)) < 0.4
        now = rng.random((n, P)) < 0.4
        light = reactive_light(s, _indices(seen), _indices(now))
        passive = 1.0 - (s * now).sum(axis=0)
        assert np.all(light >= passive - 1e-6)


def test_still_hand_is_restored_where_the_cap_allows():
    rng = np.random.default_rng(5)
    n, P = 9, 300
    s = shares(rng.uniform(0.5, 1.0, (n, P)))
    blocked = rng.random((n, P)) < 0.35
    light = reactive_light(s, _indices(blocked), _indices(blocked), cap=2.0)
    lost = (s * blocked).sum(axis=0)
    ok = lost <= 0.5
    np.testing.assert_allclose(light[ok], 1.0, atol=1e-5)
    np.testing.assert_allclose(light[~ok], 2.0 * (1.0 - lost[~ok]), atol=1e-5)


def test_shares_and_bad_shapes():
    w = np.array([[1.0, 0.0, 3.0], [3.0, 0.0, 1.0]])
    np.testing.assert_allclose(shares(w), [[0.25, 0.0, 0.75], [0.75, 0.0, 0.25]])
    with pytest.raises(ValueError):
        shares(np.ones(4))
    with pytest.raises(ValueError, match="3 index arrays for 2"):
        reactive_light(shares(w), [np.array([0])] * 3, [np.array([0])] * 2)


def test_spec_names_latency_in_whole_frames_and_rigs():
    assert ReactiveSpec(0.1).latency_frames(60) == 6 and ReactiveSpec(0.1).name(60) == "reactive_100ms"
    assert ReactiveSpec(0.1).name(20) == "reactive_100ms" and ReactiveSpec(0.1).latency_frames(20) == 2
    assert ReactiveSpec(0.05, subset="P2", suppress=True).name(60) == "reactive_50ms_P2_suppress"
    assert ReactiveSpec(0.03).name(60) == "reactive_33ms"  # 1.8 frames: 2 frames, 33 ms modelled
    assert rig_slots("P25") == SUBSETS["P25"] and rig_slots("P2") == PRIOR_RIGS["P2"]
    for bad in ({"latency_s": -0.01}, {"cap": 0.5}, {"subset": "P7"}):
        with pytest.raises(ValueError):
            ReactiveSpec(**bad)
