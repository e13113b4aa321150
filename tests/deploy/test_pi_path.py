"""The Raspberry Pi path around the install: a node that finds no coordinator or finds the display
held by a desktop says so in one line and exits with its own status (no traceback, no restart loop),
and the install compiles what has no wheel for the machine with the build tools it installs then.

The arm64 install itself runs in deploy/check-arm64.sh (about 10 minutes under qemu; not here).
"""
from __future__ import annotations

import configparser
import grp
import io
import os
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pip
import pytest

from node.display_check import DISPLAY_HELD_EXIT, display_conflict, running_programs
from protos import auth

REPO = Path(__file__).resolve().parents[2]
DEPLOY = REPO / "deploy"


def node(token: Path, *args: str, env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "shadowless", "node", "--slot", "r0c0", "--token-file", str(token),
                           *args], capture_output=True, text=True, timeout=120, env=env)


def said(stderr: str) -> list[str]:
    """The warnings and errors among the node's log lines."""
    return [line for line in stderr.splitlines() if " ERROR " in line or " WARNING " in line]


def token_file(tmp_path: Path) -> Path:
    p = tmp_path / "token"
    p.write_text(auth.new_token() + "\n")
    p.chmod(0o600)
    return p


def test_a_node_that_finds_no_coordinator_gives_up_in_one_line(tmp_path):
    own = f"_sl-pi-{os.getpid() % 10**6}"      # a service nobody advertises
    r = node(token_file(tmp_path), "--mdns-interface", "127.0.0.1", "--discovery-timeout", "1", "--cache-dir",
             str(tmp_path / "cache"), env={**os.environ, "SHADOWLESS_MDNS_SERVICE": own})
    assert r.returncode == 4 and "Traceback" not in r.stderr, r.stderr
    (line,) = said(r.stderr)
    assert f"no coordinator advertised {own}._tcp.local. on 127.0.0.1" in line and "--coordinator HOST:PORT" in line
    assert "gave up after --discovery-timeout 1 s" in line


def test_a_wayland_session_is_named_before_the_window_is_opened(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "DISPLAY"}
    r = node(token_file(tmp_path), "--output", "window", env={**env, "WAYLAND_DISPLAY": "wayland-1"})
    assert r.returncode == DISPLAY_HELD_EXIT and "Traceback" not in r.stderr, r.stderr
    (line,) = r.stderr.strip().splitlines()
    assert "WAYLAND_DISPLAY=wayland-1" in line and "raspi-config" in line and "--output kms" in line


def test_a_desktop_holding_the_display_is_found_among_the_processes(tmp_path):
    proc = tmp_path / "proc"
    for pid, name in ((1, "systemd"), (812, "wayfire"), (900, "Xvfb"), (901, "Xwayland")):
        (proc / str(pid)).mkdir(parents=True)
        (proc / str(pid) / "comm").write_text(name + "\n")
    (proc / "self").mkdir()
    desktop = running_programs(proc)
    assert desktop == {"systemd", "wayfire", "Xvfb", "Xwayland"}
    kms = display_conflict("kms", {}, desktop)
    assert "Wayland desktop (wayfire)" in kms and "set-default multi-user.target" in kms
    assert "raspi-config" in display_conflict("window", {"DISPLAY": ":0"}, desktop)
    assert "X server (Xorg)" in display_conflict("kms", {}, {"Xorg", "lightdm"})
    # a virtual X server holds no display; offscreen and the room never need one
    assert display_conflict("window", {"DISPLAY": ":99"}, {"Xvfb"}) is None
    assert display_conflict("kms", {}, {"Xvfb", "systemd"}) is None
    assert display_conflict("offscreen", {"WAYLAND_DISPLAY": "wayland-1"}, desktop) is None
    assert display_conflict("room", {}, desktop) is None


def test_the_node_unit_does_not_restart_a_node_the_desktop_keeps_from_the_display():
    cp = configparser.ConfigParser(strict=False, interpolation=None)
    cp.read(DEPLOY / "shadowless-node.service")
    assert cp["Service"]["RestartPreventExitStatus"].split() == [str(DISPLAY_HELD_EXIT)]


def fake_wheel(where: Path, requires: list[str]) -> Path:
    """A shadowless wheel of one module whose command prints its version, requiring ``requires``."""
    whl = where / "shadowless-0.1.0-py3-none-any.whl"
    info = "shadowless-0.1.0.dist-info"
    with zipfile.ZipFile(whl, "w") as z:
        z.writestr("fake_shadowless.py", "def main():\n    print('shadowless 0.1.0')\n")
        z.writestr(f"{info}/METADATA", "Metadata-Version: 2.1\nName: shadowless\nVersion: 0.1.0\nProvides-Extra: node\n"
                   "Provides-Extra: kms\n" + "".join(f"Requires-Dist: {r}\n" for r in requires))
        z.writestr(f"{info}/WHEEL", "Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\nTag: py3-none-any\n")
        z.writestr(f"{info}/entry_points.txt", "[console_scripts]\nshadowless = fake_shadowless:main\n")
        z.writestr(f"{info}/RECORD", "")
    return whl


