"""A show controller fires a cue by number: /shadowless/jump with an OSC int (a desk, QLab) or a whole
float (TouchDesigner's default) fires the cue whose id is that number, as a string does; a fraction is
refused with one /shadowless/error line. A real coordinator in this process, python-osc's messages over
UDP on 127.0.0.1."""
from __future__ import annotations

import asyncio
import socket

from pythonosc.osc_message_builder import OscMessageBuilder
from pythonosc.osc_packet import OscPacket

from coordinator.rig import Rig, grid_slots, init_rig
from protos.cues import Cue, CueList
from waits import wait_until_async
from inprocess_coordinator import inprocess_coordinator

TOKEN = b"n" * 32


def _datagram(address: str, arg=None, type_=None) -> bytes:
    b = OscMessageBuilder(address=address)
    if arg is not None:
        b.add_arg(arg, type_)
    return b.build().dgram


def test_jump_takes_a_cue_number_as_an_int_or_a_whole_float(tmp_path):
    rig_dir = init_rig(tmp_path / "rig", name="oscnum", slots=grid_slots(1, 1), width=32, height=32,
                       content_width=32, content_height=32)
    with open(rig_dir / "rig.toml", "a") as f:
        f.write('\n[osc]\nlisten = "127.0.0.1:0"\n')

    async def go():
        async with inprocess_coordinator(Rig(rig_dir), TOKEN) as app:
            coord, osc = app.coordinator, app.osc
            coord.set_cues(CueList(tuple(Cue(id=str(k), name=f"dark {k}", kind="blackout") for k in (1, 2, 3))))
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.bind(("127.0.0.1", 0))
            sock.setblocking(False)
            heard: dict[str, list] = {}

            def listen() -> dict[str, list]:
                try:
                    while True:
                        for m in OscPacket(sock.recv(65536)).messages:
                            heard[m.message.address] = list(m.message.params)
                except BlockingIOError:
                    return heard

            def current_cue() -> str:
                sock.sendto(_datagram("/shadowless/status"), ("127.0.0.1", osc.port))
                return (listen().get("/shadowless/cue/current") or [""])[0]

            try:
                for arg, type_, cue in ((3, "i", "3"), (1.0, "f", "1"), ("2", "s", "2")):
                    sock.sendto(_datagram("/shadowless/jump", arg, type_), ("127.0.0.1", osc.port))
                    await wait_until_async(current_cue, lambda c, cue=cue: c == cue,
                                           what=f"cue {cue} current after /shadowless/jump {arg!r} ({type_})")
                assert "/shadowless/error" not in heard, heard["/shadowless/error"]

                sock.sendto(_datagram("/shadowless/jump", 1.5, "f"), ("127.0.0.1", osc.port))
                error = await wait_until_async(listen, lambda h: "/shadowless/error" in h,
                                               what="the refusal of cue 1.5")
                address, reason = error["/shadowless/error"]
                assert address == "/shadowless/jump" and "whole number" in reason and "1.5" in reason, reason
                assert current_cue() == "2"
            finally:
                sock.close()

    asyncio.run(go())
