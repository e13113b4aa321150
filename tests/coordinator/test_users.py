"""The rig's users (coordinator/users.py) and `shadowless rig user`: scrypt hashes checked against
hashlib's scrypt run on the stored salt, an atomic 0600 file, one-line refusals that change nothing
stored, and a store that sees another process's change."""
from __future__ import annotations

import base64
import hashlib
import io
import json
import os
import stat
import sys

import pytest

from coordinator import users
from coordinator.rig import init_rig
from coordinator.users import FILE_NAME, Role, UserError, UserStore, check_name, parse_role

PW = "correct horse"


@pytest.fixture(autouse=True)
def cheap_hashes(monkeypatch):
    """Hashes at a low scrypt cost (the parameters travel with each hash, so verifying follows them)."""
    monkeypatch.setattr(users, "SCRYPT_N", 1 << 10)


@pytest.fixture(scope="module")
def rig_dir(tmp_path_factory):
    return init_rig(tmp_path_factory.mktemp("people") / "rig", name="people", slots=["a"], width=32, height=32,
                    content_width=64, content_height=32)


def test_passwords_are_kept_as_scrypt_hashes_and_verified(tmp_path):
    store = UserStore(tmp_path)
    assert store.add("Alice", "operator", PW) == "added alice (operator)"
    store.add("bob", Role.VIEWER, PW)
    raw = (tmp_path / FILE_NAME).read_text()
    assert PW not in raw
    doc = json.loads(raw)["users"]
    # the stored hash is scrypt of the password under the stored salt and parameters (hashlib as the reference)
    kind, n, r, p, salt, digest = doc["alice"]["hash"].split("$")
    assert kind == "scrypt"
    want = hashlib.scrypt(PW.encode(), salt=base64.b64decode(salt), n=int(n), r=int(r), p=int(p),
                          dklen=len(base64.b64decode(digest)))
    assert base64.b64decode(digest) == want
    assert doc["alice"]["hash"] != doc["bob"]["hash"], "each hash has its own salt"
    assert store.verify("ALICE", PW) is Role.OPERATOR, "names are case-insensitive"
    assert store.verify("alice", PW + "!") is None
    assert store.verify("carol", PW) is None
    assert store.verify("bob", PW) is Role.VIEWER
    # written atomically, private like the token
    assert stat.S_IMODE(os.stat(tmp_path / FILE_NAME).st_mode) == 0o600
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_refusals_are_one_line_and_change_nothing(tmp_path):
    store = UserStore(tmp_path)
    store.add("alice", "admin", PW)
    before = (tmp_path / FILE_NAME).read_bytes()
    for call, words in [(lambda: store.add("alice", "viewer", PW), "exists already"),
                        (lambda: store.add("Al ice", "viewer", PW), "must be 1-32"),
                        (lambda: store.add("token", "viewer", PW), "reserved"),
                        (lambda: store.add("dan", "boss", PW), "choose one of viewer, operator, admin"),
                        (lambda: store.add("dan", "viewer", "short"), "8-1024 characters"),
                        (lambda: store.remove("zed"), "no user 'zed'"),
                        (lambda: store.set_role("zed", "admin"), "no user 'zed'")]:
        with pytest.raises(UserError) as e:
            call()
        assert words in str(e.value) and "\n" not in str(e.value)
    assert (tmp_path / FILE_NAME).read_bytes() == before
    assert check_name(" Eve@Venue ") == "eve@venue" and parse_role("Operator") is Role.OPERATOR


def test_a_store_sees_another_writers_change_and_a_damaged_file_lets_nobody_in(tmp_path):
    reader, writer = UserStore(tmp_path), UserStore(tmp_path)
    assert reader.role_of("alice") is None and reader.list() == []
    writer.add("alice", "viewer", PW)
    assert reader.role_of("alice") is Role.VIEWER
    writer.set_role("alice", "operator")
    assert reader.role_of("alice") is Role.OPERATOR
    writer.remove("alice")
    assert reader.role_of("alice") is None and len(reader) == 0
    writer.add("alice", "viewer", PW)
    (tmp_path / FILE_NAME).write_text('{"users": {"alice": {"role": "god", "hash": "x"}}}')
    assert reader.verify("alice", PW) is None
    assert "damaged" in reader.error
    with pytest.raises(UserError, match="damaged"):
        writer.add("bob", "viewer", PW)      # a change never rewrites a file it cannot read


def test_the_command_line_manages_users_offline(rig_dir, monkeypatch, capsys):
    from shadowless.cli import main

    def rig_user(*args, stdin=""):
        monkeypatch.setattr(sys, "stdin", io.StringIO(stdin))      # not a terminal: no password can be typed
        code = main(["rig", "user", *args, "--rig-dir", str(rig_dir)])
        out = capsys.readouterr()
        return code, out.out, out.err

    code, out, err = rig_user("add", "Olga", "--role", "operator", "--password-file", "-", stdin=PW + "\n")
    assert code == 0, err
    assert "added olga (operator)" in out and "no coordinator serves this rig now" in out
    assert UserStore(rig_dir).verify("olga", PW) is Role.OPERATOR
    code, out, err = rig_user("add", "olga", "--password-file", "-", stdin=PW + "\n")
    assert code == 2 and err.count("\n") == 1 and "exists already" in err
    code, out, err = rig_user("add", "vic", "--role", "viewer")
    assert code == 2 and "--password-file" in err and UserStore(rig_dir).role_of("vic") is None
    code, out, err = rig_user("list", "--json")
    assert [u["name"] for u in json.loads(out)] == ["olga"]
