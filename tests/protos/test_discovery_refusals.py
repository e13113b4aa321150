"""Discovery mistakes an operator can make cost one line that names what is wrong (the service that was
searched, and where), exit status 2, no traceback: a --mdns-interface that is no IPv4 address or no
address of this machine (operator commands and nodes alike), and a rig that nobody advertises on the
service searched. Each row goes to the bad-input corpus table (SHADOWLESS_CORPUS_TABLE)."""
from __future__ import annotations

import os
import subprocess
import sys
import threading

import pytest

from protos import auth

OWN = f"_sl-none-{os.getpid() % 10**6}"

# (name, argv after `python -m shadowless` with {token}, environment additions, what the one line must say)
CASES = [
    ("status: interface not an address", ["status", "--token-file", "{token}", "--mdns-interface", "not-an-ip"], {},
     "--mdns-interface 'not-an-ip' is not an IPv4 address"),
    ("status: interface not on this machine", ["status", "--token-file", "{token}", "--mdns-interface", "192.0.2.1"],
     {"SHADOWLESS_MDNS_SERVICE": OWN}, f"cannot browse {OWN}._tcp.local. over mDNS on 192.0.2.1: "),
    ("status: nobody advertises the service", ["status", "--token-file", "{token}", "--rig", "nosuch",
                                               "--mdns-interface", "127.0.0.1"], {"SHADOWLESS_MDNS_SERVICE": OWN},
     f"no coordinator of rig 'nosuch' found over mDNS: searched {OWN}._tcp.local. on 127.0.0.1 for 3 s"),
    ("node: interface not an address", ["node", "--slot", "r0c0", "--token-file", "{token}", "--mdns-interface",
                                        "10.0.0.300"], {}, "--mdns-interface '10.0.0.300' is not an IPv4 address"),
    ("node: interface not on this machine", ["node", "--slot", "r0c0", "--token-file", "{token}", "--mdns-interface",
                                             "192.0.2.1"], {"SHADOWLESS_MDNS_SERVICE": OWN},
     f"cannot browse {OWN}._tcp.local. over mDNS on 192.0.2.1: "),
]


@pytest.fixture(scope="module")
def token_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("tok") / "token"
    path.write_text(auth.new_token() + "\n")
    path.chmod(0o600)
    return path


@pytest.mark.parametrize("name,argv,env,says", CASES, ids=[c[0] for c in CASES])
def test_a_discovery_mistake_is_one_line(name, argv, env, says, token_file, corpus_table):
    argv = [a.replace("{token}", str(token_file)) for a in argv]
    r = subprocess.run([sys.executable, "-m", "shadowless", *argv], capture_output=True, text=True, timeout=60,
                       env={**os.environ, **env})
    lines = r.stderr.strip().splitlines()
    corpus_table("discovery", " ".join(argv), lines[-1] if lines else "", r.returncode)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert len(lines) == 1 and says in lines[0], r.stderr


def test_a_node_that_finds_nothing_names_the_service_it_searched(token_file, tmp_path):
    # not a refusal (the node keeps looking, a coordinator may be starting): a warning naming what it searched
    env = {**os.environ, "SHADOWLESS_MDNS_SERVICE": OWN}
    proc = subprocess.Popen([sys.executable, "-m", "shadowless", "node", "--slot", "r0c0", "--token-file",
                             str(token_file), "--mdns-interface", "127.0.0.1", "--rig", "nosuch", "--cache-dir",
                             str(tmp_path / "cache")], stderr=subprocess.PIPE, text=True, env=env)
    want = f"no coordinator advertised {OWN}._tcp.local. for rig 'nosuch' on 127.0.0.1 within 3 s; still looking"
    seen = []
    deadline = threading.Timer(60, proc.kill)     # a node that says nothing ends the read at 60 s
    deadline.start()
    try:
        for line in proc.stderr:     # bounded: the node logs a line per look (every few seconds) until stopped
            seen.append(line)
            if want in line or len(seen) > 50:
                break
    finally:
        deadline.cancel()
        deadline.join()
        proc.terminate()
        proc.wait(30)
        proc.stderr.close()
    assert any(want in line for line in seen), "".join(seen)
