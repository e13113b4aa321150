"""The one `shadowless` command: help that teaches, and the operator commands against a real rig.

The commands run in the test's interpreter (``shadowless.cli.main``, output captured at the file
descriptors), except a few (:func:`sh`) that run as real processes to show what a shell sees: the
help, a refusal and a status against the rig."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from waits import wait_until

from cli_inprocess import run_shadowless
from shadowless.cli import COMMANDS


def sh(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """`python -m shadowless ARGS...`: a real process."""
    return subprocess.run([sys.executable, "-m", "shadowless", *args], capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def here(capfd):
    """``here(*args)``: `shadowless ARGS...` in this interpreter, as a CompletedProcess."""
    def run(*args: str) -> subprocess.CompletedProcess:
        code, out, err = run_shadowless(list(args), capfd)
        return subprocess.CompletedProcess(["shadowless", *args], code, out, err)
    return run


def test_top_level_help_lists_every_command_and_a_workflow():
    out = sh("--help").stdout
    for name in COMMANDS:
        assert name in out
    assert "rig init" in out and "shadowless local" in out


@pytest.mark.parametrize("command", ["coordinator", "node", "rig", "status", "show", "play", "configure", "local", "content", "bench"])
def test_each_command_explains_itself(command, here):
    r = here(command, "--help")
    assert r.returncode == 0, r.stderr
    assert len(r.stdout.splitlines()) > 5


@pytest.mark.parametrize("command", ["status", "show", "play", "pattern", "solo", "cue"])
def test_the_quickstarts_commands_teach_with_examples(command, here):
    """The quickstart says `shadowless COMMAND --help` explains each command with examples: those it
    uses do, and status explains its table's columns."""
    out = here(command, "--help").stdout
    assert "\nexamples:\n" in out and f"  shadowless {command} " in out, out
    if command == "status":
        assert "the table's columns:" in out and "left (it stopped on purpose" in out


def test_node_help_documents_the_clock_test_hooks(here):
    out = here("node", "--help").stdout
    assert "--clock-offset-ms" in out and "--clock-drift-ppm" in out and "--protocol-version" not in out


def test_rig_init_and_show(tmp_path, here):
    r = here("rig", "init", str(tmp_path / "r"), "--grid", "3x2", "--resolution", "1280x800")
    assert r.returncode == 0, r.stderr
    doc = json.loads(here("rig", "show", str(tmp_path / "r")).stdout)
    assert sorted(doc["slots"]) == ["r0c0", "r0c1", "r0c2", "r1c0", "r1c1", "r1c2"]
    assert doc["slots"]["r0c0"]["size"] == [1280, 800]
    again = here("rig", "init", str(tmp_path / "r"))
    assert again.returncode == 2 and "already holds a rig" in again.stderr


def test_missing_rig_directory_is_a_clear_error(tmp_path):
    r = sh("coordinator", "--rig", str(tmp_path / "nope"), "--listen", "127.0.0.1:0", "--no-mdns")
    assert r.returncode == 2 and "not a rig directory" in r.stderr and "rig init" in r.stderr


def test_operator_commands_against_a_running_rig(tmp_path, here):
    import cv2

    from shadowless.local import LocalRig

    rig = LocalRig(["r0c0", "r0c1"], tmp_path, output_size=(48, 32), content_size=(48, 32), snapshots=True, mdns=False)
    with rig:
        rig.wait_ready()
        conn = ["--coordinator", f"127.0.0.1:{rig.port}", "--rig-dir", str(rig.rig_dir)]
        st = wait_until(lambda: json.loads(sh("status", "--json", *conn).stdout),
                        lambda st: all(n["state"] == "live" for n in st["nodes"]), what="both nodes live")
        assert st["rig"]["name"] == rig.rig_name and {n["slot"] for n in st["nodes"]} == {"r0c0", "r0c1"}
        table = here("status", *conn).stdout
        assert "r0c0" in table and "live" in table and "skew" in table

        h = np.array([[1.0, 0, 2], [0, 1.0, 1], [0, 0, 1]])
        np.save(tmp_path / "h.npy", h)
        r = here("configure", "--slot", "r0c1", "--homography", str(tmp_path / "h.npy"), "--gain", "0.5", *conn)
        assert r.returncode == 0 and "revision" in r.stdout, r.stderr
        r = here("configure", "--slot", "r0c1", "--gain", "0", *conn)            # 0 is a gain (light off), not "unchanged"
        assert r.returncode == 0, r.stderr
        assert json.loads((rig.rig_dir / "slots" / "r0c1.json").read_text())["gain"] == 0.0
        for bad_args, says in ((["--gain", "-1"], "--gain: '-1' is not a number from 0 to 16"),
                               (["--gain", "nan"], "--gain: 'nan' is not a number from 0 to 16"),
                               ([], "nothing to change on slot 'r0c1'")):
            before = (rig.rig_dir / "slots" / "r0c1.json").read_bytes()
            r = here("configure", "--slot", "r0c1", *bad_args, *conn)
            assert r.returncode != 0 and says in r.stderr and "Traceback" not in r.stderr, (bad_args, r.stderr)
            assert (rig.rig_dir / "slots" / "r0c1.json").read_bytes() == before, "a refusal changes nothing stored"
        here("configure", "--slot", "r0c1", "--gain", "1", *conn)

        img = np.full((32, 48, 3), 40000, np.uint16)
        cv2.imwrite(str(tmp_path / "grey.png"), img)
        r = here("show", str(tmp_path / "grey.png"), "--persist", *conn)
        assert r.returncode == 0, r.stderr
        # r0c0 was never calibrated: it shows black, and the operator is told so
        assert "warning: 1 slot has no pose and shows black: r0c0" in r.stderr and "shadowless calibrate" in r.stderr
        r = here("play", "--pattern", "counter", "--frames", "15", "--fps", "15", "--json", "--allow-partial", *conn)
        assert r.returncode == 0, r.stderr
        played = json.loads(r.stdout)
        assert played["frames_sent"] == 15 and played["nodes"] == 2
        # frames sent a microsecond ahead of their time arrive late: the goal was not reached, exit 1
        late = ["play", "--pattern", "counter", "--frames", "10", "--fps", "30", "--latency-ms", "0.001", *conn]
        r = here(*late)
        assert r.returncode == 1 and "were not shown by every live node" in r.stderr and "--allow-partial" in r.stderr
        r = here(*late, "--allow-partial")
        assert r.returncode == 0 and "note:" in r.stderr, r.stderr
        r = here("play", "--pattern", "counter", "--latency-ms", "-5", *conn)
        assert r.returncode == 2 and "--latency-ms" in r.stderr and "Traceback" not in r.stderr

        bad = sh("status", "--coordinator", f"127.0.0.1:{rig.port}", "--token-file", str(tmp_path / "h.npy"))
        assert bad.returncode == 2 and "token" in bad.stderr
