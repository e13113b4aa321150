"""systemd itself reads the units and the x11 drop-in without a word of complaint, and the boot
transaction they join once enabled has no ordering cycle.

`systemd-analyze verify` loads unit files as the service manager would (every key, every
value, the drop-ins of ``NAME.service.d/`` next to the file, the units they name) and prints
what it ignores or refuses. A misspelt value ("Failed to parse service type, ignoring") or an
unknown key only prints a line and still exits 0, so the tests require silence, not just the
exit status. What verify checks outside the files is kept true in a copy: ExecStart's program
must be executable (it becomes this environment's ``shadowless``) and the EnvironmentFile a
file that exists (a copy of the shipped one). The ``shadowless`` user and the ``video`` and
``render`` groups need not exist: verify does not resolve User=/Group=/SupplementaryGroups=
(they are looked up when the service starts), so nothing about them is tolerated either.
"""
from __future__ import annotations

import configparser
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"
UNITS = {"shadowless-node.service": "node.env", "shadowless-coordinator.service": "coordinator.env"}
INSTALLED_EXE = "/opt/shadowless/venv/bin/shadowless"
ANALYZE = shutil.which("systemd-analyze")

pytestmark = pytest.mark.skipif(ANALYZE is None, reason="systemd-analyze is not installed (Debian: systemd)")


def executable() -> str:
    """An existing executable to stand in for /opt/shadowless/venv/bin/shadowless."""
    script = Path(sys.executable).with_name("shadowless")
    return str(script) if os.access(script, os.X_OK) else sys.executable


def stage(tmp: Path, *, dropin: str | None = None, enable: bool = False, edit=None) -> list[Path]:
    """Copies of the units in ``tmp`` as verify can check them: ExecStart's program replaced by
    an existing one, EnvironmentFile= by a copy. ``dropin``: the x11 drop-in's text, installed as
    ``shadowless-node.service.d/x11.conf``. ``enable``: the ``TARGET.wants/`` links that
    ``systemctl enable`` makes from [Install] WantedBy=. ``edit``: (name, text) -> text."""
    paths = []
    for name, envfile in UNITS.items():
        env_copy = tmp / envfile
        shutil.copy(DEPLOY / envfile, env_copy)
        text = (DEPLOY / name).read_text()
        assert INSTALLED_EXE in text and f"/etc/shadowless/{envfile}" in text
        text = text.replace(INSTALLED_EXE, executable()).replace(f"/etc/shadowless/{envfile}", str(env_copy))
        if edit:
            text = edit(name, text)
        path = tmp / name
        path.write_text(text)
        paths.append(path)
        if enable:
            cp = configparser.ConfigParser(strict=False, interpolation=None)
            cp.read_string(text)
            for target in cp["Install"]["WantedBy"].split():
                wants = tmp / f"{target}.wants"
                wants.mkdir(exist_ok=True)
                (wants / name).symlink_to(path)
    if dropin is not None:
        d = tmp / "shadowless-node.service.d"
        d.mkdir()
        (d / "x11.conf").write_text(dropin)
    return paths


def verify(*units: str | Path) -> tuple[int, list[str]]:
    """verify's exit status and every line it printed (stdout and stderr)."""
    r = subprocess.run([ANALYZE, "verify", "--man=no", *map(str, units)],
                       capture_output=True, text=True, timeout=120, check=False)
    return r.returncode, [line for line in (r.stdout + r.stderr).splitlines() if line.strip()]


def test_the_units_and_the_x11_dropin_verify_without_a_word(tmp_path):
    units = stage(tmp_path, dropin=(DEPLOY / "shadowless-node-x11.conf").read_text())
    rc, lines = verify(*units)
    assert (rc, lines) == (0, []), "\n".join(lines)


def test_a_mistake_in_a_unit_is_reported(tmp_path):
    """The control: verify does speak up about what it ignores (yet exits 0), so silence above
    means every line was understood."""
    def typo(name, text):
        return text.replace("Type=notify", "Type=notfy").replace("WatchdogSec=10s", "WatchdogSec=ten")

    units = stage(tmp_path, edit=typo, dropin="[Service]\nEnviroment=DISPLAY=:0\n")
    _, lines = verify(*units)
    said = "\n".join(lines)
    assert "notfy" in said and "ten" in said and "Enviroment" in said, said


def test_enabled_at_boot_with_the_x11_dropin_there_is_no_ordering_cycle(tmp_path):
    """Both units enabled (their WantedBy= links) and the node's x11 drop-in installed: starting
    graphical.target, which is what booting a desktop does, orders every job without a cycle."""
    units = stage(tmp_path, dropin=(DEPLOY / "shadowless-node-x11.conf").read_text(), enable=True)
    rc, lines = verify(*units, "graphical.target")
    assert (rc, lines) == (0, []), "\n".join(lines)


def test_after_graphical_target_in_the_dropin_would_be_a_cycle(tmp_path):
    """Why the drop-in orders the node after the display manager and not after graphical.target:
    the node is wanted by multi-user.target (so multi-user.target waits for it), graphical.target
    comes after multi-user.target, and systemd would break the cycle by dropping the node's start
    job. Also the control that the test above can see a cycle."""
    dropin = (DEPLOY / "shadowless-node-x11.conf").read_text()
    assert re.search(r"^After=display-manager\.service$", dropin, re.MULTILINE)
    units = stage(tmp_path, enable=True,
                  dropin=dropin.replace("After=display-manager.service", "After=graphical.target"))
    _, lines = verify(*units, "graphical.target")
    assert any("ordering cycle" in line and "shadowless-node.service" in line for line in lines), "\n".join(lines)
