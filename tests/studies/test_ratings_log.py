"""The ratings file of a study run: appended answers survive reopening, a torn last line is cut
off, a foreign file is refused, a file from before two questions is refused for appending, and
`study scheffe` reads it with each participant on each image as one judge, each question apart."""
from __future__ import annotations

from itertools import combinations

import pytest

from studies.ratings_log import COLUMNS, LEGACY_COLUMNS, RatingsLog
from studies.scheffe import ratings_array, read_ratings, scheffe_nakaya


def test_answers_are_appended_and_known_after_reopening(tmp_path):
    f = tmp_path / "r.csv"
    log = RatingsLog(f)
    assert f.read_text() == ",".join(COLUMNS) + "\n" and log.answered == set()
    log.append(3, "parrot.png", "P9D", "P25", trial=7, answer=2, question="sop")
    log.append(3, "parrot.png", "P9D", "P25", trial=7, answer=-1, question="shadow")
    log.append(3, "parrot.png", "P25", "P1", trial=8, answer=0, question="sop")
    assert f.read_text().splitlines()[1:] == ["3,P9D,P25,-2,parrot.png,7,2,sop", "3,P9D,P25,1,parrot.png,7,-1,shadow",
                                              "3,P25,P1,0,parrot.png,8,0,sop"]
    again = RatingsLog(f)
    assert again.has(3, "parrot.png", "P9D", "P25", "sop") and not again.has(3, "parrot.png", "P25", "P9D", "sop")
    assert again.has(3, "parrot.png", "P9D", "P25", "shadow") and not again.has(3, "parrot.png", "P25", "P1", "shadow")
    assert not again.has(4, "parrot.png", "P9D", "P25", "sop") and again.repaired == 0
    with pytest.raises(ValueError, match="-2 .. 2"):
        again.append(3, "x", "A", "B", trial=1, answer=3, question="sop")


def test_a_torn_last_line_is_cut_off_and_asked_again(tmp_path):
    f = tmp_path / "r.csv"
    RatingsLog(f).append(1, "a", "A", "B", trial=1, answer=1, question="q")
    with f.open("a") as out:
        out.write("1,A,C,-1,a,2,1,")           # the machine stopped in the middle of this write
    log = RatingsLog(f)
    assert log.repaired == len("1,A,C,-1,a,2,1,") and not log.has(1, "a", "A", "C", "q") and log.has(1, "a", "A", "B", "q")
    log.append(1, "a", "A", "C", trial=2, answer=-1, question="q")
    assert f.read_text().splitlines()[1:] == ["1,A,B,-1,a,1,1,q", "1,A,C,1,a,2,-1,q"]


def test_a_file_of_another_kind_is_refused(tmp_path):
    f = tmp_path / "r.csv"
    f.write_text("participant,first,second,score\ns1,A,B,1\n")
    with pytest.raises(ValueError, match="not a study ratings file: its header must name the columns"):
        RatingsLog(f)
    f.write_text(",".join(COLUMNS) + "\n1,A,B\n")
    with pytest.raises(ValueError, match="r.csv:2: a rating needs every column"):
        RatingsLog(f)
    f.write_text(",".join(LEGACY_COLUMNS) + "\n1,A,B,-1,a,1,1\n")    # one question per trial: read, not continued
    with pytest.raises(ValueError, match="before a study run asked two questions.*give the run a new --ratings file"):
        RatingsLog(f)
    assert read_ratings(f) == [("1/a", "A", "B", -1.0)]


def test_scheffe_reads_a_run_s_ratings_one_judge_per_participant_and_image(tmp_path):
    f = tmp_path / "r.csv"
    log = RatingsLog(f)
    items = ["A", "B", "C"]
    for p in (1, 2):
        for img in ("x", "y"):
            for k, (a, b) in enumerate(combinations(items, 2)):
                left, right = (a, b) if (p + k) % 2 else (b, a)
                answer = -1 if left == "A" else (1 if right == "A" else 0)     # A always preferred
                log.append(p, img, left, right, trial=k + 1, answer=answer, question="sop")
    x, its, judges = ratings_array(read_ratings(f, question="sop"))
    assert judges == ("1/x", "1/y", "2/x", "2/y") and set(its) == set(items)
    res = scheffe_nakaya(x, its, judges)
    scale = dict(zip(its, res.scale))
    assert scale["A"] == pytest.approx(2 / 3) and scale["B"] == pytest.approx(-1 / 3) == scale["C"]
    _, _, only_x = ratings_array(read_ratings(f, image="x", question="sop"))
    assert only_x == ("1/x", "2/x")
    with pytest.raises(ValueError, match="no ratings of image 'z'"):
        read_ratings(f, image="z")
