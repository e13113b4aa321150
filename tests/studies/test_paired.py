"""Paired tests against Student's sleep data (Cushny and Peebles, 1905; Student, 1908), whose
paired t (t = -4.0621, df = 9, p = 0.002833, group 1 − group 2), Wilcoxon (V = 0, the positive
rank sum of group 1 − group 2, p = 0.009091, normal approximation with continuity correction)
and Shapiro-Wilk on the differences (W = 0.82987, p = 0.03334) are printed in R's documentation
and countless textbooks; a simulation of the null; signs, ratios and zeros against closed forms
and a Wilcoxon computed by hand."""
from __future__ import annotations

import json
import math
import statistics

import numpy as np
import pytest
from scipy import stats

from studies.paired import paired_tests, read_measures, read_times

SLEEP_1 = np.array([0.7, -1.6, -0.2, -1.2, -0.1, 3.4, 3.7, 0.8, 0.0, 2.0])
SLEEP_2 = np.array([1.9, 0.8, 1.1, 0.1, -0.1, 4.4, 5.5, 1.6, 4.6, 3.4])


def test_sleep_data_takes_wilcoxon_because_the_differences_are_not_normal():
    r = paired_tests(SLEEP_1, SLEEP_2, log=False)
    assert (round(r.normality_w, 5), round(r.normality_p, 5)) == (0.82987, 0.03334)
    # second − first: R's V = 0 for first − second is W+ = 9 * 10 / 2 - 0 = 45 here (one zero dropped)
    assert r.test == "Wilcoxon signed-rank" and r.statistic == 45.0 and r.ranked == 9 and round(r.p, 6) == 0.009091
    assert r.effect == "r" and r.effect_size == pytest.approx(2.6086 / 3.0, abs=1e-4)   # Z / sqrt(9 ranked), B > A
    assert r.direction == "B − A" and r.mean_difference > 0


def test_sleep_data_paired_t_when_normality_is_not_required():
    r = paired_tests(SLEEP_1, SLEEP_2, log=False, alpha=0.01)   # W's p = 0.033 passes at 1 %
    assert r.test == "paired t" and round(r.statistic, 4) == 4.0621 and r.df == 9 and round(r.p, 6) == 0.002833
    d = SLEEP_2 - SLEEP_1            # second − first: t and d_z both positive
    assert r.effect_size == pytest.approx(d.mean() / d.std(ddof=1)) and r.effect_size > 0


def test_log_times_and_null_level():
    rng = np.random.default_rng(1)
    rejections = 0
    for _ in range(300):
        base = rng.lognormal(1.0, 0.4, 16)
        a, b = base * rng.lognormal(0, 0.1, 16), base * rng.lognormal(0, 0.1, 16)
        rejections += paired_tests(a, b).p < 0.05
    assert 0.02 < rejections / 300 < 0.10
    slow = rng.lognormal(1.0, 0.3, 20)
    r = paired_tests(slow, slow * 0.8 * rng.lognormal(0, 0.02, 20))
    assert r.p < 1e-6 and r.geometric_mean_ratio == pytest.approx(0.8, abs=0.03)


def test_times_csv(tmp_path):
    f = tmp_path / "t.csv"
    f.write_text("participant,condition,time_s\n" + "".join(
        f"p{i},{c},{t}\n" for i in range(5) for c, t in (("P1", 2.0 + i), ("P25", 1.5 + i), ("P25", 1.7 + i))))
    names, a, b = read_times(f)
    assert names == ("P1", "P25") and a[0] == 2.0 and b[0] == pytest.approx(np.sqrt(1.5 * 1.7))
    f.write_text("participant,condition,time_s\np1,P1,2\np1,P25,1\np2,P1,3\n")
    with pytest.raises(ValueError, match="p2 lack a time"):
        read_times(f)
    f.write_text("participant,condition,time_s\np1,P1,-2\n")
    with pytest.raises(ValueError, match="t.csv:2: time '-2' must be a positive"):
        read_times(f)
    f.write_text("participant,condition,accuracy\np1,A,0\np1,B,0.5\np1,B,1\np2,A,1\np2,B,0\n")
    column, names, a, b = read_measures(f)
    assert column == "accuracy" and list(a) == [0.0, 1.0] and list(b) == [0.75, 0.0]   # a mean of accuracies
    f.write_text("participant,condition,accuracy\np1,A,85\n")
    with pytest.raises(ValueError, match="t.csv:2: accuracy '85' must be a fraction 0..1"):
        read_measures(f)


def strict_json(text: str):
    def refuse(name):
        raise ValueError(f"not JSON: {name}")
    return json.loads(text, parse_constant=refuse)


@pytest.mark.parametrize("test", ["t", "wilcoxon"])
def test_every_sign_is_second_minus_first(test):
    """t, d_z, r and the differences all turn with the order of the conditions, and agree."""
    rng = np.random.default_rng(4)
    a = rng.lognormal(1.0, 0.3, 12)
    b = a * rng.lognormal(-0.15, 0.1, 12)        # the second condition is faster
    ab, ba = paired_tests(a, b, test=test), paired_tests(b, a, names=("B", "A"), test=test)
    assert ab.effect_size < 0 and ab.mean_difference < 0 and ab.geometric_mean_ratio < 1
    assert ba.effect_size == pytest.approx(-ab.effect_size) and ba.p == pytest.approx(ab.p)
    assert ba.geometric_mean_ratio == pytest.approx(1 / ab.geometric_mean_ratio)
    if test == "t":
        ref = stats.ttest_rel(np.log(b), np.log(a))
        assert ab.statistic == pytest.approx(ref.statistic) and ab.statistic < 0 and ba.statistic > 0


