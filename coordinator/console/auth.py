"""Who may use the console: login with the rig token, sessions, CSRF and a login rate limit.

The operator pastes the rig's token into the login form; it is compared in constant time
(:func:`hmac.compare_digest`) with the coordinator's. A login opens a session: a random id in
an HttpOnly, SameSite=Strict cookie (Secure when the console serves TLS) and a random CSRF
token the page keeps in memory and sends in the ``X-CSRF-Token`` header of every POST. A
session ends after :data:`IDLE_S` without a request, or on logout.

Failed logins are counted per client address: after :data:`MAX_FAILURES` within
:data:`WINDOW_S`, every login from that address is answered 429 with ``Retry-After`` until
the oldest failure leaves the window (a correct token then too: a guesser learns nothing).
"""
from __future__ import annotations

import hmac
import math
import secrets
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable

#: the session cookie's name
COOKIE = "shadowless_console"
#: the header every POST carries the session's CSRF token in
CSRF_HEADER = "X-CSRF-Token"
#: a session unused this long (seconds) is closed
IDLE_S = 30 * 60.0
#: failed logins allowed per client address within WINDOW_S seconds
MAX_FAILURES = 5
WINDOW_S = 60.0
#: sessions kept at once (the least recently used is closed first)
MAX_SESSIONS = 64
#: client addresses whose failures are remembered (the stalest are forgotten first)
MAX_ADDRESSES = 4096


def token_matches(given: str, token: bytes) -> bool:
    """Whether the pasted ``given`` text is the rig token (surrounding whitespace ignored;
    constant time in the token's content)."""
    return hmac.compare_digest(given.strip().encode("utf-8", "surrogateescape"), token.strip())


@dataclass
class Session:
    """One logged-in browser."""

    sid: str
    csrf: str
    address: str
    created: float
    last_used: float

    @property
    def who(self) -> str:
        """How the action log names this session: a prefix of its id (never the whole id)."""
        return self.sid[:8]


@dataclass
class Sessions:
    """The open sessions, with idle expiry. ``clock`` is monotonic seconds (injectable)."""

    idle_s: float = IDLE_S
    clock: Callable[[], float] = time.monotonic
    _by_id: dict[str, Session] = field(default_factory=dict)

    def open(self, address: str) -> Session:
        self.expire()
        while len(self._by_id) >= MAX_SESSIONS:
            oldest = min(self._by_id.values(), key=lambda s: s.last_used)
            del self._by_id[oldest.sid]
        now = self.clock()
        s = Session(sid=secrets.token_urlsafe(32), csrf=secrets.token_urlsafe(32), address=address, created=now,
                    last_used=now)
        self._by_id[s.sid] = s
        return s

    def get(self, sid: str | None, *, touch: bool = True) -> Session | None:
        """The live session with id ``sid`` (its idle clock restarted with ``touch``), else None."""
        if not sid:
            return None
        s = self._by_id.get(sid)
        if s is None:
            return None
        now = self.clock()
        if now - s.last_used > self.idle_s:
            del self._by_id[sid]
            return None
        if touch:
            s.last_used = now
        return s

    def close(self, sid: str) -> None:
        self._by_id.pop(sid, None)

    def expire(self) -> None:
        now = self.clock()
        for sid in [sid for sid, s in self._by_id.items() if now - s.last_used > self.idle_s]:
            del self._by_id[sid]

    def __len__(self) -> int:
        return len(self._by_id)


def csrf_ok(session: Session, header: str | None) -> bool:
    return bool(header) and hmac.compare_digest(header.encode(), session.csrf.encode())


@dataclass
class LoginLimiter:
    """Failed logins per client address in a sliding window."""

    max_failures: int = MAX_FAILURES
    window_s: float = WINDOW_S
    clock: Callable[[], float] = time.monotonic
    _failures: dict[str, deque] = field(default_factory=dict)

    def _recent(self, address: str) -> deque:
        q = self._failures.get(address)
        if q is None:
            return deque()
        now = self.clock()
        while q and now - q[0] >= self.window_s:
            q.popleft()
        if not q:
            del self._failures[address]
        return q

    def retry_after(self, address: str) -> int:
        """Seconds until ``address`` may try again (0: now)."""
        q = self._recent(address)
        if len(q) < self.max_failures:
            return 0
        return max(1, math.ceil(q[0] + self.window_s - self.clock()))

    def failed(self, address: str) -> None:
        q = self._failures.pop(address, None)
        if q is None:
            q = deque()
            if len(self._failures) >= MAX_ADDRESSES:
                del self._failures[next(iter(self._failures))]
        q.append(self.clock())
        self._failures[address] = q     # re-inserted last: the dict stays in order of last failure
