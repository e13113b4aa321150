"""The service units and environment files stay consistent with the CLI they start."""
from __future__ import annotations

import configparser
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"


def parse_with_the_cli(argv: list[str]):
    import importlib.util

    spec = importlib.util.spec_from_file_location("deploy_cli_check", Path(__file__).with_name("cli_check.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.parse_with_the_cli(argv)


def unit(name: str) -> configparser.ConfigParser:
    cp = configparser.ConfigParser(strict=False, interpolation=None)
    cp.optionxform = str
    cp.read(DEPLOY / name)
    return cp


def env(name: str) -> dict[str, str]:
    out = {}
    for line in (DEPLOY / name).read_text().splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            k, _, v = line.partition("=")
            out[k] = v
    return out


def expand(cmd: str, values: dict[str, str]) -> list[str]:
    """ExecStart's words as systemd makes them (systemd.service(5), "Command lines"): a word
    ``${VAR}`` is exactly one argument, even when empty; a word ``$VAR`` is split at whitespace
    (none when empty); inside a word both are replaced by the value."""
    argv = []
    for word in shlex.split(cmd):
        if m := re.fullmatch(r"\$\{(\w+)\}", word):
            argv.append(values.get(m.group(1), ""))
        elif m := re.fullmatch(r"\$(\w+)", word):
            argv.extend(values.get(m.group(1), "").split())
        else:
            argv.append(re.sub(r"\$\{?(\w+)\}?", lambda m: values.get(m.group(1), ""), word))
    return argv


@pytest.mark.parametrize("service,envfile,command", [
    ("shadowless-node.service", "node.env", "node"),
    ("shadowless-coordinator.service", "coordinator.env", "coordinator"),
])
def test_unit_starts_a_valid_command_and_restarts_on_failure(service, envfile, command):
    u = unit(service)
    svc = u["Service"]
    assert svc["Restart"] == "on-failure"
    assert svc["EnvironmentFile"].endswith(envfile)
    values = env(envfile)
    assert "SHADOWLESS_TOKEN_FILE" in values, "the token is read from a file named in the environment"
    argv = expand(svc["ExecStart"], values)
    assert argv[1] == command
    assert not any("token" in a for a in argv), "the token must never be on the command line"
    # every flag the unit passes is one the command accepts

    help_text = subprocess.run([sys.executable, "-m", "shadowless", command, "--help"], capture_output=True, text=True).stdout
    for a in argv[2:]:
        if a.startswith("--"):
            assert a in help_text, f"{service} passes {a}, which `shadowless {command}` does not accept"


def test_node_unit_grants_only_what_the_realtime_swap_needs():
    svc = unit("shadowless-node.service")["Service"]
    assert svc["AmbientCapabilities"] == "CAP_SYS_NICE"
    assert svc["User"] != "root"


def test_the_node_unit_pins_its_rig_by_id():
    values = env("node.env")
    assert "RIG" in values, "node.env names the rig the node joins"
    argv = expand(unit("shadowless-node.service")["Service"]["ExecStart"], {**values, "RIG": "3730d2948b80"})
    assert argv[argv.index("--rig") + 1] == "3730d2948b80"


@pytest.mark.parametrize("service,envfile", [
    ("shadowless-node.service", "node.env"),
    ("shadowless-coordinator.service", "coordinator.env"),
])
def test_the_command_the_unit_runs_parses(service, envfile):
    values = env(envfile)
    argv = expand(unit(service)["Service"]["ExecStart"], values)
    args = parse_with_the_cli(argv[1:])
    if service == "shadowless-node.service":
        assert args.output == "kms", "a node drives its HDMI output without X by default"
        assert str(args.cache_dir) == values["CACHE_DIR"]


def test_the_units_tell_systemd_when_they_are_ready_and_alive():
    for service, watchdog in (("shadowless-node.service", "10s"), ("shadowless-coordinator.service", "30s")):
        u = unit(service)
        svc = u["Service"]
        assert svc["Type"] == "notify" and svc["NotifyAccess"] == "main"
        assert svc["WatchdogSec"] == watchdog
        assert svc["User"] == "shadowless"
        assert u["Install"]["WantedBy"] == "multi-user.target", "Raspberry Pi OS Lite boots to multi-user"


def test_the_node_unit_reaches_the_display_and_gpu_without_x():
    svc = unit("shadowless-node.service")["Service"]
    assert set(svc["SupplementaryGroups"].split()) == {"video", "render"}
    assert svc["LimitRTPRIO"] and svc["CapabilityBoundingSet"] == "CAP_SYS_NICE"
    assert "DISPLAY" not in (DEPLOY / "shadowless-node.service").read_text().replace("# ", "")
    assert env("node.env")["CACHE_DIR"].startswith("/var/lib/shadowless/"), "the only writable place"
    assert "/var/lib/shadowless" in svc["ReadWritePaths"].split() and svc["ProtectSystem"] == "strict"


def test_the_x11_dropin_points_the_node_at_the_desktop():
    lines = (DEPLOY / "shadowless-node-x11.conf").read_text().splitlines()
    environment = dict(line.removeprefix("Environment=").split("=", 1) for line in lines
                       if line.startswith("Environment="))
    assert environment["DISPLAY"] == ":0"
    assert environment["XAUTHORITY"] == "/etc/shadowless/Xauthority"


def test_the_coordinator_sees_the_machines_tmp_and_writes_under_var_lib():
    svc = unit("shadowless-coordinator.service")["Service"]
    assert "PrivateTmp" not in svc, "paths operators give (--record, a mesh) must mean this machine's"
    assert "/var/lib/shadowless" in svc["ReadWritePaths"].split() and svc["ProtectSystem"] == "strict"