def test_a_median_is_called_a_median_and_the_geometric_mean_is_one():
    """Ratios whose median is below 1 and geometric mean above it: each is reported under its name."""
    ratios = np.array([0.5, 0.9, 0.95, 1.2, 3.0, 0.97, 1.8])
    a = np.array([2.0, 3.0, 1.5, 4.0, 2.5, 3.5, 1.2])
    for test in ("t", "wilcoxon"):
        r = paired_tests(a, a * ratios, test=test)
        assert r.median_ratio == pytest.approx(statistics.median(ratios)) and r.median_ratio < 1
        assert r.geometric_mean_ratio == pytest.approx(math.prod(ratios) ** (1 / len(ratios)))
        assert r.geometric_mean_ratio > 1
    raw = paired_tests(SLEEP_1, SLEEP_2, log=False)     # negative hours: no ratio, and why
    assert math.isnan(raw.geometric_mean_ratio) and "0 or negative" in raw.ratio_undefined


def wilcoxon_by_hand(d: np.ndarray) -> tuple[float, float]:
    """W+ and the two-sided p of the signed-rank test with zeros dropped: normal approximation,
    tie-corrected variance, continuity correction (the textbook procedure, R's wilcox.test)."""
    d = d[d != 0]
    n = len(d)
    ranks = stats.rankdata(np.abs(d))          # average ranks for ties
    w_plus = float(ranks[d > 0].sum())
    _, counts = np.unique(np.abs(d), return_counts=True)
    var = n * (n + 1) * (2 * n + 1) / 24 - float(((counts ** 3 - counts) / 48).sum())
    dev = w_plus - n * (n + 1) / 4
    z = (dev - math.copysign(0.5, dev)) / math.sqrt(var)
    return w_plus, 2 * stats.norm.sf(abs(z))


def test_accuracies_with_zeros_and_ties_are_ranked_as_the_textbook_does(tmp_path):
    first = np.array([0.0, 0.2, 0.5, 0.5, 0.0, 0.4, 1.0, 0.6, 0.3, 0.0, 0.7, 0.5])
    second = np.array([0.4, 0.6, 0.5, 0.9, 0.0, 0.8, 1.0, 0.6, 0.7, 0.2, 0.5, 0.9])   # ties and zeros
    r = paired_tests(first, second, log=False, test="wilcoxon")
    w_plus, p = wilcoxon_by_hand(np.round(second - first, 12))
    assert r.ranked == 8 and r.statistic == pytest.approx(w_plus) and r.p == pytest.approx(p, rel=1e-9)
    assert r.effect_size > 0 and r.zero_method == "wilcox"
    pratt = paired_tests(first, second, log=False, test="wilcoxon", zero_method="pratt")
    assert pratt.p == pytest.approx(stats.wilcoxon(np.round(second - first, 12), zero_method="pratt", correction=True,
                                                    method="approx").pvalue)
    nothing = paired_tests(first, first, log=False, test="wilcoxon")
    assert math.isnan(nothing.p) and "every difference is 0" in nothing.undefined
    same = paired_tests(first, first + 0.1, log=False, test="t")
    assert math.isnan(same.statistic) and "t = mean / 0" in same.undefined



def test_the_paired_command_names_direction_ratios_and_undefined_numbers(tmp_path, capsys):
    from shadowless.cli import main

    ratios = [0.5, 0.9, 0.95, 1.2, 3.0, 0.97, 1.8]
    f = tmp_path / "t.csv"
    f.write_text("participant,condition,time_s\n" + "".join(f"p{k},P1,2\np{k},P25,{2 * q}\n" for k, q in enumerate(ratios)))
    assert main(["study", "paired", str(f), "--test", "wilcoxon"]) == 0
    text = capsys.readouterr().out
    assert "differences are P25 − P1" in text and "Wilcoxon signed-rank (P25 − P1): W+ = " in text
    assert f"geometric mean of the ratios {math.prod(ratios) ** (1 / 7):.3f}x, median of the ratios 0.970x" in text
    a = tmp_path / "a.csv"
    a.write_text("participant,condition,accuracy\n" + "".join(f"p{k},P1,{v}\np{k},P25,{v}\n" for k, v in
                                                               enumerate((0, 0.5, 1, 0))))
    assert main(["study", "paired", str(a), "--json"]) == 0
    doc = strict_json(capsys.readouterr().out)
    assert doc["p"] is None and doc["r"] is None and doc["df"] is None and "every difference is 0" in doc["undefined"]
    assert doc["geometric_mean_ratio"] is None and "0 or negative" in doc["ratio_undefined"]
    assert main(["study", "paired", str(a)]) == 0
    text = capsys.readouterr().out
    assert "Wilcoxon signed-rank: undefined: every difference is 0" in text and "ratios P25 / P1: undefined" in text
