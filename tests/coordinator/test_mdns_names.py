"""A coordinator probes for its mDNS name and renames itself when another responder answers for it
(RFC 6762 §9): a second rig of the same name on the network takes ``NAME-2``, says so in its log, and
both stay discoverable by their rig id (in TXT), nodes and operators alike."""
from __future__ import annotations

import asyncio
import json
import os
import re
import subprocess
import sys

from coordinator.mdns import free_instance_name
from coordinator.rig import parse_config
from protos.discovery import Discovery
from shadowless.local import LocalRig
from waits import wait_until

SERVICE = "_x._tcp.local."


def test_free_instance_name_takes_the_first_free_suffix():
    assert free_instance_name("table", SERVICE, set()) == "table"
    assert free_instance_name("table", SERVICE, {"table._x._tcp.local."}) == "table-2"
    assert free_instance_name("Table", SERVICE, {"table._x._tcp.local.", "table-2._x._tcp.local."}) == "Table-3"
    assert free_instance_name("table", SERVICE, {"table-2._x._tcp.local."}) == "table"


def _advertised(rig: LocalRig, timeout: float = 60.0) -> str:
    def log() -> str:
        assert rig.coordinator.poll() is None, rig.log("coordinator")[-2000:]
        return rig.log("coordinator")

    pattern = r"advertising (\S+) on \S+ port \d+"
    return re.search(pattern, wait_until(log, lambda text: re.search(pattern, text), what="the coordinator advertising",
                                         timeout=timeout)).group(1)


def test_a_second_rig_of_the_same_name_renames_itself_and_both_stay_found(tmp_path):
    own = f"_sl-name-{os.getpid() % 10**6}"
    service = f"{own}._tcp.local."
    name = f"twin-{os.getpid()}"
    rigs = [LocalRig(["r0c0", "r0c1"], tmp_path / k, output_size=(32, 18), content_size=(32, 18), rig_name=name,
                     env={"SHADOWLESS_MDNS_SERVICE": own}).create() for k in ("first", "second")]
    try:
        first, second = rigs
        first.start_coordinator()
        first.wait_ready(60)
        assert _advertised(first) == f"{name}.{service}"
        # the first rig's nodes run: more processes share port 5353, where the unicast answer to
        # zeroconf's own (QU) probe reached the second coordinator only by chance
        for s in first.slots:
            first.start_node(s)

        async def live():
            async with await first.client() as c:
                await first.wait_live(c, timeout=120)

        asyncio.run(live())
        second.start_coordinator()
        second.wait_ready(60)
        assert _advertised(second) == f"{name}-2.{service}"
        assert f"the mDNS name {name}.{service} is already answered for" in second.log("coordinator")
        ids = {parse_config((r.rig_dir / "rig.toml").read_text()).rig_id: r for r in rigs}

        async def browse() -> list:
            disc = Discovery(interfaces=["127.0.0.1"], service_type=service)
            await disc.start()
            try:
                loop = asyncio.get_running_loop()
                deadline = loop.time() + 20
                while True:
                    ads = await disc.find(rig=name, timeout=5, settle=0.5)
                    if len(ads) >= 2 or loop.time() > deadline:
                        return ads
            finally:
                await disc.close()

        ads = asyncio.run(browse())
        assert {(a.rig_id, a.port, a.service_name) for a in ads} == {
            (rid, r.port, f"{name}.{service}" if r is first else f"{name}-2.{service}") for rid, r in ids.items()}
        # an operator finds each rig by its directory (its id), whatever name it advertises under
        env = {**os.environ, "SHADOWLESS_MDNS_SERVICE": own}
        for rid, r in ids.items():
            out = subprocess.run([sys.executable, "-m", "shadowless", "status", "--json", "--rig-dir", str(r.rig_dir),
                                  "--mdns-interface", "127.0.0.1"], capture_output=True, text=True, timeout=60, env=env)
            assert out.returncode == 0, out.stderr
            assert json.loads(out.stdout)["rig"]["id"] == rid
    finally:
        for r in rigs:
            r.close()
