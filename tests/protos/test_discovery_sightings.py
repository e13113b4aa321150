"""What a Discovery keeps from the responses it hears, fed as parsed mDNS packets into its own zeroconf
(exactly the path a packet from the network takes, without sending any): every (address, port) an SRV
names, paired with the A and TXT records of the same message; an SRV goodbye ends only its own
sighting; a flood of fake answers is bounded (the least recently seen go first)."""
from __future__ import annotations

import asyncio
import os
import socket

from zeroconf import DNSAddress, DNSIncoming, DNSOutgoing, DNSPointer, DNSService, DNSText
from zeroconf.const import _CLASS_IN, _CLASS_UNIQUE, _FLAGS_AA, _FLAGS_QR_RESPONSE, _TYPE_A, _TYPE_PTR, _TYPE_SRV, _TYPE_TXT

from protos.discovery import MAX_SIGHTINGS, Discovery

SERVICE = f"_sl-feed-{os.getpid() % 10**6}._tcp.local."


def txt(**props: str) -> bytes:
    out = b""
    for k, v in props.items():
        item = f"{k}={v}".encode()
        out += bytes([len(item)]) + item
    return out


def response(instance: str, server: str, ip: str, port: int, rig: str, *, ttl: int = 120) -> DNSIncoming:
    """One responder's answer: PTR, SRV, TXT and A in one message (cache-flush bit on the unique ones)."""
    name = f"{instance}.{SERVICE}"
    out = DNSOutgoing(_FLAGS_QR_RESPONSE | _FLAGS_AA)
    for rec in (DNSPointer(SERVICE, _TYPE_PTR, _CLASS_IN, ttl and 4500, name),
                DNSService(name, _TYPE_SRV, _CLASS_IN | _CLASS_UNIQUE, ttl, 0, 0, port, server),
                DNSText(name, _TYPE_TXT, _CLASS_IN | _CLASS_UNIQUE, ttl and 4500, txt(rig=rig, name=instance, proto="4")),
                DNSAddress(server, _TYPE_A, _CLASS_IN | _CLASS_UNIQUE, ttl, socket.inet_aton(ip))):
        out.add_answer_at_time(rec, 0)
    return DNSIncoming(out.packets()[0])


def test_every_responder_is_kept_a_goodbye_ends_its_own_and_a_flood_is_bounded():
    async def go():
        disc = Discovery(interfaces=["127.0.0.1"], service_type=SERVICE)
        await disc.start()
        feed = disc._azc.zeroconf.record_manager.async_updates_from_response
        try:
            feed(response("table", "real.local.", "127.0.0.2", 7600, "rig-a"))
            feed(response("table", "real.local.", "127.0.0.9", 7601, "rig-a"))   # same name and host, its own message
            feed(response("table", "rogue.local.", "127.0.0.3", 9000, "rig-a"))
            assert sorted((a.target, a.rig_id, a.name) for a in disc.current()) == [
                ("127.0.0.2:7600", "rig-a", "table"), ("127.0.0.3:9000", "rig-a", "table"),
                ("127.0.0.9:7601", "rig-a", "table")]
            assert disc.current(rig="rig-b") == []
            generation = disc.generation
            feed(response("table", "rogue.local.", "127.0.0.3", 9000, "rig-a", ttl=0))   # its goodbye
            assert disc.generation > generation
            assert sorted(a.target for a in disc.current()) == ["127.0.0.2:7600", "127.0.0.9:7601"]
            for i in range(MAX_SIGHTINGS + 44):        # a flood of distinct fake answers
                feed(response(f"fake{i}", f"f{i}.local.", "127.0.0.4", 10000 + i, "rig-a"))
            held = disc.current()
            assert len(held) == MAX_SIGHTINGS
            assert "127.0.0.4:10299" in {a.target for a in held} and "127.0.0.2:7600" not in {a.target for a in held}
            feed(response("table", "real.local.", "127.0.0.2", 7600, "rig-a"))   # it answers again: back
            assert "127.0.0.2:7600" in {a.target for a in disc.current()}
        finally:
            await disc.close()

    asyncio.run(go())
