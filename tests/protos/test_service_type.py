"""SHADOWLESS_MDNS_SERVICE gives a rig an mDNS service of its own: its coordinator is found by the
programs that share the value and by no other; a value that is no service name stops a program at
once with one line."""
from __future__ import annotations

import asyncio
import importlib
import os
import subprocess
import sys

import pytest
from waits import wait_until
from zeroconf import BadTypeInNameException, service_type_name

import protos.version
from protos.discovery import Discovery
from shadowless.local import LocalRig

NAMES = ["_a", "_1", "_a1", "_-a", "_a-", "_a--b", "_a-b", "_" + "a" * 15, "_" + "a" * 16, "_abc_d", "_ABC",
         "_shadowless-gw0", "a", "__a"]


@pytest.fixture
def reload_version(monkeypatch):
    """Re-read protos.version under a patched environment; restored to this process's own after."""
    yield lambda: importlib.reload(protos.version)
    monkeypatch.undo()
    importlib.reload(protos.version)


@pytest.mark.parametrize("name", NAMES)
def test_accepted_names_are_what_zeroconf_accepts(name, monkeypatch, reload_version):
    try:  # the independent reference: zeroconf's own check of a service type
        service_type_name(f"{name}._tcp.local.")
        valid = True
    except BadTypeInNameException:
        valid = False
    monkeypatch.setenv("SHADOWLESS_MDNS_SERVICE", name)
    if valid:
        assert reload_version().SERVICE_TYPE == f"{name}._tcp.local."
    else:
        with pytest.raises(SystemExit, match="is not an mDNS service name"):
            reload_version()


def test_an_empty_value_is_the_default(monkeypatch, reload_version):
    monkeypatch.setenv("SHADOWLESS_MDNS_SERVICE", "")
    assert reload_version().SERVICE_TYPE == "_shadowless._tcp.local."


def test_a_wrong_value_is_one_line_before_anything_runs():
    env = {**os.environ, "SHADOWLESS_MDNS_SERVICE": "shadowless"}
    r = subprocess.run([sys.executable, "-m", "shadowless", "status", "--mdns-interface", "127.0.0.1"],
                       capture_output=True, text=True, timeout=60, env=env)
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.strip() == ("SHADOWLESS_MDNS_SERVICE='shadowless' is not an mDNS service name: '_' and then 1 "
                                "to 15 letters, digits or single hyphens, starting and ending with a letter or "
                                "digit (e.g. _shadowless-b)")


def test_a_rig_on_its_own_service_is_found_only_by_its_own(tmp_path):
    own = f"_sl-own-{os.getpid() % 10**6}"
    assert own + "._tcp.local." != protos.version.SERVICE_TYPE
    rig = LocalRig(["r0c0"], tmp_path, output_size=(32, 32), content_size=(32, 32),
                   env={"SHADOWLESS_MDNS_SERVICE": own}).create()
    try:
        rig.start_coordinator()
        rig.wait_ready()
        line = f"advertising {rig.rig_name}.{own}._tcp.local."
        wait_until(lambda: rig.log("coordinator"), lambda log: line in log, what=f"the coordinator's log line {line!r}")

        async def browse() -> list:  # this process browses its own service
            disc = Discovery(interfaces=["127.0.0.1"])
            await disc.start()
            try:
                return await disc.find(rig=rig.rig_name, timeout=3)
            finally:
                await disc.close()

        assert asyncio.run(browse()) == []

        def status(service: str | None) -> subprocess.CompletedProcess:
            env = {k: v for k, v in os.environ.items() if k != "SHADOWLESS_MDNS_SERVICE"}
            env.update({"SHADOWLESS_MDNS_SERVICE": service} if service else {})
            return subprocess.run([sys.executable, "-m", "shadowless", "status", "--json", "--rig-dir", str(rig.rig_dir),
                                   "--mdns-interface", "127.0.0.1"], capture_output=True, text=True, timeout=60, env=env)

        found = status(own)
        assert found.returncode == 0 and '"nodes"' in found.stdout, found.stderr
        lost = status("_sl-another")
        assert lost.returncode != 0 and f"no coordinator of rig '{rig.rig_name}'" in lost.stderr, lost.stderr
    finally:
        rig.close()
