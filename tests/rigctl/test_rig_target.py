"""Operator commands talk to the rig named by --rig-dir (its id and token) and nothing else,
with a twin (same name and id, another token) and another rig advertising beside it."""
from __future__ import annotations

import shutil

import pytest

from coordinator.rig import parse_config
from protos import auth
from shadowless.local import LocalRig
from procs import shadowless_process

SIZE = (32, 18)


def _rig(path, **kw) -> LocalRig:
    return LocalRig(["r0c0"], path, output_size=SIZE, content_size=SIZE, mdns=True, **kw)


@pytest.fixture(scope="module")
def rigs(tmp_path_factory):
    base = tmp_path_factory.mktemp("rigs")
    real = _rig(base / "real").create()
    twin = _rig(base / "twin")
    twin.rig_dir.mkdir(parents=True)
    shutil.copy(real.rig_dir / "rig.toml", twin.rig_dir / "rig.toml")
    (twin.rig_dir / "token").write_text(auth.new_token() + "\n")
    (twin.rig_dir / "token").chmod(0o600)
    twin.create()
    other = _rig(base / "other").create()
    idle = _rig(base / "idle").create()          # a rig directory whose coordinator is not running
    started = []
    try:
        for r in (twin, other, real):
            r.start_coordinator()
            started.append(r)
        for r in started:
            r.wait_ready()
        yield {"real": real, "twin": twin, "other": other, "idle": idle}
    finally:
        for r in started:
            r.close()



def rig_id(rig: LocalRig) -> str:
    return parse_config((rig.rig_dir / "rig.toml").read_text()).rig_id


@pytest.mark.allow_leaks
def test_the_rig_dir_picks_its_own_coordinator_among_a_twin_and_another_rig(rigs):
    real, twin = rigs["real"], rigs["twin"]
    for _ in range(3):                                   # the twin must never win, whatever answers first
        r = shadowless_process("status", "--rig-dir", str(real.rig_dir), "--mdns-interface", "127.0.0.1", "--json")
        assert r.returncode == 0, r.stderr
        assert rig_id(real) in r.stdout and f'"{real.port}"' not in r.stderr
    # the twin's own directory reaches the twin, not the real rig (same id, its own token)
    r = shadowless_process("status", "--rig-dir", str(twin.rig_dir), "--mdns-interface", "127.0.0.1")
    assert r.returncode == 0, r.stderr


@pytest.mark.allow_leaks
def test_a_token_file_and_rig_name_without_a_directory_still_pass_over_the_twin(rigs):
    real = rigs["real"]
    r = shadowless_process("status", "--token-file", str(real.rig_dir / "token"), "--rig", real.rig_name,
                   "--mdns-interface", "127.0.0.1")
    assert r.returncode == 0, r.stderr


@pytest.mark.allow_leaks
def test_a_coordinator_of_another_rig_is_refused_by_name_not_blamed_on_the_token(rigs):
    real, other = rigs["real"], rigs["other"]
    r = shadowless_process("status", "--rig-dir", str(real.rig_dir), "--coordinator", other.target)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    line = r.stderr.strip()
    assert line.count("\n") == 0, line
    assert other.rig_name in line and rig_id(other) in line and rig_id(real) in line and "another rig" in line


@pytest.mark.allow_leaks
def test_the_twin_at_an_explicit_address_is_told_apart_by_its_proof(rigs):
    real, twin = rigs["real"], rigs["twin"]
    r = shadowless_process("status", "--rig-dir", str(real.rig_dir), "--coordinator", twin.target)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "could not prove it knows the token in" in r.stderr and str(real.rig_dir / "token") in r.stderr


@pytest.mark.allow_leaks
def test_a_rig_not_running_names_what_is_advertised_instead(rigs):
    idle, real = rigs["idle"], rigs["real"]
    r = shadowless_process("status", "--rig-dir", str(idle.rig_dir), "--mdns-interface", "127.0.0.1")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert f"no coordinator of rig {idle.rig_name!r}" in r.stderr
    assert real.rig_name in r.stderr, "the operator sees which rigs are advertised"


@pytest.mark.allow_leaks
def test_contradicting_rig_options_are_refused_before_connecting(rigs):
    real, other = rigs["real"], rigs["other"]
    r = shadowless_process("status", "--rig-dir", str(real.rig_dir), "--rig", other.rig_name)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "is not the rig in" in r.stderr
