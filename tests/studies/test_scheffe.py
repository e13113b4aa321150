"""Scheffé–Nakaya against a least-squares fit of its model (numpy), the studentized range, and a
simulation of the null hypothesis."""
from __future__ import annotations

from itertools import combinations

import numpy as np
import pytest
from scipy import stats

from studies.scheffe import ratings_array, read_ratings, scheffe_nakaya


def simulate(t=5, n=12, *, effects=None, indiv=0.3, comb=0.0, noise=0.8, seed=0, discrete=True):
    rng = np.random.default_rng(seed)
    a = np.zeros(t) if effects is None else np.asarray(effects, float)
    a_il = rng.normal(0, indiv, (t, n)) if indiv else np.zeros((t, n))
    g = rng.normal(0, comb, (t, t)) if comb else np.zeros((t, t))
    g = g - g.T
    rows = []
    for l in range(n):
        for i, j in combinations(range(t), 2):
            v = a[i] - a[j] + a_il[i, l] - a_il[j, l] + g[i, j] + rng.normal(0, noise)
            v = float(np.clip(np.round(v), -2, 2)) if discrete else float(v)
            if rng.random() < 0.5:     # shown the other way round: recorded from that side
                rows.append((f"s{l}", f"P{j}", f"P{i}", -v))
            else:
                rows.append((f"s{l}", f"P{i}", f"P{j}", v))
    return rows


def lstsq_rss(columns: list[np.ndarray], y: np.ndarray) -> float:
    if not columns:
        return float(y @ y)
    a = np.column_stack(columns)
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    r = y - a @ coef
    return float(r @ r)


def test_sums_of_squares_are_the_least_squares_decomposition():
    rows = simulate(effects=[0.8, 0.3, 0.0, -0.2, -0.9], comb=0.4, discrete=False, seed=3)
    x, items, people = ratings_array(rows)
    res = scheffe_nakaya(x, items, people)
    t, _, n = x.shape
    obs, main, ind, pair = [], [], [], []
    pairs = list(combinations(range(t), 2))
    for l in range(n):
        for k, (i, j) in enumerate(pairs):
            obs.append(x[i, j, l])
            e = np.zeros(t)
            e[i], e[j] = 1, -1
            main.append(e)
            m = np.zeros((t, n))
            m[i, l], m[j, l] = 1, -1
            ind.append(m.ravel())
            p = np.zeros(len(pairs))
            p[k] = 1
            pair.append(p)
    y = np.array(obs)
    main, ind, pair = np.array(main), np.array(ind), np.array(pair)
    r0 = lstsq_rss([], y)
    r1 = lstsq_rss([main], y)
    r2 = lstsq_rss([main, ind], y)
    r3 = lstsq_rss([main, ind, pair], y)
    assert res.row("total").ss == pytest.approx(r0, rel=1e-12)
    assert res.row("main effect").ss == pytest.approx(r0 - r1, rel=1e-9)
    assert res.row("individual differences").ss == pytest.approx(r1 - r2, rel=1e-9)
    assert res.row("combination").ss == pytest.approx(r2 - r3, rel=1e-9)
    assert res.row("error").ss == pytest.approx(r3, rel=1e-9)
    # the scale values are the least-squares main effects (sum to zero)
    coef, *_ = np.linalg.lstsq(main, y, rcond=None)
    np.testing.assert_allclose(res.scale, coef - coef.mean(), atol=1e-12)
    dfs = {r.source: r.df for r in res.anova}
    assert dfs == {"main effect": 4, "individual differences": 44, "combination": 6, "error": 66, "total": 120}


def test_yardstick_and_letters():
    rows = simulate(effects=[1.0, 0.9, 0.0, -0.9, -1.0], seed=5, n=20)
    x, items, people = ratings_array(rows)
    res = scheffe_nakaya(x, items, people)
    ms_e, df_e = res.row("error").ms, res.row("error").df
    assert res.yardstick[0.05] == pytest.approx(stats.studentized_range.ppf(0.95, 5, df_e) * np.sqrt(ms_e / 100))
    assert res.yardstick[0.01] > res.yardstick[0.05]
    letters = dict(zip(items, res.letters[0.05]))
    assert set(letters["P0"]) & set(letters["P1"]) and not set(letters["P0"]) & set(letters["P4"])
    assert res.row("main effect").p < 1e-6


def test_the_main_effect_test_holds_its_level_under_the_null():
    """Brute force: with no differences, the F test rejects at 5 % about 5 % of the time."""
    rejections = 0
    runs = 400
    for seed in range(runs):
        x, items, people = ratings_array(simulate(t=4, n=8, indiv=0.0, discrete=False, seed=100 + seed))
        rejections += scheffe_nakaya(x, items, people, levels=()).row("main effect").p < 0.05
    rate = rejections / runs
    assert 0.02 < rate < 0.09, rate        # binomial 95 % band around 0.05 for 400 runs is ~0.03..0.07


