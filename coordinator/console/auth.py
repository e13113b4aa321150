"""Who may use the console: logins by name and password or with the rig token, sessions and
their roles, CSRF and the login limits.

An operator logs in with their name and password (a user of the rig, :mod:`coordinator.users`),
or pastes the rig's token, compared in constant time (:func:`hmac.compare_digest`) with the
coordinator's; a token login is an admin named ``token``. A login opens a session: a random id in
an HttpOnly, SameSite=Strict cookie (Secure when the console serves TLS) and a random CSRF
token the page keeps in memory and sends in the ``X-CSRF-Token`` header of every POST. The
session carries who logged in and their role (:class:`~coordinator.users.Role`); the console
looks the role up again at every request, so a role changed or a user removed from the command
line holds at once. A session ends after :data:`IDLE_S` without a request, or on logout.

Failed logins are limited twice (:class:`LoginLimiter`):

* **per source**: after a failed login, the next one from the same client address (IPv6: the
  same /64, which one host commonly holds), and the next one for the same user name, waits
  (the first failure is free, then 1 s, 2 s, 4 s … up to :data:`BACKOFF_CAP_S`); a login that
  succeeds, or :data:`FORGET_S` without a failure, starts the address again from nothing. An
  operator who mistypes five times waits 8 s, not a minute.
* **globally**: failures from all addresses draw on one budget of :data:`GLOBAL_BUDGET` per
  :data:`GLOBAL_WINDOW_S` (a token bucket). Once it is spent, a login is tried only when the
  bucket holds a whole failure again (one every 2 s), so guessers on many addresses together
  get no more tries than that. The last failure in the bucket is kept for addresses without a
  failure of their own in the last :data:`FORGET_S`: once each address of a guessing pool has
  failed once, they wait for a second one, and a browser from a clean address gets the turn
  they leave (within 2 s of the last clean one).

A browser that has logged in once carries a **device cookie** (:class:`DeviceCookies`: a random
id and its HMAC under a key derived from the rig token, OWASP's "device cookies"). Its logins
are limited by its own failures only, never by the global budget nor by its address: a guesser
cannot forge one, so the right token typed in a browser that logged in before gets in within
its own backoff (0 s when it did not mistype), however many addresses attack. A browser that
never logged in gets the reserved turn (above) unless fresh addresses keep taking it: against
an endless supply of them it competes for one turn every 2 s.

While a limit holds, a login is answered 429 with ``Retry-After`` and "try again in N s"
without looking at the token (a correct one too: a guesser learns nothing).
"""
from __future__ import annotations

import base64
import hashlib
import hmac
import math
import secrets
import time
from dataclasses import dataclass, field
from typing import Callable

from coordinator.address_owner import address_owner

#: the session cookie's name
COOKIE = "shadowless_console"
#: the header every POST carries the session's CSRF token in
CSRF_HEADER = "X-CSRF-Token"
#: a session unused this long (seconds) is closed
IDLE_S = 30 * 60.0
#: failed logins from one address (or browser) that cost no wait; each further one doubles the wait
FREE_FAILURES = 1
#: the wait after the first failure past the free ones (seconds), and the most it grows to
BACKOFF_FIRST_S = 1.0
BACKOFF_CAP_S = 30.0
#: an address (or browser) without a failed login for this long (seconds) starts from nothing again
FORGET_S = 15 * 60.0
#: failed logins from all addresses (browsers without a device cookie) per GLOBAL_WINDOW_S seconds
GLOBAL_BUDGET = 30
GLOBAL_WINDOW_S = 60.0
#: of that budget, the failures a source that failed within FORGET_S cannot draw on (kept for the others)
GLOBAL_RESERVE = 1.0
#: the device cookie's name, and how long a browser keeps it (seconds)
DEVICE_COOKIE = "shadowless_device"
DEVICE_MAX_AGE_S = 180 * 24 * 3600
#: sessions kept at once (the least recently used is closed first)
MAX_SESSIONS = 64
#: client addresses (and browsers) whose failures are remembered (the stalest are forgotten first)
MAX_ADDRESSES = 4096


