"""Scheffé–Nakaya at its edges, through `shadowless study scheffe` in this process: ratios of zeros
are undefined (null in strict JSON, said in the text), scores off the scale are refused naming
their row, small p values keep their digits, and a run's file of two questions gets two
analyses while an older file of one still reads."""
from __future__ import annotations

import json
import math
from itertools import combinations

import pytest

from shadowless.cli import main
from studies.scheffe import ratings_array, read_ratings, scheffe_nakaya

#: the worked example of test_scheffe.py (MARUI, after Sato): 6 subjects, pairs 1-2, 1-3, 2-3, -3..3
WORKED = [(-2, -1, 1), (-2, -2, 2), (-3, 0, 3), (-3, 0, 2), (-1, 1, 2), (-3, -1, 0)]


def strict_json(text: str):
    def refuse(name):
        raise AssertionError(f"not JSON: {name}")
    return json.loads(text, parse_constant=refuse)


def write(path, rows, header="participant,first,second,score"):
    path.write_text(header + "\n" + "".join(",".join(map(str, r)) + "\n" for r in rows))
    return path


def study(capsys, *argv):
    code = main(["study", "scheffe", *map(str, argv)])
    out = capsys.readouterr()
    return code, out.out, out.err


def consistent(items=("A", "B", "C", "D"), judges=5, values=(1, 0, 0, -1)):
    """Every judge rates every pair exactly a_i - a_j: nothing is left for the error term."""
    return [(f"s{j}", items[a], items[b], values[a] - values[b]) for j in range(judges)
            for a, b in combinations(range(len(items)), 2)]


def test_ratios_of_zero_are_undefined_not_significant(tmp_path, capsys):
    x, items, people = ratings_array(consistent())
    res = scheffe_nakaya(x, items, people)
    main_effect = res.row("main effect")
    assert main_effect.ss > 0 and res.row("error").ss == 0.0
    assert math.isnan(main_effect.f) and math.isnan(main_effect.p) and "MS / 0" in main_effect.undefined
    assert "0 / 0" in res.row("combination").undefined          # nothing there either
    assert all(math.isnan(y) for y in res.yardstick.values()) and res.letters == {} and res.undefined

    for name, rows in (("consistent", consistent()), ("zeros", [(p, a, b, 0) for p, a, b, _ in consistent()])):
        f = write(tmp_path / f"{name}.csv", rows)
        code, out, _ = study(capsys, f, "--json", "--chart", tmp_path / f"{name}.svg")
        doc = strict_json(out)                              # no Infinity, no NaN
        assert code == 0 and all(r["f"] is None and r["p"] is None for r in doc["anova"])
        assert all(r["undefined"] for r in doc["anova"][:3]) and doc["yardstick"] == {"0.05": None, "0.01": None}
        code, text, _ = study(capsys, f)
        assert "F and p undefined" in text and "yardsticks undefined" in text and "inf" not in text
    assert "every rating is 0" in text


@pytest.mark.parametrize(("score", "says"), [
    ("7", "r.csv:4: score '7' is outside the scale -3..3"),
    ("1.5", "r.csv:4: score '1.5' is not a whole step of the scale -3..3 (--continuous allows fractions)"),
])
def test_scores_off_the_scale_are_refused_naming_the_row(tmp_path, capsys, score, says):
    rows = [(f"subject {k + 1}", a, b, s) for k, r in enumerate(WORKED) for (a, b), s in
            zip((("1", "2"), ("1", "3"), ("2", "3")), r)]
    rows[2] = (*rows[2][:3], score)
    f = write(tmp_path / "r.csv", rows)
    code, out, err = study(capsys, f, "--scale", "-3..3")        # -3..3 without the '=' argparse would need
    assert code == 2 and out == "" and says in err and len(err.strip().splitlines()) == 1
    if score == "1.5":
        assert study(capsys, f, "--scale", "-3..3", "--continuous", "--json")[0] == 0
    code, _, err = study(capsys, write(tmp_path / "w.csv", [r for r in rows if r[3] != score]
                                       + [(*rows[2][:3], 3)]))
    assert code == 2 and "outside the scale -2..2 (--scale gives another)" in err      # the default scale
    with pytest.raises(SystemExit):
        main(["study", "scheffe", str(f), "--scale", "0..6"])
    assert "runs from -MAX to MAX" in capsys.readouterr().err


def test_json_keeps_full_precision_and_text_keeps_small_p_digits(tmp_path, capsys):
    rows = [(f"s{j}", a, b, (1 if a < b else -1) * (2 if {a, b} == {"A", "D"} else 1) * (1 if (j + len(a + b)) % 5 else 0))
            for j in range(12) for a, b in combinations("ABCD", 2)]
    f = write(tmp_path / "r.csv", rows)
    x, items, people = ratings_array(read_ratings(f))
    want = scheffe_nakaya(x, items, people, levels=()).row("main effect").p      # (no yardstick: faster)
    assert 0 < want < 1e-6
    code, out, _ = study(capsys, f, "--json")
    doc = strict_json(out)
    assert doc["anova"][0]["p"] == want                        # bit for bit, not round(x, 6)
    code, text, _ = study(capsys, f)
    line = next(s for s in text.splitlines() if s.startswith("main effect"))
    assert line.split()[-1] == f"{want:.2g}" and "e-" in line.split()[-1]


def test_two_questions_are_two_analyses_and_an_old_file_still_reads(tmp_path, capsys):
    head = "participant,first,second,score,image,trial,answer,question"
    rows = []
    for p in (1, 2, 3):
        for k, (a, b) in enumerate(combinations("ABC", 2)):
            sop = 1 if a == "A" else 0                    # sop: A preferred
            shadow = -1 if b == "C" else 0                # shadow: C preferred
            rows += [(p, a, b, sop, "img", k + 1, -sop, "sop"), (p, a, b, shadow, "img", k + 1, -shadow, "shadow")]
    f = write(tmp_path / "two.csv", rows, head)
    code, out, _ = study(capsys, f, "--json", "--chart", tmp_path / "c.svg")
    doc = strict_json(out)["questions"]
    assert code == 0 and list(doc) == ["sop", "shadow"] and doc["sop"]["question"] == "sop"
    sop_scale = doc["sop"]["scale"]
    assert max(sop_scale, key=sop_scale.get) == "A"
    assert max(doc["shadow"]["scale"], key=doc["shadow"]["scale"].get) == "C"
    assert (tmp_path / "c.sop.svg").is_file() and (tmp_path / "c.shadow.svg").is_file()
    only = strict_json(study(capsys, f, "--question", "shadow", "--json")[1])
    assert only["scale"] == doc["shadow"]["scale"] and "questions" not in only
    code, _, err = study(capsys, f, "--question", "colour")
    assert code == 2 and "no answers to question 'colour' (questions: sop, shadow)" in err
    code, text, _ = study(capsys, f)
    assert sum(s.startswith("main effect ") for s in text.splitlines()) == 2 and "question sop:" in text and "question shadow:" in text

    old = write(tmp_path / "old.csv", [r[:7] for r in rows if r[7] == "sop"], head.rsplit(",", 1)[0])
    code, out, _ = study(capsys, old, "--json")
    doc = strict_json(out)
    assert code == 0 and doc["scale"] == sop_scale and "two questions" in doc["note"]
    assert "note:" in study(capsys, old)[1]
