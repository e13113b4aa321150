"""rig.toml's ``[osc]``: where show control listens, whom it hears, where it reports, how it chases.

::

    [osc]
    listen = "127.0.0.1:9000"              # HOST:PORT (UDP); off when [osc] or listen is missing
    allow = ["127.0.0.1", "10.0.0.0/24"]   # sender addresses or networks; default: this machine only
    feedback = ["10.0.0.20:9001"]          # where the status stream goes on every change (default: none)
    timecode_fps = 25                      # frames per second of "hh:mm:ss:ff" timecode
    timecode_offset_s = 0.0                # the timecode at the show's first frame
    chase_threshold_ms = 100               # the show seeks when the external clock is further off than this
    mtc_port = "MIDI Interface"            # chase MIDI timecode from this MIDI input (a name or part of
                                           # one; the `midi` extra; `coordinator --rig DIR --mtc-port list`)

OSC has no authentication: whoever can send a datagram from an allowed address drives the show,
so ``allow`` names the show controllers and nothing more, and the port should sit on the show
network only. ``mtc_port`` alone (no ``listen``) reads MIDI timecode without listening for OSC.
Every refusal is one :class:`~coordinator.errors.RigError` line naming rig.toml.
"""
from __future__ import annotations

import ipaddress
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from coordinator.errors import RigError
from coordinator.schema import parse_toml, read_text

#: senders heard when rig.toml gives no ``allow``: this machine only
DEFAULT_ALLOW = ("127.0.0.1/32", "::1/128")
KEYS = ("listen", "allow", "feedback", "timecode_fps", "timecode_offset_s", "chase_threshold_ms", "mtc_port")
Network = ipaddress.IPv4Network | ipaddress.IPv6Network


@dataclass(frozen=True)
class OscConfig:
    """Show control's settings (the module docstring); ``listen`` and ``mtc_port`` None: off."""

    listen: tuple[str, int] | None = None
    allow: tuple[Network, ...] = tuple(ipaddress.ip_network(n) for n in DEFAULT_ALLOW)
    feedback: tuple[tuple[str, int], ...] = ()
    timecode_fps: float = 25.0
    timecode_offset_s: float = 0.0
    chase_threshold_ms: float = 100.0
    mtc_port: str | None = None

    @property
    def on(self) -> bool:
        """Whether show control runs: OSC listens, or MIDI timecode is read, or both."""
        return self.listen is not None or self.mtc_port is not None

    def allows(self, address: str) -> bool:
        """Whether a datagram from ``address`` (an IP address; IPv4-mapped IPv6 counts as IPv4) is heard."""
        try:
            ip = ipaddress.ip_address(address.split("%")[0])
        except ValueError:
            return False
        if ip.version == 6 and ip.ipv4_mapped is not None:
            ip = ip.ipv4_mapped
        return any(ip.version == n.version and ip in n for n in self.allow)


def parse_host_port(text: object, what: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[v6]:PORT``) -> (host, port); ValueError naming ``what`` and the form."""
    host, sep, port = str(text).strip().rpartition(":")
    host = host.strip("[]")
    if not isinstance(text, str) or not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"{what} must be \"HOST:PORT\", e.g. \"127.0.0.1:9000\", got {text!r}")
    return host, int(port)


def _number(doc: dict, key: str, default: float, lo: float, hi: float) -> float:
    v = doc.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        raise ValueError(f"{key} must be a number {lo:g}..{hi:g}, got {v!r}")
    return float(v)


def parse_osc(doc: Any) -> OscConfig:
    """The ``[osc]`` table (a dict, or None when rig.toml has none) as an OscConfig; ValueError in one line."""
    if doc is None:
        return OscConfig()
    if not isinstance(doc, dict):
        raise ValueError("[osc] must be a table")
    unknown = sorted(set(doc) - set(KEYS))
    if unknown:
        raise ValueError(f"unknown key{'s' if len(unknown) > 1 else ''} {', '.join(unknown)} (the keys are "
                         f"{', '.join(KEYS)})")
    listen = parse_host_port(doc["listen"], "listen") if "listen" in doc else None
    allow_doc = doc.get("allow", list(DEFAULT_ALLOW))
    if not isinstance(allow_doc, list) or not allow_doc:
        raise ValueError("allow must be a list of addresses or networks, e.g. [\"127.0.0.1\", \"10.0.0.0/24\"]")
    allow = []
    for a in allow_doc:
        try:
            allow.append(ipaddress.ip_network(str(a).strip(), strict=False))
        except ValueError:
            raise ValueError(f"allow: {a!r} is no address or network (e.g. \"10.0.0.5\" or \"10.0.0.0/24\")") from None
    feedback_doc = doc.get("feedback", [])
    if isinstance(feedback_doc, str):
        feedback_doc = [feedback_doc]
    if not isinstance(feedback_doc, list):
        raise ValueError("feedback must be a list of \"HOST:PORT\"")
    feedback = tuple(parse_host_port(f, "each feedback target") for f in feedback_doc)
    if any(port == 0 for _, port in feedback):
        raise ValueError("a feedback target needs a port other than 0")
    mtc = doc.get("mtc_port")
    if mtc is not None and (not isinstance(mtc, str) or not mtc.strip() or len(mtc) > 200):
        raise ValueError(f"mtc_port must be a MIDI input port's name (or part of it), got {mtc!r}")
    return OscConfig(listen=listen, allow=tuple(allow), feedback=feedback, mtc_port=mtc.strip() if mtc else None,
                     timecode_fps=_number(doc, "timecode_fps", 25.0, 1.0, 1000.0),
                     timecode_offset_s=_number(doc, "timecode_offset_s", 0.0, -86400.0, 86400.0),
                     chase_threshold_ms=_number(doc, "chase_threshold_ms", 100.0, 1.0, 60000.0))


def load_osc(rig_dir: str | Path) -> OscConfig:
    """The ``[osc]`` of ``rig_dir/rig.toml``; RigError naming the file and the key in one line."""
    path = Path(rig_dir) / "rig.toml"
    try:
        return parse_osc(parse_toml(read_text(path), str(path)).get("osc"))
    except ValueError as exc:
        raise RigError(f"{path}: [osc] {exc}") from None
