"""Refused joins and calls, counted per peer address, slot and reason.

A peer that retries a refused join (a node with the wrong token, a second node for a taken
slot) or floods handshakes produces thousands of refusals. They are kept as counters, not as a
list the flood would wash out, and logged at WARNING once per key and then at most once a
minute with the count since, so the log stays readable while ``status`` shows every offender.
"""
from __future__ import annotations

from dataclasses import dataclass

from coordinator.api import RefusedPeer

#: distinct (address, slot, reason) kept; the least recently refused are forgotten first
MAX_KEYS = 256
#: a key that keeps being refused is logged again after this long, with its count
RELOG_S = 60.0
#: characters of a slot name and of a reason kept (a peer chooses the slot it claims: up to the message cap)
MAX_SLOT_CHARS = 40
MAX_REASON_CHARS = 400


def clipped(text: str, limit: int) -> str:
    """``text`` cut to ``limit`` characters, an ellipsis marking the cut."""
    return text if len(text) <= limit else text[: limit - 1] + "…"


def peer_address(peer: str) -> str:
    """The address of a gRPC peer string without its port: ``ipv4:10.0.0.5:51234`` ->
    ``10.0.0.5``, ``ipv6:[::1]:5000`` -> ``::1``; other forms unchanged."""
    kind, _, rest = peer.partition(":")
    if kind == "ipv4":
        return rest.rpartition(":")[0] or rest
    if kind == "ipv6":
        host = rest.rpartition(":")[0] or rest
        return host.strip("[]")
    return peer


@dataclass
class _Entry:
    peer: str          # the full peer string (with its port) of the last refusal, for the log
    count: int
    last: float
    logged_at: float
    logged_count: int


class Refusals:
    """Counts refusals; :meth:`record` says whether this one should be logged."""

    def __init__(self) -> None:
        self._entries: dict[tuple[str, str, str], _Entry] = {}

    def record(self, peer: str, slot: str, reason: str, now: float) -> str | None:
        """Count a refusal at ``now`` (seconds); the line to log, or None to stay quiet. Slot and
        reason are clipped (MAX_SLOT_CHARS, MAX_REASON_CHARS): a peer picks them."""
        slot, reason = clipped(slot, MAX_SLOT_CHARS), clipped(reason, MAX_REASON_CHARS)
        key = (peer_address(peer), slot, reason)
        e = self._entries.pop(key, None)           # re-inserted last: the dict stays in refusal order
        if e is None:
            if len(self._entries) >= MAX_KEYS:
                del self._entries[next(iter(self._entries))]
            self._entries[key] = _Entry(peer, 1, now, now, 1)
            return f"refused {peer} (slot {slot or '-'}): {reason}"
        e.peer, e.count, e.last = peer, e.count + 1, now
        self._entries[key] = e
        if now - e.logged_at < RELOG_S:
            return None
        since, span = e.count - e.logged_count, now - e.logged_at
        e.logged_at, e.logged_count = now, e.count
        return f"refused {peer} (slot {slot or '-'}) {since} more times in {span:.0f} s, {e.count} in all: {reason}"

    def summary(self, now: float, limit: int = 64) -> tuple[RefusedPeer, ...]:
        """The ``limit`` most recently refused keys, newest first."""
        out = []
        for (address, slot, reason), e in reversed(self._entries.items()):
            out.append(RefusedPeer(address, slot, reason, now - e.last, e.count))
            if len(out) == limit:
                break
        return tuple(out)

    def total(self) -> int:
        return sum(e.count for e in self._entries.values())
