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
