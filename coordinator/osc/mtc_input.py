"""A MIDI port's timecode, read through mido (python-rtmidi backend): the optional ``midi`` extra.

``pip install 'shadowless[midi]'`` brings mido and python-rtmidi; without them every use refuses in
one line naming the extra (:class:`MidiUnavailable`), and nothing else of the coordinator needs
them (the node's install never does). The port is chosen by name: the exact name
:func:`port_names` lists, or a part of it that names one port only (ALSA's names carry client
numbers that change between boots: ``"MIDI Interface"`` finds ``"MIDI Interface:MIDI Interface
MIDI 1 20:0"``).

rtmidi calls back in its own thread for every message; :meth:`MtcInput.feed` dates its bytes
there (the rig clock, when they arrived), decodes them (:class:`coordinator.osc.mtc.MtcDecoder`)
and hands the readings to ``on_readings(port name, readings)`` in that thread (the service passes
them to its event loop).
"""
from __future__ import annotations

import logging
import os
import sys
from typing import Any, Callable

from coordinator.errors import CoordinatorError
from coordinator.osc.mtc import MtcDecoder, Reading

log = logging.getLogger(__name__)

EXTRA = "midi"


class MidiUnavailable(CoordinatorError):
    """No MIDI library (or no MIDI system) here: one line saying what to install or why."""


def _mido() -> Any:
    try:
        import mido
    except ImportError:
        raise MidiUnavailable(f"MIDI timecode needs mido and python-rtmidi: pip install 'shadowless[{EXTRA}]' "
                              "on the coordinator") from None
    try:
        mido.set_backend("mido.backends.rtmidi", load=True)
    except ImportError:
        raise MidiUnavailable(f"MIDI timecode needs python-rtmidi beside mido: pip install 'shadowless[{EXTRA}]' "
                              "on the coordinator") from None
    return mido


#: the ALSA sequencer's device: rtmidi's Linux backend needs it (without, ALSA prints its own error first)
ALSA_SEQ = "/dev/snd/seq"


def port_names() -> list[str]:
    """The MIDI input ports of this machine; MidiUnavailable without the library or a MIDI system."""
    mido = _mido()
    if sys.platform.startswith("linux") and not os.path.exists(ALSA_SEQ):
        raise MidiUnavailable(f"no MIDI system here: {ALSA_SEQ} is missing (the ALSA sequencer: load the snd-seq "
                              "module; a container needs the device passed in)")
    try:
        return list(dict.fromkeys(mido.get_input_names()))
    except Exception as exc:  # noqa: BLE001 - rtmidi's SystemError when there is no ALSA sequencer, ...
        raise MidiUnavailable(f"no MIDI system to read ports from here ({' '.join(str(exc).split())}); "
                              "on Linux the ALSA sequencer (/dev/snd/seq, module snd-seq) must be there") from None


def choose_port(wanted: str, names: list[str]) -> str:
    """The port ``wanted`` names: exactly, else the one port whose name holds it (case aside);
    CoordinatorError naming the ports otherwise."""
    if wanted in names:
        return wanted
    hits = [n for n in names if wanted.lower() in n.lower()]
    if len(hits) == 1:
        return hits[0]
    have = "; ".join(names) if names else "none"
    if hits:
        raise CoordinatorError(f"MIDI port {wanted!r} matches {len(hits)} ports ({'; '.join(hits)}): "
                               "give more of its name")
    raise CoordinatorError(f"no MIDI input port {wanted!r} (ports here: {have}; `shadowless coordinator --rig DIR "
                           "--mtc-port list` lists them)")


class MtcInput:
    """The MIDI input ``port`` (a name or part of one), decoded into MTC readings for
    ``on_readings`` (called in rtmidi's thread). ``clock_ns``: the rig clock."""

    def __init__(self, port: str, on_readings: Callable[[str, list[Reading]], None], clock_ns: Callable[[], int]):
        self.wanted, self.on_readings, self.clock_ns = port, on_readings, clock_ns
        self.name = port            # the port's full name once open
        self.decoder = MtcDecoder()
        self.messages = 0
        self._port: Any = None

    def open(self) -> None:
        mido = _mido()
        self.name = choose_port(self.wanted, port_names())
        try:
            self._port = mido.open_input(self.name, callback=lambda message: self.feed(message.bytes()))
        except Exception as exc:  # noqa: BLE001 - rtmidi's errors: the port went away, is busy, ...
            raise CoordinatorError(f"cannot open MIDI port {self.name!r}: {' '.join(str(exc).split())}") from None
        log.info("reading MIDI timecode from %r", self.name)

    def close(self) -> None:
        if self._port is not None:
            self._port.close()
            self._port = None

    def feed(self, data: bytes | list[int]) -> None:
        """Bytes of the port, just arrived (called in one thread at a time: rtmidi's)."""
        at = self.clock_ns()
        self.messages += 1
        try:
            readings = self.decoder.feed(data, at)
            if readings:
                self.on_readings(self.name, readings)
        except Exception:  # noqa: BLE001 - rtmidi's thread must live on; the log says what broke
            log.exception("MTC: a message from %r could not be handled", self.name)
