"""The study's schedule: every pair on every image, sides balanced within and across participants,
a random order; the shipped configurations are the virtual room's subsets."""
from __future__ import annotations

from collections import Counter
from itertools import combinations, permutations

import pytest

from studies.configurations import load_configurations
from studies.schedule import (
    balanced_sides,
    make_schedule,
    read_schedule,
    write_schedule,
)

CONFIGS = ["P1", "P9D", "P9W", "P13", "P17", "P20", "P25"]
IMAGES = ["parrot.png", "splash.png", "wood.png"]


def test_the_shipped_configurations_are_the_rooms_subsets():
    from sim.scene import SUBSETS

    assert load_configurations() == {k: tuple(v) for k, v in SUBSETS.items()}


def test_configuration_files_are_checked(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text('[configurations]\nA = ["s1", "s2"]\nB = ["s2"]\n')
    assert load_configurations(f) == {"A": ("s1", "s2"), "B": ("s2",)}
    for text, says in (('[configurations]\nA = []\n', "non-empty list"), ('[configurations]\nA = ["s", "s"]\n', "twice"),
                       ('A = ["s"]\n', r"needs a \[configurations\] table"), ('[configurations\n', "not TOML")):
        f.write_text(text)
        with pytest.raises(ValueError, match=says):
            load_configurations(f)


@pytest.mark.parametrize("t", [2, 3, 6, 7, 8])
def test_balanced_sides_orient_every_pair_once_with_even_left_counts(t):
    pairs = balanced_sides(t)
    assert sorted(tuple(sorted(p)) for p in pairs) == list(combinations(range(t), 2))
    lefts = Counter(a for a, _ in pairs)
    assert {lefts[i] for i in range(t)} <= {(t - 1) // 2, t // 2}
    assert sum(lefts.values()) == t * (t - 1) // 2


def test_nakaya_schedule_is_complete_and_balanced():
    trials = make_schedule(6, CONFIGS, IMAGES, seed=11)
    assert len(trials) == 6 * 21 * 3
    by_person = {p: [t for t in trials if t.participant == p] for p in range(1, 7)}
    both_ways: Counter = Counter()
    for mine in by_person.values():
        assert [t.trial for t in mine] == list(range(1, 64))
        for img in IMAGES:
            shown = [(t.left, t.right) for t in mine if t.image == img]
            # every unordered pair once per image ...
            assert sorted(tuple(sorted(s)) for s in shown) == sorted(tuple(sorted(c)) for c in combinations(CONFIGS, 2))
            # ... each configuration on the left 3 of its 6 times
            assert set(Counter(left for left, _ in shown).values()) == {3}
            both_ways.update(shown)
    # across participants every pair is seen each way round equally often (3 times of 6 per image)
    assert set(both_ways.values()) == {9}
    orders = {tuple((t.image, t.left, t.right) for t in mine) for mine in by_person.values()}
    assert len(orders) == 6                              # a random order per participant
    assert all(len({t.image for t in mine[:21]}) == 3 for mine in by_person.values())   # images mixed, not blocked
    assert make_schedule(6, CONFIGS, IMAGES, seed=11) == trials != make_schedule(6, CONFIGS, IMAGES, seed=12)


def test_an_odd_participant_count_leaves_each_pair_one_sided_by_at_most_one_view():
    trials = make_schedule(5, CONFIGS[:4], ["a"], seed=2)
    ways = Counter((t.left, t.right) for t in trials)
    for a, b in combinations(CONFIGS[:4], 2):
        assert ways[(a, b)] + ways[(b, a)] == 5 and abs(ways[(a, b)] - ways[(b, a)]) == 1


def test_ordered_design_and_blocks():
    trials = make_schedule(3, CONFIGS[:4], ["a", "b"], design="ordered", blocked=True, seed=4)
    for p in (1, 2, 3):
        mine = [t for t in trials if t.participant == p]
        for img in ("a", "b"):
            assert sorted((t.left, t.right) for t in mine if t.image == img) == sorted(permutations(CONFIGS[:4], 2))
        seq = [t.image for t in mine]
        assert seq == [seq[0]] * 12 + [seq[12]] * 12 and seq[0] != seq[12]   # one image after the other
    firsts = [next(t.image for t in trials if t.participant == p) for p in (1, 2, 3)]
    assert firsts == ["a", "b", "a"]                                       # the images' order rotates


def test_schedule_csv_round_trip_and_refusals(tmp_path):
    trials = make_schedule(2, CONFIGS[:3], ["x.png"], seed=1)
    f = tmp_path / "s.csv"
    write_schedule(f, trials)
    assert read_schedule(f) == trials
    assert f.read_text().splitlines()[0] == "participant,trial,image,left,right"
    assert [p.name for p in tmp_path.iterdir()] == ["s.csv"]           # no temp file left behind
    for text, says in (("who,trial,image,left,right\n", "must name the columns"),
                       ("participant,trial,image,left,right\n1,x,a,A,B\n", "s.csv:2: participant and trial"),
                       ("participant,trial,image,left,right\n1,1,a,A,A\n", "two different configurations"),
                       ("participant,trial,image,left,right\n1,1,a,A,B\n1,1,a,B,C\n", "trial 1 twice")):
        f.write_text(text)
        with pytest.raises(ValueError, match=says):
            read_schedule(f)
    with pytest.raises(ValueError, match="at least 2 different configurations"):
        make_schedule(2, ["A"], ["x"])
    with pytest.raises(ValueError, match="unknown design"):
        make_schedule(2, ["A", "B"], ["x"], design="ura")
