"""`shadowless study`: the analyses through the real CLI (registered in shadowless/cli.py), run in the
test's interpreter (output captured at the file descriptors), the first analysis also as a real process."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from cli_inprocess import cli_capture, run_here  # noqa: F401 - cli_capture: the module's autouse fixture


def study(*args, process: bool = False) -> subprocess.CompletedProcess:
    """`shadowless study ARGS...`: in this interpreter, or with ``process`` as a real process."""
    argv = ["study", *map(str, args)]
    if process:
        return subprocess.run([sys.executable, "-m", "shadowless", *argv], capture_output=True, text=True, timeout=120)
    code, out, err = run_here(argv)
    return subprocess.CompletedProcess(argv, code, out, err)


def test_scheffe_and_paired_from_csv(tmp_path):
    rng = np.random.default_rng(0)
    effects = {"P1": -1.0, "P9D": 0.3, "P9W": 0.0, "P25": 0.7}
    names = list(effects)
    lines = ["participant,first,second,score"]
    for person in range(10):
        for i in range(4):
            for j in range(i + 1, 4):
                v = np.clip(np.round(effects[names[i]] - effects[names[j]] + rng.normal(0, 0.7)), -2, 2)
                lines.append(f"s{person},{names[i]},{names[j]},{v:g}")
    (tmp_path / "r.csv").write_text("\n".join(lines) + "\n")
    done = study("scheffe", tmp_path / "r.csv", "--json", "--chart", tmp_path / "c.svg", process=True)
    assert done.returncode == 0, done.stderr
    d = json.loads(done.stdout)
    assert max(d["scale"], key=d["scale"].get) == "P25" and min(d["scale"], key=d["scale"].get) == "P1"
    assert (tmp_path / "c.svg").read_text().startswith("<svg")
    table = study("scheffe", tmp_path / "r.csv")
    assert "yardstick Y(.05)" in table.stdout and "main effect" in table.stdout

    times = ["participant,condition,time_s"] + [f"p{i},P1,{2.0 + 0.1 * i}" for i in range(8)] + \
        [f"p{i},P25,{1.5 + 0.11 * i + 0.02 * (i % 3)}" for i in range(8)]
    (tmp_path / "t.csv").write_text("\n".join(times) + "\n")
    done = study("paired", tmp_path / "t.csv", "--json")
    assert done.returncode == 0, done.stderr
    d = json.loads(done.stdout)
    assert d["conditions"] == ["P1", "P25"] and d["p"] < 0.01 and d["geometric_mean_ratio"] < 1 and d["statistic"] < 0


def test_bad_study_files_are_one_line_and_status_2(tmp_path):
    (tmp_path / "bad.csv").write_text("who,what\n")
    for args in (("scheffe", tmp_path / "bad.csv"), ("paired", tmp_path / "bad.csv"),
                 ("scheffe", tmp_path / "missing.csv")):
        done = study(*args)
        assert done.returncode == 2 and "Traceback" not in done.stderr
        assert len(done.stderr.strip().splitlines()) == 1, done.stderr


def test_study_help_loads_no_study_and_a_subcommand_loads_only_its_own():
    """Every subcommand comes from one table and is imported only when it is the one given."""
    code = ("import sys\nfrom shadowless.cli import main\nfrom shadowless.study import ANALYSES\n"
            "for argv in (['study', '--help'], ['study', 'paired', '--help']):\n"
            "    try:\n        main(argv)\n    except SystemExit:\n        pass\n"
            "    print(sorted(name for name, (module, _) in ANALYSES.items() if module in sys.modules), file=sys.stderr)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stderr.strip().splitlines()[-2:] == ["[]", "['paired']"], done.stderr[-2000:]


def test_every_study_subcommand_explains_itself_and_takes_the_log_options():
    from shadowless.study import ANALYSES

    for name, (_, summary) in ANALYSES.items():
        done = study(name, "--help")
        assert done.returncode == 0, (name, done.stderr)
        assert done.stdout.startswith(f"usage: shadowless study {name} ") and "--log-level" in done.stdout, name
    listing = study("--help").stdout
    for name, (_, summary) in ANALYSES.items():
        assert f"shadowless study {name}" in listing and summary.split()[0] in listing, name
