"""deploy/install-node.sh and deploy/install-coordinator.sh, rehearsed into a staging root.

``--root DIR`` prefixes every path the scripts write and prints what would change the system
itself (apt, the user, chown, systemctl) as "would run: ..."; so the scripts run here as they
would on a node, without root and without the network, and what they leave is inspected.

Offline, pip cannot fetch the dependencies (numpy, grpcio, ...) the real install takes from
PyPI, so the rehearsal installs only shadowless itself into the staged venv
(``--pip-args "--no-index --no-deps --no-build-isolation"``: the checkout is built with the
build backend already installed) and lends it this environment's packages through PYTHONPATH
(the site-packages directory only: neither its ``.pth`` files nor this checkout are on it, so
``shadowless`` is imported from the staged venv). The venv is made by this interpreter
(``--python``), from the same base Python, so those compiled packages fit. Everything else
runs as it would for real: the Python check, venv creation, pip with the pinned constraints, a
checkout copied before pip builds it (node) or a wheel (coordinator), the unit, env and token
files, `shadowless rig init`. Each install takes a few seconds.
"""
from __future__ import annotations

import os
import re
import shutil
import stat
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DEPLOY = REPO / "deploy"
RIG_ID = "3730d2948b80"
PIP_ARGS = "--no-index --no-deps --no-build-isolation --no-cache-dir --quiet"
SITE = sysconfig.get_paths()["purelib"]       # this environment's packages, lent to the staged venv


def script_env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PIP_", "VIRTUAL_ENV"))}
    env["PYTHONPATH"] = SITE
    env.update(extra)
    return env


def run(script: str, *args: str | Path, env: dict[str, str] | None = None, check: bool = True):
    r = subprocess.run(["bash", str(DEPLOY / script), *map(str, args)], capture_output=True, text=True,
                       env=env or script_env(), timeout=300, check=False)
    if check:
        assert r.returncode == 0, f"{script} exited {r.returncode}\n{r.stdout}\n{r.stderr}"
    return r


def install(script: str, root: Path, *args: str | Path, check: bool = True):
    return run(script, "--root", root, "--python", sys.executable, "--pip-args", PIP_ARGS, *args, check=check)


def would_run(output: str) -> list[str]:
    return [line.removeprefix("would run: ") for line in output.splitlines() if line.startswith("would run: ")]


