"""One logging set-up for every process: -v/-q, and journald's priorities without a second timestamp."""
from __future__ import annotations

import argparse
import logging
import os
import re
import subprocess
import sys

import pytest

from protos import logging_setup as ls


@pytest.fixture
def restore_root():
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    yield
    for h in list(root.handlers):
        root.removeHandler(h)
    for h in handlers:
        root.addHandler(h)
    root.setLevel(level)


def lines_of(path) -> list[str]:
    return path.read_text().splitlines()


def test_terminal_lines_carry_time_level_and_tag_once(tmp_path, restore_root):
    out = tmp_path / "log.txt"
    with open(out, "w") as f:
        ls.setup("info", name="node r0c0", stream=f, journald=False)
        logging.getLogger("node").info("joined")
        logging.getLogger("node.link").warning("slow")
        logging.getLogger("node").debug("hidden")
    first, second = lines_of(out)
    assert re.match(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3} INFO    node r0c0: joined$", first), first
    assert second.endswith("WARNING node r0c0 node.link: slow"), second


def test_journald_lines_carry_the_priority_and_no_time(tmp_path, restore_root, monkeypatch):
    out = tmp_path / "journal.txt"
    with open(out, "w") as f:
        st = os.fstat(f.fileno())
        monkeypatch.setenv("JOURNAL_STREAM", f"{st.st_dev}:{st.st_ino}")
        assert ls.journald_stderr(f)
        ls.setup("debug", name="coordinator", stream=f)
        log = logging.getLogger("coordinator.server")
        log.debug("d")
        log.info("i")
        log.warning("w")
        log.error("e")
        try:
            raise ValueError("boom")
        except ValueError:
            log.exception("failed")
    got = lines_of(out)
    assert got[:4] == ["<7>coordinator coordinator.server: d", "<6>coordinator coordinator.server: i",
                       "<4>coordinator coordinator.server: w", "<3>coordinator coordinator.server: e"]
    assert all(line.startswith("<3>") for line in got[4:]), "a traceback keeps its priority on every line"
    assert any("ValueError: boom" in line for line in got[4:])
    assert not any(re.search(r"\d\d:\d\d:\d\d", line) for line in got)


def test_another_stream_than_the_journals_is_not_mistaken_for_it(tmp_path, monkeypatch):
    with open(tmp_path / "a", "w") as a, open(tmp_path / "b", "w") as b:
        st = os.fstat(a.fileno())
        monkeypatch.setenv("JOURNAL_STREAM", f"{st.st_dev}:{st.st_ino}")
        assert ls.journald_stderr(a) and not ls.journald_stderr(b)
        monkeypatch.setenv("JOURNAL_STREAM", "garbage")
        assert not ls.journald_stderr(a)


@pytest.mark.parametrize("argv, default, level", [
    ([], "warning", logging.WARNING), (["-v"], "warning", logging.INFO), (["-vv"], "warning", logging.DEBUG),
    (["-vvvv"], "warning", logging.DEBUG), (["-q"], "info", logging.WARNING), (["-qqqq"], "info", logging.CRITICAL),
    (["-vv", "--log-level", "error"], "info", logging.ERROR),
])
def test_verbosity_moves_from_the_commands_default(argv, default, level):
    p = argparse.ArgumentParser()
    ls.add_verbosity_args(p, default=default)
    assert ls.level_from_args(p.parse_args(argv)) == level


def test_a_node_under_systemd_writes_priorities_through_the_real_cli(tmp_path):
    """The node's refusal of a missing token file, as journald would receive it."""
    err = tmp_path / "stderr"
    with open(err, "w") as f:
        st = os.fstat(f.fileno())
        env = {**os.environ, "JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"}
        env.pop("SHADOWLESS_TOKEN_FILE", None)
        r = subprocess.run([sys.executable, "-m", "shadowless", "node", "--slot", "r0c0", "--token-file",
                            str(tmp_path / "missing")], stderr=f, env=env, timeout=60)
    assert r.returncode == 2
    line = err.read_text().strip()
    assert line.startswith("<3>node r0c0: ") and str(tmp_path / "missing") in line, line


def test_quiet_and_verbose_reach_a_subcommand_after_its_action(tmp_path):
    """-v after a sub-action (content list) is accepted, and adds to what came before it."""
    r = subprocess.run([sys.executable, "-m", "shadowless", "content", "-q", "list", "-v", "--rig-dir",
                        str(tmp_path / "none")], capture_output=True, text=True, timeout=60)
    assert "unrecognized arguments" not in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_lines_follow_stderr_when_it_is_replaced_after_set_up(tmp_path, restore_root, monkeypatch):
    """A command run in-process (as tests and the demo do) sets logging up on the stderr of the
    moment; when that stream is replaced and closed, lines go to the new one, never to the closed."""
    first, second = tmp_path / "first", tmp_path / "second"
    with open(first, "w") as f:
        monkeypatch.setattr(sys, "stderr", f)
        ls.setup("info", name="coordinator", journald=False)
        logging.getLogger("coordinator").info("one")
    with open(second, "w") as f:
        monkeypatch.setattr(sys, "stderr", f)
        logging.getLogger("coordinator").info("two")
    assert [ln.endswith("coordinator: one") for ln in lines_of(first)] == [True]
    assert [ln.endswith("coordinator: two") for ln in lines_of(second)] == [True]
