"""`shadowless bench --keep-json FILE`: the benchmark's own JSON, kept with the command, date,
machine and load, scratch paths cut; refused before anything runs when FILE cannot be written."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from bench.keep import cut_paths, last_document
from cli_inprocess import run_shadowless

REPO = Path(__file__).resolve().parents[2]


def test_a_cheap_benchmark_is_kept_with_its_command_and_still_printed(tmp_path):
    scratch = tmp_path / "scratch"
    r = subprocess.run(
        [sys.executable, "-m", "shadowless", "bench", "--note", "a test run", "image_bombs", "--formats", "PNG",
         "--no-before", "--keep", str(scratch), "--keep-json", str(tmp_path)],   # a directory: DIR/NAME.json
        cwd=REPO, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    printed = json.loads(r.stdout)                      # stdout is the benchmark's document, as without the option
    kept = json.loads((tmp_path / "image_bombs.json").read_text())
    assert f"kept the JSON in {tmp_path / 'image_bombs.json'}" in r.stderr
    assert kept["name"] == "image_bombs"
    assert kept["command"] == "shadowless bench image_bombs --formats PNG --no-before --keep scratch"
    assert kept["result"] == printed and printed["benchmark"] == "image_bombs"
    assert kept["source"] == "a test run. Paths of the run's scratch files are cut to their names."
    assert kept["exit_status"] == 0 and kept["machine"]["cpus"] >= 1 and kept["date"] == kept["started"][:10]
    assert all(len(kept["load"][k]) == 3 for k in ("start", "end"))
    assert "/tmp" not in json.dumps(kept) and (scratch / "image_bombs").is_dir()


def test_a_file_that_cannot_be_written_is_refused_before_the_run(tmp_path, capfd):
    for value, says in ((tmp_path / "none" / "x.json", "there is no directory"),
                        (tmp_path / "x.txt", "name a .json file or an existing directory")):
        code, out, err = run_shadowless(["bench", "image_bombs", "--formats", "NOPE", "--keep-json", value], capfd)
        assert code == 2 and says in err and "--formats" not in err and out == ""   # refused before --formats is read
    code, _, err = run_shadowless(["bench", "--note", "x", "image_bombs"], capfd)
    assert code == 2 and "--note goes with --keep-json" in err
    assert list(tmp_path.iterdir()) == []


def test_scratch_paths_are_cut_to_names_and_the_checkout_made_relative():
    doc = {"picture": "/tmp/run-1/out/p.png", "logs /tmp/a/b.log:": ["see /tmp/a/n.log.", "/tmpfoo/x"],
           "rig": "/repo/rigs/table", "root": "/repo", "other": "/repository/x", "n": 3}
    out, cut = cut_paths(doc, repo=Path("/repo"), scratch=["/tmp"])
    assert cut and out == {"picture": "p.png", "logs b.log:": ["see n.log.", "/tmpfoo/x"],
                           "rig": "rigs/table", "root": ".", "other": "/repository/x", "n": 3}
    assert cut_paths({"a": "/var/tmp/x"}, repo=Path("/repo"), scratch=["/tmp"]) == ({"a": "/var/tmp/x"}, False)


def test_a_checkout_under_the_temporary_directory_is_still_the_checkout():
    # a clone in /tmp runs the suite: its interpreter's path is the checkout's, made relative, not cut
    doc = {"command": "/tmp/ci/.venv/bin/python -c x", "log": "/tmp/run-1/a.log"}
    out, cut = cut_paths(doc, repo=Path("/tmp/ci"), scratch=["/tmp"])
    assert out == {"command": ".venv/bin/python -c x", "log": "a.log"} and cut
    assert cut_paths({"command": "/tmp/ci/.venv/bin/python"}, repo=Path("/tmp/ci"), scratch=["/tmp"]) == \
        ({"command": ".venv/bin/python"}, False)


def test_the_last_json_document_among_printed_lines():
    text = 'progress 1\n{"a": 1}\nnot json {\n{\n "b": [1,\n  2]\n}\ntail\n'
    assert last_document(text) == {"b": [1, 2]}
    assert last_document("no document here\n") is None


def test_any_command_s_printed_figures_are_kept_as_json_or_as_lines(tmp_path, capfd):
    from bench.keep import main

    prog = "import json; print('fitting'); print(json.dumps({'knee': 17}))"
    assert main([str(tmp_path / "fig.json"), "--note", "a check", "--", sys.executable, "-c", prog]) == 0
    kept = json.loads((tmp_path / "fig.json").read_text())
    assert kept["result"] == {"knee": 17} and kept["source"] == "a check" and kept["name"] == "fig"
    assert "fitting" in capfd.readouterr().out                   # the output passes through
    assert main([str(tmp_path / "text.json"), "--", sys.executable, "-c", "print('16.3 projectors');print(' ')"]) == 0
    assert json.loads((tmp_path / "text.json").read_text())["result"] == {"text": ["16.3 projectors"]}
    assert main([str(tmp_path / "none.json"), "--", sys.executable, "-c", "raise SystemExit(3)"]) == 3
    assert not (tmp_path / "none.json").exists() and "printed nothing" in capfd.readouterr().err


def test_the_benchmark_sees_its_own_arguments_only(tmp_path, capsys):
    import argparse

    from bench.keep import run_kept

    args = argparse.Namespace(bench="probe", keep_json=str(tmp_path), keep_note="n", seconds=2)
    assert run_kept(args, lambda a: print(json.dumps({"parameters": vars(a)}))) == 0
    kept = json.loads((tmp_path / "probe.json").read_text())
    assert kept["result"] == {"parameters": {"bench": "probe", "seconds": 2}} and kept["source"] == "n"
    assert json.loads(capsys.readouterr().out) == kept["result"]