def env_file(path: Path) -> dict[str, str]:
    return dict(line.split("=", 1) for line in path.read_text().splitlines() if line and not line.startswith("#"))


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def staged_version(root: Path) -> str:
    """The staged command runs by itself (no borrowed packages, no checkout on the path)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    r = subprocess.run([str(root / "opt/shadowless/venv/bin/shadowless"), "--version"], capture_output=True,
                       text=True, env=env, cwd=root, timeout=60, check=False)
    assert r.returncode == 0, r.stderr
    return r.stdout.strip()


VENV = Path("opt/shadowless/venv")


def venv_from(node_root: Path, root: Path, *, without_shadowless: bool = False) -> None:
    """Copy the venv the node install made into ``root``, so that the script finds one and installs into
    it, as it would over an earlier install: creating a venv (with pip bootstrapped into it) is most of an
    install's cost, and the node fixture's fresh install checks it. ``without_shadowless``: shadowless is
    taken out of the copy first (every file its RECORD lists), so that only the install under test can
    put it back."""
    shutil.copytree(node_root / VENV, root / VENV, symlinks=True)
    if without_shadowless:
        (site,) = (root / VENV / "lib").glob("python3*/site-packages")
        (dist,) = site.glob("shadowless-*.dist-info")
        for line in (dist / "RECORD").read_text().splitlines():
            (site / line.rsplit(",", 2)[0]).unlink(missing_ok=True)
        shutil.rmtree(dist, ignore_errors=True)
        assert not list(site.glob("shadowless-*.dist-info")) and not (root / VENV / "bin/shadowless").exists()


@pytest.fixture(scope="module")
def token(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("token") / "token"
    p.write_text("s3cret-token-of-the-rig\n")
    p.chmod(0o600)
    return p


@pytest.fixture(scope="module")
def node(tmp_path_factory, token):
    """A node installed from this checkout: (staging root, the script's result)."""
    root = tmp_path_factory.mktemp("node-root")
    before = {p.name for p in REPO.iterdir()}
    r = install("install-node.sh", root, "--slot", "r1c2", "--token", token, "--rig", RIG_ID)
    built_here = sorted(n for n in {p.name for p in REPO.iterdir()} - before if n == "build" or n.endswith(".egg-info"))
    assert not built_here, f"pip built in this checkout ({built_here}), not in a copy"
    return root, r


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """shadowless built as a wheel from a copy of this checkout (what an operator may carry)."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    shutil.copytree(REPO, src, ignore=shutil.ignore_patterns(".git", ".venv", "build", "*.egg-info", "results",
                                                             ".pytest_cache", ".ruff_cache", "__pycache__"))
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index",
                        "--no-cache-dir", "--quiet", "-w", str(tmp / "dist"), str(src)],
                       capture_output=True, text=True, timeout=300, check=False)
    assert r.returncode == 0, r.stderr
    (whl,) = (tmp / "dist").glob("shadowless-*.whl")
    return whl


@pytest.fixture(scope="module")
def coordinator(tmp_path_factory, token, wheel, node):
    """A coordinator installed from a wheel, keeping an existing token, with a 2x2 rig (into a copy of the
    node's venv without shadowless: the wheel is what puts it there)."""
    root = tmp_path_factory.mktemp("coordinator-root")
    venv_from(node[0], root, without_shadowless=True)
    return root, install("install-coordinator.sh", root, "--source", wheel, "--token", token,
                         "--", "--name", "table", "--grid", "2x2")


@pytest.mark.parametrize("script,words", [
    ("install-node.sh", ["--slot", "--token", "--rig", "--output", "--root", "--no-start", "--python", "--source"]),
    ("install-coordinator.sh", ["--rig-dir", "--listen", "--token", "--root", "--no-start", "--python", "--source"]),
])
def test_help(script, words):
    r = run(script, "--help")
    assert r.stdout.startswith("usage:") and not r.stderr
    for w in words:
        assert w in r.stdout, f"{script} --help does not mention {w}"
    assert run(script, "--bogus", check=False).returncode == 2


@pytest.mark.parametrize("script", ["install-node.sh", "install-coordinator.sh"])
def test_a_python_older_than_3_11_is_refused(script, tmp_path, token):
    fake = tmp_path / "bin" / "python3"
    fake.parent.mkdir()
    fake.write_text("#!/bin/sh\necho 'Python 3.9.2'\n")
    fake.chmod(0o755)
    root = tmp_path / "root"
    args = ["--slot", "r0c0", "--token", token] if script == "install-node.sh" else []
    given = run(script, "--root", root, "--python", fake, *args, check=False)
    on_path = run(script, "--root", root, *args, check=False,       # the default, python3, is the fake
                  env=script_env(PATH=f"{fake.parent}{os.pathsep}{os.environ['PATH']}"))
    for r in (given, on_path):
        assert r.returncode == 2, r.stdout + r.stderr
        assert "3.11 or newer" in r.stderr and "3.9" in r.stderr, r.stderr
        assert "would run" not in r.stdout, "refused before anything is done"
    assert not (root / "etc").exists() and not (root / "opt").exists()


def test_a_node_without_slot_or_token_is_refused_before_anything_is_done(tmp_path, token):
    r = install("install-node.sh", tmp_path, "--token", token, check=False)
    assert r.returncode == 2 and "--slot" in r.stderr
    r = install("install-node.sh", tmp_path, "--slot", "r0c0", check=False)
    assert r.returncode == 2 and "--token" in r.stderr
    r = install("install-node.sh", tmp_path, "--slot", "r0c0", "--token", token, "--output", "hdmi", check=False)
    assert r.returncode == 2 and "output 'hdmi'" in r.stderr
    assert not (tmp_path / "opt").exists()


def test_the_node_is_staged_complete(node, token):
    root, r = node
    unit = root / "etc/systemd/system/shadowless-node.service"
    assert unit.read_text() == (DEPLOY / "shadowless-node.service").read_text()
    assert not (root / "etc/systemd/system/shadowless-node.service.d").exists(), "kms needs no X drop-in"
    values = env_file(root / "etc/shadowless/node.env")
    assert (values["SLOT"], values["RIG"], values["OUTPUT"]) == ("r1c2", RIG_ID, "kms")
    assert values["SHADOWLESS_TOKEN_FILE"] == "/etc/shadowless/token"
    staged_token = root / "etc/shadowless/token"
    assert staged_token.read_text() == token.read_text() and mode(staged_token) == 0o600
    assert staged_version(root) == "shadowless 0.1.0"
    assert f"pins: {REPO / 'constraints.txt'}" in r.stdout


def test_the_node_says_what_it_would_do_to_the_system(node):
    root, r = node
    lines = would_run(r.stdout)
    assert "apt-get update -q" in lines
    (apt,) = [line for line in lines if "apt-get install" in line]
    for package in ("python3-venv", "libegl1", "libgl1", "libgl1-mesa-dri", "libgles2", "libsdl2-2.0-0"):
        assert package in apt.split()
    (useradd,) = [line for line in lines if line.startswith("useradd ")]
    assert "--system" in useradd and "--groups video,render shadowless" in useradd
    assert f"chown shadowless:shadowless {root}/etc/shadowless/token" in lines
    assert lines[-3:] == ["systemctl daemon-reload", "systemctl enable shadowless-node.service",
                          "systemctl restart shadowless-node.service"]


def test_a_second_run_keeps_the_env_file_and_the_token(node, tmp_path):
    root, _ = node
    env_path, token_path = root / "etc/shadowless/node.env", root / "etc/shadowless/token"
    edited = env_path.read_text().replace("NODE_ARGS=", "NODE_ARGS=--fetch-rate 20M") + "# tuned by hand\n"
    env_path.write_text(edited)
    before = token_path.read_text()
    unit = root / "etc/systemd/system/shadowless-node.service"
    unit.write_text("# stale\n")
    other = tmp_path / "other-token"
    other.write_text("another rig's token\n")

    r = install("install-node.sh", root, "--slot", "r0c0", "--token", other, "--no-apt", "--no-start")
    assert env_path.read_text() == edited
    assert token_path.read_text() == before and mode(token_path) == 0o600
    assert f"kept the existing {env_path}" in r.stdout and f"kept the existing token {token_path}" in r.stdout
    assert "keeps SLOT=r1c2 (not --slot r0c0)" in r.stderr
    assert unit.read_text() == (DEPLOY / "shadowless-node.service").read_text(), "the unit is ours: replaced"
    lines = would_run(r.stdout)
    assert "systemctl enable shadowless-node.service" in lines
    assert not any("restart" in line or "apt-get" in line for line in lines), "--no-start, --no-apt"
    assert staged_version(root) == "shadowless 0.1.0"


def test_a_window_output_gets_the_x11_dropin(node, tmp_path, token):
    cookie = tmp_path / "cookie"
    cookie.write_bytes(b"\x01\x00MIT-MAGIC-COOKIE-1")
    root = tmp_path / "root"
    venv_from(node[0], root)      # as over a kms node turned window: what is checked is what a window output adds
    r = install("install-node.sh", root, "--slot", "r0c0", "--token", token, "--output", "window:1",
                "--xauthority", cookie, "--no-start")
    dropin = root / "etc/systemd/system/shadowless-node.service.d/x11.conf"
    assert dropin.read_text() == (DEPLOY / "shadowless-node-x11.conf").read_text()
    assert env_file(root / "etc/shadowless/node.env")["OUTPUT"] == "window:1"
    xauth = root / "etc/shadowless/Xauthority"
    assert xauth.read_bytes() == cookie.read_bytes() and mode(xauth) == 0o600
    assert "shadowless[node,kms,window]" in r.stdout
    (apt,) = [line for line in would_run(r.stdout) if "apt-get install" in line]
    assert "libgl1" in apt.split()


def test_the_coordinator_is_staged_complete_with_its_rig(coordinator, token):
    root, r = coordinator
    assert (root / "etc/systemd/system/shadowless-coordinator.service").read_text() == \
        (DEPLOY / "shadowless-coordinator.service").read_text()
    values = env_file(root / "etc/shadowless/coordinator.env")
    assert values["RIG_DIR"] == "/var/lib/shadowless/rig" and values["LISTEN"] == "0.0.0.0:7600"
    assert values["SHADOWLESS_TOKEN_FILE"] == "/var/lib/shadowless/rig/token"
    rig = root / "var/lib/shadowless/rig"
    rig_toml = (rig / "rig.toml").read_text()
    assert re.search(r'^name = "table"', rig_toml, re.MULTILINE)
    rig_id = re.search(r'^id = "(\w+)"', rig_toml, re.MULTILINE).group(1)
    assert f"RIG={rig_id}" in r.stdout, "rig init's hint for the nodes is shown"
    assert (rig / "token").read_text() == token.read_text(), "the given token is kept by rig init"
    assert mode(rig / "token") == 0o600
    assert staged_version(root) == "shadowless 0.1.0"
    assert f"pins: {REPO / 'constraints.txt'}" in r.stdout, "the wheel's pins: the script's checkout's"
    lines = would_run(r.stdout)
    (apt,) = [line for line in lines if "apt-get install" in line]
    assert {"python3-venv", "libegl1", "libgl1", "libgl1-mesa-dri", "libglib2.0-0"} <= set(apt.split())
    assert any(line.startswith("useradd ") and "--groups video,render shadowless" in line for line in lines)
    assert lines[-2:] == ["systemctl enable shadowless-coordinator.service",
                          "systemctl restart shadowless-coordinator.service"]


def test_a_second_coordinator_run_keeps_the_rig_and_its_env(coordinator):
    root, _ = coordinator
    env_path = root / "etc/shadowless/coordinator.env"
    edited = env_path.read_text().replace("COORDINATOR_ARGS=", "COORDINATOR_ARGS=--console 0.0.0.0:7680")
    env_path.write_text(edited)
    rig = root / "var/lib/shadowless/rig"
    rig_toml, token = (rig / "rig.toml").read_text(), (rig / "token").read_text()
    r = install("install-coordinator.sh", root, "--no-apt", "--no-start", "--", "--grid", "5x5")
    assert env_path.read_text() == edited
    assert (rig / "rig.toml").read_text() == rig_toml and (rig / "token").read_text() == token
    assert f"kept the rig in {rig}" in r.stdout and "are unused" in r.stderr


@pytest.mark.parametrize("script", ["install-node.sh", "install-coordinator.sh"])
def test_a_real_install_needs_root(script, token):
    """Without --root it changes the system, so it refuses to start as anyone but root."""
    argv = ["bash", str(DEPLOY / script), "--slot", "r0c0", "--token", str(token)][: 6 if "node" in script else 2]
    if os.geteuid() == 0:                   # be somebody else for the test
        runuser = shutil.which("runuser")
        assert runuser, "runuser (util-linux) is needed to run as another user"
        argv = [runuser, "-u", "nobody", "--", *argv]
    r = subprocess.run(argv, capture_output=True, text=True, timeout=60, cwd="/", check=False)
    assert r.returncode == 2 and "run it as root" in r.stderr, r.stdout + r.stderr