#: what the device cookies' key is derived from the rig token for (the coordinator's ``token_key``)
DEVICE_KEY_PURPOSE = b"shadowless console device cookie v1"


@dataclass
class Session:
    """One logged-in browser: who logged in (a user's name, or ``token`` for the rig token) and
    the role they hold (``viewer``, ``operator`` or ``admin``), which the action log and the
    console's checks use."""

    sid: str
    csrf: str
    address: str
    created: float
    last_used: float
    who: str = "token"
    role: str = "admin"
    #: when the user's password was set at login (their sessions end when it is set again)
    stamp: str = ""


@dataclass
class Sessions:
    """The open sessions, with idle expiry. ``clock`` is monotonic seconds (injectable)."""

    idle_s: float = IDLE_S
    clock: Callable[[], float] = time.monotonic
    _by_id: dict[str, Session] = field(default_factory=dict)

    def open(self, address: str, *, who: str = "token", role: str = "admin", stamp: str = "") -> Session:
        self.expire()
        while len(self._by_id) >= MAX_SESSIONS:
            oldest = min(self._by_id.values(), key=lambda s: s.last_used)
            del self._by_id[oldest.sid]
        now = self.clock()
        s = Session(sid=secrets.token_urlsafe(32), csrf=secrets.token_urlsafe(32), address=address, created=now,
                    last_used=now, who=who, role=role, stamp=stamp)
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

    def open_sessions(self) -> list[Session]:
        """The live sessions (expired ones closed first)."""
        self.expire()
        return list(self._by_id.values())


def csrf_ok(session: Session, header: str | None) -> bool:
    return bool(header) and hmac.compare_digest(header.encode(), session.csrf.encode())


class DeviceCookies:
    """The device cookie of browsers that logged in: ``<id>.<mac>``, where ``id`` is 16 random
    bytes and ``mac`` their HMAC-SHA256 under a key derived from the rig token (so a new token
    voids every device cookie, and a restarted coordinator still knows them; nothing is stored).
    ``key`` is that key: the coordinator's ``token_key(DEVICE_KEY_PURPOSE)``."""

    def __init__(self, key: bytes):
        self._key = key

    def _mac(self, device: str) -> str:
        mac = hmac.new(self._key, device.encode("ascii"), hashlib.sha256).digest()
        return base64.urlsafe_b64encode(mac).rstrip(b"=").decode("ascii")

    def issue(self, device: str | None = None) -> str:
        """A cookie value for ``device`` (a new random id when None)."""
        device = device or secrets.token_urlsafe(16)
        return f"{device}.{self._mac(device)}"

    def verify(self, value: str | None) -> str | None:
        """The device id a cookie value proves, or None (missing, malformed or forged)."""
        if not value or len(value) > 128:
            return None
        device, sep, mac = value.partition(".")
        if not sep or not device.isascii() or not mac.isascii():
            return None
        return device if hmac.compare_digest(mac, self._mac(device)) else None


@dataclass
class _Backoff:
    """Consecutive failures of one address or browser: (count, last failure, locked until)."""

    count: int
    last: float
    until: float


