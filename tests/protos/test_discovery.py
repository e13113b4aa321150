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
