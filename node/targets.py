"""Which advertised coordinators a node tries, in which order, and when again.

A rogue or misconfigured advertiser on the venue's network must never keep a node
from its rig. So every advertised coordinator is tried in each pass (one that
refuses or cannot be reached never ends the pass), each has its own backoff, and
the order is: coordinators of the rig this node joined before first (its id is kept
in a small file so that it survives a restart), then the others in random order
(a stable order would let one advertiser always go first).

Pure bookkeeping: no network, no clock of its own (callers pass ``time.monotonic()``).
"""
from __future__ import annotations

import logging
import random
from dataclasses import dataclass, field
from pathlib import Path

from protos.atomic_files import atomic_write_text

log = logging.getLogger("node")

__all__ = ["Candidate", "TargetBook", "read_known_rig", "write_known_rig"]


@dataclass(frozen=True)
class Candidate:
    """One coordinator to try: ``HOST:PORT`` and what its advertisement says (unverified)."""
    target: str
    rig_id: str = ""
    name: str = ""

    def label(self) -> str:
        return f"{self.target} (rig {self.name!r}, id {self.rig_id})" if self.rig_id else self.target


@dataclass
class _State:
    next_try: float = 0.0
    failures: int = 0
    reason: str = ""          # the last refusal or failure, as logged


@dataclass
class TargetBook:
    """Per-target backoff and the preference for the rig joined before.

    ``unreachable_min_s``..``unreachable_max_s``: backoff of a target that did not answer
    (doubling); ``refusal_s``: the wait before asking again a target that refused or
    could not prove the token (it will not change its mind soon).
    """
    known_rig: str = ""
    unreachable_min_s: float = 0.2
    unreachable_max_s: float = 5.0
    refusal_s: float = 10.0
    rng: random.Random = field(default_factory=random.Random)
    _states: dict[str, _State] = field(default_factory=dict)

    def order(self, candidates: list[Candidate], now: float) -> list[Candidate]:
        """The candidates due at ``now``: the known rig's first, each group shuffled."""
        due = [c for c in candidates if self._states.get(c.target, _State()).next_try <= now]
        self.rng.shuffle(due)
        return sorted(due, key=lambda c: not (self.known_rig and c.rig_id == self.known_rig))

    def next_due(self, candidates: list[Candidate], now: float) -> float:
        """Seconds from ``now`` until one of ``candidates`` is due again (0 if one is)."""
        if not candidates:
            return 0.0
        return max(0.0, min(self._states.get(c.target, _State()).next_try for c in candidates) - now)

    def joined(self, candidate: Candidate, rig_id: str) -> bool:
        """``candidate`` proved the token and took this node, as rig ``rig_id`` (verified).
        True if that rig is new to this node."""
        self._states.pop(candidate.target, None)
        new = rig_id != self.known_rig
        self.known_rig = rig_id
        return new

    def refused(self, candidate: Candidate, reason: str, now: float) -> bool:
        """``candidate`` refused this node or could not prove the token. True if this is news
        (first time, or another reason than last time): worth a warning rather than a debug line."""
        st = self._states.setdefault(candidate.target, _State())
        news = st.reason != reason
        st.reason, st.failures, st.next_try = reason, st.failures + 1, now + self.refusal_s
        return news

    def unreachable(self, candidate: Candidate, reason: str, now: float) -> bool:
        """``candidate`` did not answer; backs off exponentially. True if this is news."""
        st = self._states.setdefault(candidate.target, _State())
        news = st.reason != reason
        delay = min(self.unreachable_max_s, self.unreachable_min_s * 2 ** min(st.failures, 16))
        st.reason, st.failures = reason, st.failures + 1
        st.next_try = now + delay * self.rng.uniform(0.8, 1.2)
        return news

    def forget_absent(self, candidates: list[Candidate]) -> None:
        """Drop the state of targets no longer advertised (a coordinator that comes back at the
        same address starts afresh)."""
        present = {c.target for c in candidates}
        for t in [t for t in self._states if t not in present]:
            del self._states[t]


def read_known_rig(path: Path) -> str:
    """The rig id this node joined last (``path``'s one line), "" if none or unreadable."""
    try:
        text = path.read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError):
        return ""
    return text if text.isprintable() and 0 < len(text) <= 128 else ""


def write_known_rig(path: Path, rig_id: str) -> None:
    """Keep ``rig_id`` for the next start (atomically; a failure is logged, never fatal)."""
    try:
        atomic_write_text(path, rig_id + "\n")      # fsynced: a power cut leaves the old id or the new
    except OSError as exc:
        log.warning("cannot keep the joined rig's id in %s: %s", path, exc)
