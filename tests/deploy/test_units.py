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
    cmd = re.sub(r"\$\{(\w+)\}", lambda m: values.get(m.group(1), ""), cmd)
    cmd = re.sub(r"\$(\w+)", lambda m: values.get(m.group(1), ""), cmd)
    return shlex.split(cmd)


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
