"""`shadowless study`: the coordinator's analyses and the room's studies under one command; `study motion`."""
from __future__ import annotations

import importlib
import json
import subprocess
import sys

import av
import cv2
import pytest

from shadowless.cli import main
from shadowless.study import ANALYSES


def test_study_offers_every_analysis(capsys):
    with pytest.raises(SystemExit) as done:
        main(["study", "--help"])
    assert done.value.code == 0
    out = capsys.readouterr().out
    for name in ("scheffe", "paired", *ANALYSES):
        assert name in out
    for module, _ in ANALYSES.values():  # one line per study: a module with configure and run
        mod = importlib.import_module(module)
        assert callable(mod.configure) and callable(mod.run)


def test_the_statistical_analyses_do_not_load_the_room():
    code = ("import sys\nfrom shadowless.cli import main\ntry:\n    main(['study', 'paired', '--help'])\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in sys.modules if m.startswith('sim')))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "[]"


def test_motion_writes_json_plot_and_movie(tmp_path, capsys):
    out = tmp_path / "m"
    code = main(["study", "motion", "--camera-scale", "0.1", "--duration", "0.2", "--fps", "10", "--subsets", "P1,P25",
                 "--reactive-rig", "P25", "--rule", "boost", "--out", str(out), "--json"])
    assert code == 0
    doc = json.loads(capsys.readouterr().out)
    assert set(doc["systems"]) == {"P1", "P25", "reactive_100ms"}
    assert doc["parameters"]["frames"] == 2 and doc["parameters"]["camera"] == [259, 194]
    r = doc["systems"]["reactive_100ms"]
    assert r["latency_frames"] == 1 and r["projectors"] == 25 and "integrated_area_overbright_above_10_mm2_s" in r
    assert doc["systems"]["P1"]["integrated_area_above_90_mm2_s"] > 0 == doc["systems"]["P25"]["integrated_area_above_90_mm2_s"]
    full = json.loads((out / "motion.json").read_text())
    assert len(full["per_frame"]["times_s"]) == 2 and set(full["per_frame"]["systems"]) == set(doc["systems"])
    assert cv2.imread(str(out / "motion.png")) is not None
    with av.open(str(out / "motion.mp4")) as c:
        assert sum(1 for _ in c.decode(video=0)) == 2


def test_motion_table(tmp_path, capsys):
    code = main(["study", "motion", "--camera-scale", "0.1", "--duration", "0.1", "--fps", "10", "--subsets", "P25",
                 "--reactive-rig", "P2", "--rule", "suppress", "--no-movie", "--out", str(tmp_path)])
    assert code == 0
    out = capsys.readouterr().out
    assert "reactive_100ms_P2_suppress" in out and "umbra" in out and "plot:" in out and "movie:" not in out


@pytest.mark.parametrize(("argv", "says"), [
    (["--latency", "abc"], "is not a list of latencies"),
    (["--reactive-rig", "P7"], "no rig 'P7'"),
    (["--rule", "boost,shout"], "rules are boost"),
    (["--fps", "0"], "--fps: '0' is not a number"),
    (["--show", "P1,nope", "--duration", "0.1", "--camera-scale", "0.1"], "--show: no system nope"),
])
def test_motion_mistakes_are_one_line_and_status_2(tmp_path, capsys, argv, says):
    try:
        code = main(["study", "motion", "--out", str(tmp_path), *argv])
    except SystemExit as exc:
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert says in err and len(err.splitlines()) == 1 and "Traceback" not in err


def _status_and_error(argv, capsys):
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    return code, capsys.readouterr().err.strip()


@pytest.fixture
def study_files(tmp_path):
    """A rig directory (slots r0c0, r0c1), a configurations file for it and a schedule."""
    from coordinator.rig import init_rig

    init_rig(tmp_path / "rig", name="bench", slots=["r0c0", "r0c1"], width=64, height=48, content_width=80,
             content_height=40)
    (tmp_path / "c.toml").write_text('[configurations]\nA = ["r0c0"]\nB = ["r0c1"]\nC = ["r0c0", "r0c1"]\n')
    (tmp_path / "s.csv").write_text("participant,trial,image,left,right\n1,1,pic.png,A,B\n2,1,pic.png,B,Q\n"
                                    "3,1,pic.png,P25,P1\n4,1,missing.png,A,B\n")
    return tmp_path


@pytest.mark.parametrize(("argv", "says"), [
    (["--only", "P1,P99"], "--only: no configuration P99"),
    (["--only", "P1"], "need at least 2 different configurations"),
    (["--out", "/nonexistent/s.csv"], "no such folder /nonexistent"),
    (["--participants", "0"], "--participants"),
])
def test_schedule_mistakes_are_one_line_and_status_2(tmp_path, capsys, argv, says):
    base = ["study", "schedule", "--participants", "2", "--images", "a.png", "--out", str(tmp_path / "s.csv")]
    code, err = _status_and_error(base + argv, capsys)
    assert code == 2 and says in err and len(err.splitlines()) == 1 and "Traceback" not in err, err


@pytest.mark.parametrize(("participant", "extra", "says"), [
    ("1", ["--no-rig-dir"], "--rig-dir is needed"),
    ("9", [], "has no trials of participant 9"),
    ("2", [], "configuration(s) Q, which"),
    ("3", ["--default-configurations"], "slot(s) p1, r0c2, r0c3, r0c4, r1c0, r1c1, r1c2, r1c3 and 16 more are not"),
    ("4", [], "image 'missing.png' of the schedule is not in"),
    ("1", ["--ratings-in-no-folder"], "cannot create"),
])
def test_run_refuses_before_it_touches_the_rig(study_files, capsys, participant, extra, says):
    ratings = study_files / ("nowhere/r.csv" if "--ratings-in-no-folder" in extra else "r.csv")
    argv = ["study", "run", str(study_files / "s.csv"), "--participant", participant, "--ratings", str(ratings),
            "--coordinator", "127.0.0.1:9"]
    if "--no-rig-dir" not in extra:
        argv += ["--rig-dir", str(study_files / "rig")]
    if "--default-configurations" not in extra:
        argv += ["--configurations", str(study_files / "c.toml")]
    code, err = _status_and_error(argv, capsys)
    assert code == 2 and says in err and len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert err.startswith("shadowless study run: ")


def test_scheffe_analyses_one_image_of_a_run(tmp_path, capsys):
    rows = ["participant,first,second,score,image,trial,answer"]
    for p in (1, 2):
        for img in ("x", "y"):
            rows += [f"{p},A,B,1,{img},1,-1", f"{p},C,A,-2,{img},2,2", f"{p},B,C,{p - 1},{img},3,{1 - p}"]
    (tmp_path / "r.csv").write_text("\n".join(rows) + "\n")
    assert main(["study", "scheffe", str(tmp_path / "r.csv"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["participants"] == 4          # each participant on each image
    assert main(["study", "scheffe", str(tmp_path / "r.csv"), "--image", "y", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["participants"] == 2 and doc["scale"]["A"] == pytest.approx(1.0)   # (1 + 2) * 2 / (3 * 2)
