"""The grammar of a node's ``--output`` spec, checked without opening anything.

Kept apart from :mod:`node.outputs` (which brings GL and windowing) so that the node's command
line refuses a malformed spec at once, in one line, in the process that never renders.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["SPEC_FORMS", "OutputSpec", "parse_output_spec", "parse_room_address"]

#: the accepted forms, for error messages and ``--help``
SPEC_FORMS = ("offscreen", "window", "window:MONITOR (0-based monitor index)", "kms",
              "kms:DISPLAY (0-based index or connector, e.g. kms:HDMI-A-1)", "room://HOST:PORT")


@dataclass(frozen=True)
class OutputSpec:
    """A parsed spec: ``kind`` is offscreen, window, kms or room; ``monitor`` (window), ``display``
    (kms: "" for the first) and ``address`` (room: HOST:PORT) as given."""
    kind: str
    monitor: int = 0
    display: str = ""
    address: str = ""


def parse_room_address(spec: str) -> str:
    """``room://HOST:PORT`` (or ``HOST:PORT``) -> ``HOST:PORT``; ValueError if malformed."""
    text = spec.strip()
    address = text[len("room://"):] if text.startswith("room://") else text
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"output {spec!r}: expected room://HOST:PORT, e.g. room://127.0.0.1:50070")
    return address


def parse_output_spec(spec: str) -> OutputSpec:
    """The spec's parts; ValueError naming the accepted forms if it is not one of them."""
    if not isinstance(spec, str):
        raise ValueError(f"output spec must be a string, got {type(spec).__name__}")
    text = spec.strip()
    forms = ", ".join(SPEC_FORMS)
    if text in ("", "offscreen"):
        return OutputSpec("offscreen")
    if text == "window" or text.startswith("window:"):
        index_text = text.partition(":")[2] if ":" in text else "0"
        if not index_text.isdigit():
            raise ValueError(f"output {spec!r}: the monitor must be a 0-based index like window:1 (accepted: {forms})")
        return OutputSpec("window", monitor=int(index_text))
    if text == "kms" or text.startswith("kms:"):
        if text.endswith(":"):
            raise ValueError(f"output {spec!r}: name the display after kms:, an index or a connector like "
                             f"kms:HDMI-A-1 (accepted: {forms})")
        return OutputSpec("kms", display=text.partition(":")[2])
    if text.startswith("room://"):
        return OutputSpec("room", address=parse_room_address(text))
    raise ValueError(f"unknown output {spec!r}; accepted: {forms}")
