"""Paired tests against Student's sleep data (Cushny and Peebles, 1905; Student, 1908), whose
paired t (t = -4.0621, df = 9, p = 0.002833), Wilcoxon (V = 0, p = 0.009091, normal
approximation with continuity correction) and Shapiro-Wilk on the differences (W = 0.82987,
p = 0.03334) are printed in R's documentation and countless textbooks; and a simulation of
the null."""
from __future__ import annotations

import numpy as np
import pytest

from studies.paired import paired_tests, read_times

SLEEP_1 = np.array([0.7, -1.6, -0.2, -1.2, -0.1, 3.4, 3.7, 0.8, 0.0, 2.0])
SLEEP_2 = np.array([1.9, 0.8, 1.1, 0.1, -0.1, 4.4, 5.5, 1.6, 4.6, 3.4])


def test_sleep_data_takes_wilcoxon_because_the_differences_are_not_normal():
    r = paired_tests(SLEEP_1, SLEEP_2, log=False)
    assert (round(r.normality_w, 5), round(r.normality_p, 5)) == (0.82987, 0.03334)
    assert r.test == "Wilcoxon signed-rank" and r.statistic == 0.0 and round(r.p, 6) == 0.009091
    assert r.effect == "r" and r.effect_size == pytest.approx(2.6086 / 3.0, abs=1e-4)   # |Z| / sqrt(9 nonzero)


def test_sleep_data_paired_t_when_normality_is_not_required():
    r = paired_tests(SLEEP_1, SLEEP_2, log=False, alpha=0.01)   # W's p = 0.033 passes at 1 %
    assert r.test == "paired t" and round(r.statistic, 4) == -4.0621 and r.df == 9 and round(r.p, 6) == 0.002833
    d = SLEEP_2 - SLEEP_1
    assert r.effect_size == pytest.approx(d.mean() / d.std(ddof=1))


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
    assert r.p < 1e-6 and r.ratio == pytest.approx(0.8, abs=0.03)


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
    with pytest.raises(ValueError, match="t.csv:2: time -2.0 must be a positive"):
        read_times(f)