def test_ratings_csv_and_refusals(tmp_path):
    f = tmp_path / "r.csv"
    f.write_text("participant,first,second,score\ns1,A,B,1\ns1,A,C,2\ns1,B,C,0\ns2,B,A,-1\ns2,A,C,1\ns2,C,B,1\n")
    x, items, people = ratings_array(read_ratings(f))
    assert items == ("A", "B", "C") and people == ("s1", "s2")
    assert x[0, 1, 1] == 1 and x[1, 0, 1] == -1 and x[1, 2, 1] == -1
    f.write_text("participant,first,second,score\ns1,A,B,1\ns1,A,C,2\ns2,A,B,1\ns2,A,C,1\ns2,B,C,0\n")
    with pytest.raises(ValueError, match="1 ratings missing, e.g. participant s1 on B/C"):
        ratings_array(read_ratings(f))
    f.write_text("who,first,second,score\n")
    with pytest.raises(ValueError, match="participant, first, second, score"):
        read_ratings(f)
    f.write_text("participant,first,second,score\ns1,A,B,lots\n")
    with pytest.raises(ValueError, match="r.csv:2: score 'lots'"):
        read_ratings(f)


def test_chart_is_valid_svg_with_every_item_escaped():
    from xml.etree import ElementTree as ET

    from studies.chart import scale_chart_svg

    rows = [(p, a.replace("P0", "P<0>"), b.replace("P0", "P<0>"), s) for p, a, b, s in simulate(seed=2)]
    x, items, people = ratings_array(rows)
    svg = scale_chart_svg(scheffe_nakaya(x, items, people), title="sense of projection")
    root = ET.fromstring(svg)
    texts = [t.text for t in root.iter("{http://www.w3.org/2000/svg}text")]
    assert "P<0>" in texts and "sense of projection" in texts
    assert len(list(root.iter("{http://www.w3.org/2000/svg}rect"))) == 1 + len(items)


def test_matches_a_published_worked_example():
    """The worked example of MARUI Atsushi (Tokyo University of the Arts), "シェッフェの一対比較法
    (中屋の変法)" [Scheffé's paired comparison, Nakaya's modification], 2012-09-12,
    http://marui.hatenablog.com/entry/20120912/1347435796 (program and example also at
    https://www.geidai.ac.jp/~marui/r_program/scheffe_nakaya.html), an R program written to follow
    chapter 20 of Sato Shin, 『統計的官能検査法』 (Statistical Methods in Sensory Tests), JUSE Press
    (日科技連出版社), 1985. 3 stimuli, 6 subjects, -3..3 ratings of the pairs 1-2, 1-3, 2-3
    (positive: the first preferred). Printed there to 4 decimals: the average preferences, the
    ANOVA table (SS, df, MS, F, p) and the yardsticks Y(.05) = 0.8323, Y(.01) = 1.2617."""
    ratings = [(-2, -1, 1), (-2, -2, 2), (-3, 0, 3), (-3, 0, 2), (-1, 1, 2), (-3, -1, 0)]
    rows = [(f"subject {k + 1}", a, b, float(s)) for k, r in enumerate(ratings)
            for (a, b), s in zip((("1", "2"), ("1", "3"), ("2", "3")), r)]
    x, items, people = ratings_array(rows)
    res = scheffe_nakaya(x, items, people)

    def printed(v: float, want: float) -> None:     # equal to the printed precision (4 decimals)
        assert round(v, 4) == want, (v, want)

    for got, want in zip(res.scale, (-0.9444, 1.3333, -0.3889)):
        printed(got, want)
    table = {   # source: (SS, df, MS, F, p) as printed
        "main effect": (50.7778, 2, 25.3889, 43.1132, 0.0007),
        "individual differences": (11.2222, 10, 1.1222, 1.9057, 0.2470),
        "combination": (0.0556, 1, 0.0556, 0.0943, 0.7711),
        "error": (2.9444, 5, 0.5889, None, None),
        "total": (65.0000, 18, None, None, None),
    }
    for source, (ss, df, ms, f, p) in table.items():
        r = res.row(source)
        printed(r.ss, ss)
        assert r.df == df
        for got, want in ((r.ms, ms), (r.f, f), (r.p, p)):
            if want is not None:
                printed(got, want)
    printed(res.yardstick[0.05], 0.8323)
    printed(res.yardstick[0.01], 1.2617)
    # its confidence intervals a_i - a_j ± Y: 1-2 = -2.2778 [-3.1101, -1.4454] at 95 %, 2-3 = 1.7222
    # [0.4605, 2.9840] at 99 %; 1-3 = -0.5556 is inside ±Y(.05): stimuli 1 and 3 share a letter
    printed(res.scale[0] - res.scale[1] - res.yardstick[0.05], -3.1101)
    printed(res.scale[1] - res.scale[2] - res.yardstick[0.01], 0.4605)
    assert res.letters[0.05] == ("b", "a", "b") and res.letters[0.01] == ("b", "a", "b")