@dataclass
class LoginLimiter:
    """The login limits (module docstring): exponential backoff per address or device, and a
    global token bucket of failures for logins without a device cookie. ``clock`` is monotonic
    seconds (injectable).

    Call :meth:`wait` before looking at the token or password, then :meth:`failed` or
    :meth:`succeeded`, with no ``await`` in between, or all of it under one lock that every login
    takes (the console's event loop then never lets two logins slip past one check).
    """

    free_failures: int = FREE_FAILURES
    first_s: float = BACKOFF_FIRST_S
    cap_s: float = BACKOFF_CAP_S
    forget_s: float = FORGET_S
    budget: int = GLOBAL_BUDGET
    window_s: float = GLOBAL_WINDOW_S
    reserve: float = GLOBAL_RESERVE
    clock: Callable[[], float] = time.monotonic
    _by_key: dict[str, _Backoff] = field(default_factory=dict)
    _tokens: float | None = None
    _stamp: float = 0.0

    @staticmethod
    def _key(address: str, device: str | None) -> str:
        if device:
            return f"device {device}"
        return f"address {address_owner(address)}"      # an IPv6 peer: its /64, which one host commonly holds

    def lock_s(self, count: int) -> float:
        """The wait (seconds) after ``count`` consecutive failures."""
        n = count - self.free_failures
        return 0.0 if n <= 0 else min(self.cap_s, self.first_s * 2.0 ** min(n - 1, 62))

    def _bucket(self, now: float) -> float:
        if self._tokens is None:
            self._tokens, self._stamp = float(self.budget), now
        rate = self.budget / self.window_s
        self._tokens = min(float(self.budget), self._tokens + max(0.0, now - self._stamp) * rate)
        self._stamp = now
        return self._tokens

    @staticmethod
    def _name_key(name: str | None, device: str | None) -> str | None:
        """The key of a user name's failures: only for logins without a device cookie (a browser
        that logged in before is limited by its own failures only)."""
        return f"name {name}" if name and not device else None

    def wait(self, address: str, device: str | None = None, name: str | None = None) -> tuple[int, str]:
        """(whole seconds to wait before this login is tried, 0: now; which limit holds:
        ``"address"``, ``"device"``, ``"name"``, ``"global"`` or ``""``). ``name``: the user name
        the login is for (None for the rig token)."""
        now = self.clock()
        own = 0.0
        b = self._by_key.get(self._key(address, device))
        if b is not None and now - b.last < self.forget_s:
            own = max(0.0, b.until - now)
        own_kind = "device" if device else "address"
        nk = self._name_key(name, device)
        nb = self._by_key.get(nk) if nk else None
        if nb is not None and now - nb.last < self.forget_s and nb.until - now > own:
            own, own_kind = nb.until - now, "name"
        glob = 0.0
        if not device:
            # the bucket's last failure is kept for sources without a recent failure of their own
            known = b is not None and now - b.last < self.forget_s
            need = 1.0 + (self.reserve if known else 0.0)
            tokens = self._bucket(now)
            if tokens < need:
                glob = (need - tokens) * self.window_s / self.budget
        if own <= 0.0 and glob <= 0.0:
            return 0, ""
        if glob > own:
            return max(1, math.ceil(glob)), "global"
        return max(1, math.ceil(own)), own_kind

    def held_back(self) -> bool:
        """Whether the global budget is spent now for sources that failed recently (they wait their turn)."""
        return self._bucket(self.clock()) < 1.0 + self.reserve

    def failed(self, address: str, device: str | None = None, name: str | None = None) -> None:
        """A login with a wrong token or password: the source's wait doubles (and, without a device
        cookie, the user name's); without a device cookie, it draws one failure from the global budget."""
        now = self.clock()
        for key in (self._key(address, device), self._name_key(name, device)):
            if key:
                self._bump(key, now)
        if not device:
            self._tokens = max(-float(self.budget), self._bucket(now) - 1.0)

    def _bump(self, key: str, now: float) -> None:
        b = self._by_key.pop(key, None)
        if b is None or now - b.last >= self.forget_s:
            b = _Backoff(count=0, last=now, until=now)
            while len(self._by_key) >= MAX_ADDRESSES:
                del self._by_key[next(iter(self._by_key))]
        b.count += 1
        b.last = now
        b.until = now + self.lock_s(b.count)
        self._by_key[key] = b       # re-inserted last: the dict stays in order of last failure

    def succeeded(self, address: str, device: str | None = None, name: str | None = None) -> None:
        """The right token or password: this address's (or browser's) failures, and the name's, are forgotten."""
        self._by_key.pop(self._key(address, device), None)
        if name:
            self._by_key.pop(f"name {name}", None)
