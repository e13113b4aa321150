"""The coordinator advertises itself over mDNS (bound to 127.0.0.1 here) and withdraws on shutdown."""
from __future__ import annotations

import asyncio

from shadowless.local import LocalRig
from protos.discovery import Discovery
from protos.version import PROTOCOL_VERSION


def test_advertisement_carries_the_rig_and_is_withdrawn_on_shutdown(tmp_path):
    rig = LocalRig(["r0c0"], tmp_path, output_size=(32, 32), content_size=(32, 32)).create()
    rig.start_coordinator()
    rig.wait_ready()

    async def go():
        disc = Discovery(interfaces=["127.0.0.1"])
        await disc.start()
        try:
            ads = await disc.find(rig=rig.rig_name, timeout=10)
            assert len(ads) == 1
            ad = ads[0]
            from coordinator.rig import Rig

            assert ad.rig_id == Rig(rig.rig_dir).config.rig_id
            assert ad.protocol == str(PROTOCOL_VERSION)
            assert (ad.host, ad.port) == ("127.0.0.1", rig.port)
        finally:
            await disc.close()
        rig.stop_coordinator()          # SIGTERM: graceful shutdown unregisters from mDNS
        assert rig.coordinator.returncode == 0
        assert "mDNS unregister failed" not in rig.log("coordinator")
        fresh = Discovery(interfaces=["127.0.0.1"])   # no cache: only what is advertised now
        await fresh.start()
        try:
            assert await fresh.find(rig=rig.rig_name, timeout=3) == []
        finally:
            await fresh.close()

    try:
        asyncio.run(go())
    finally:
        rig.close()


# ---------------------------------------------------------------- two responders, one instance name
import os
import socket

import pytest
from zeroconf import IPVersion, ServiceInfo
from zeroconf.asyncio import AsyncServiceInfo, AsyncZeroconf

from protos.discovery import parse_txt


@pytest.mark.parametrize("props", [
    {"rig": "abc123", "proto": "4", "instance": "x", "name": "table"},
    {"name": "t\u00e4ble", "empty": "", "eq": "a=b=c"},
    {"flag": None, "rig": "r"},
])
def test_txt_parsing_matches_zeroconf(props):
    # the independent reference: zeroconf builds the TXT rdata and parses it back itself
    info = ServiceInfo("_sl-txt._tcp.local.", "x._sl-txt._tcp.local.", port=1, properties=props)
    back = ServiceInfo("_sl-txt._tcp.local.", "x._sl-txt._tcp.local.", port=1, properties=info.text)  # bytes: parsed
    want = {k.lower(): (v or "") for k, v in back.decoded_properties.items()}
    assert parse_txt(info.text) == want


def test_truncated_txt_ends_the_parse():
    assert parse_txt(b"\x05rig=a\x09name=tab") == {"rig": "a"}
    assert parse_txt(b"") == {}


def _service() -> str:
    return f"_sl-dup-{os.getpid() % 10**6}._tcp.local."


async def _responder(service: str, instance: str, port: int, rig: str) -> tuple[AsyncZeroconf, AsyncServiceInfo]:
    """A responder on 127.0.0.1 that claims ``instance`` WITHOUT probing (cooperating_responders): two of
    them advertise one instance name, as a hostile advertiser or an unrenamed twin would."""
    azc = AsyncZeroconf(interfaces=["127.0.0.1"], ip_version=IPVersion.V4Only)
    info = AsyncServiceInfo(service, f"{instance}.{service}", addresses=[socket.inet_aton("127.0.0.1")], port=port,
                            properties={"rig": rig, "name": instance, "proto": "4", "instance": str(port)},
                            server="same-host.local.")
    await azc.async_register_service(info, cooperating_responders=True)
    return azc, info


def test_two_responders_with_one_instance_name_are_both_found_and_leave_one_by_one():
    service = _service()

    async def go():
        a_zc, a_info = await _responder(service, "table", 40001, "rig-a")
        b_zc, b_info = await _responder(service, "table", 40002, "rig-b")
        disc = Discovery(interfaces=["127.0.0.1"], service_type=service)
        await disc.start()
        try:
            loop = asyncio.get_running_loop()
            deadline = loop.time() + 20
            ads = []
            while loop.time() < deadline:   # both answer within a second or two; a name cache keeps one
                ads = await disc.find(rig="table", timeout=5, settle=0.5)
                if len(ads) == 2:
                    break
            assert sorted((a.target, a.rig_id, a.service_name) for a in ads) == [
                ("127.0.0.1:40001", "rig-a", f"table.{service}"), ("127.0.0.1:40002", "rig-b", f"table.{service}")]
            assert [a.target for a in await disc.find(rig="rig-b", timeout=0)] == ["127.0.0.1:40002"]
            await b_zc.async_unregister_service(b_info)        # goodbye from one of them only
            while loop.time() < deadline and len(disc.current()) > 1:
                await disc.wait_change(disc.generation, 1.0)
            assert [a.target for a in disc.current()] == ["127.0.0.1:40001"]
        finally:
            await disc.close()
            for zc in (a_zc, b_zc):
                await zc.async_close()

    asyncio.run(go())


def test_nothing_found_names_the_service_and_where():
    disc = Discovery(interfaces=["127.0.0.1"], service_type="_sl-none._tcp.local.")
    assert disc.nothing_found(3, "table") == ("no coordinator advertised _sl-none._tcp.local. for rig 'table' on "
                                              "127.0.0.1 within 3 s")
    assert Discovery(service_type="_x._tcp.local.").nothing_found(5) == \
        "no coordinator advertised _x._tcp.local. on any interface within 5 s"