BACKEND = """import os, zipfile
NAME, VERSION = {name!r}, {version!r}


def get_requires_for_build_wheel(config_settings=None):
    return []


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):
    whl = f"{{NAME}}-{{VERSION}}-py3-none-any.whl"
    info = f"{{NAME}}-{{VERSION}}.dist-info"
    with zipfile.ZipFile(os.path.join(wheel_directory, whl), "w") as z:
        z.writestr(f"{{NAME}}.py", "")
        z.writestr(f"{{info}}/METADATA", f"Metadata-Version: 2.1\\nName: {{NAME}}\\nVersion: {{VERSION}}\\n")
        z.writestr(f"{{info}}/WHEEL", "Wheel-Version: 1.0\\nGenerator: test\\nRoot-Is-Purelib: true\\nTag: py3-none-any\\n")
        z.writestr(f"{{info}}/RECORD", "")
    return whl
"""


def fake_sdist(where: Path, name: str, version: str) -> Path:
    """A source distribution of one empty module, built by a backend of its own (nothing to fetch):
    what a package without a wheel for the machine offers."""
    top = f"{name}-{version}"
    sdist = where / f"{top}.tar.gz"
    files = {"pyproject.toml": '[build-system]\nrequires = []\nbuild-backend = "backend"\nbackend-path = ["."]\n',
             "backend.py": BACKEND.format(name=name, version=version),
             "PKG-INFO": f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n"}
    with tarfile.open(sdist, "w:gz") as t:
        for path, text in files.items():
            data = text.encode()
            info = tarfile.TarInfo(f"{top}/{path}")
            info.size = len(data)
            t.addfile(info, io.BytesIO(data))
    return sdist


def test_the_install_brings_the_build_tools_for_what_has_no_wheel(tmp_path):
    """Staged (--root), from a directory of packages: a pinned package without a wheel for this
    machine (as moderngl 5.13.0 on aarch64) has the script install g++ and Python's headers before
    pip builds it; then `shadowless` is linked onto the PATH and the token shared with the operators."""
    token, root, found = token_file(tmp_path), tmp_path / "root", tmp_path / "packages"
    found.mkdir()
    fake_sdist(found, "moderngl", "5.13.0")
    wheel = fake_wheel(tmp_path, ["moderngl>=5.10; extra == 'node'"])
    # the venv made beforehand (the script keeps one that is there), lent this environment's pip by a
    # .pth file: ensurepip costs most of a minute on a loaded machine and is not what is tested here
    venv = root / "opt/shadowless/venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    lend = tmp_path / "lent"
    lend.mkdir()
    (lend / "pip").symlink_to(Path(pip.__file__).parent)
    site = subprocess.run([str(venv / "bin/python"), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          capture_output=True, text=True, check=True).stdout.strip()
    Path(site, "lent-pip.pth").write_text(f"{lend}\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PIP_", "VIRTUAL_ENV"))}
    r = subprocess.run(["bash", str(DEPLOY / "install-node.sh"), "--root", str(root), "--python", sys.executable,
                        "--slot", "r0c0", "--token", str(token), "--source", str(wheel), "--pip-args",
                        f"--no-index --find-links {found} --no-cache-dir --quiet"],
                       capture_output=True, text=True, timeout=300, env={**env, "PIP_CONFIG_FILE": os.devnull})
    assert r.returncode == 0, r.stdout + r.stderr
    assert "no wheel for this machine" in r.stdout and "of moderngl 5.13.0: pip compiles" in r.stdout, r.stdout
    (build,) = [line for line in r.stdout.splitlines() if line.startswith("would run:") and "g++" in line.split()]
    assert {"g++", "libc6-dev", "python3-dev", "libx11-dev"} <= set(build.split()) and "apt-get install" in build
    assert os.readlink(root / "usr/local/bin/shadowless") == "/opt/shadowless/venv/bin/shadowless"
    staged = root / "etc/shadowless/token"
    assert f"would run: chgrp shadowless {staged}" in r.stdout and f"would run: chmod 0640 {staged}" in r.stdout


def test_a_token_readable_by_the_operators_group_only_is_accepted(tmp_path):
    """Mode 0640 is refused for any group but the operators' (the install's `shadowless` group)."""
    token = token_file(tmp_path)
    token.chmod(0o640)
    group = grp.getgrgid(token.stat().st_gid).gr_name
    if group == auth.OPERATORS_GROUP:
        assert auth.read_token(token)
    else:
        with pytest.raises(auth.TokenError, match="can be read by its group"):
            auth.read_token(token)
    token.chmod(0o604)
    with pytest.raises(auth.TokenError, match="every user"):
        auth.read_token(token)
