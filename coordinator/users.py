"""The rig's people: named logins with a role, kept hashed in ``users.json`` in the rig directory.

Everyone used to share the rig token, so the action log could only name a session. A rig may
now hold users, each with a name, a password and one of three roles (:class:`Role`):

* ``viewer`` sees everything the console shows and acts on nothing;
* ``operator`` acts: shows, plays, stops, fires cues, runs jobs;
* ``admin`` also manages the users. A login with the rig token is an admin (named ``token``).

Passwords are kept as scrypt hashes (:func:`hashlib.scrypt`, a random 16-byte salt each, the
parameters stored with the hash so that they may grow later), never in clear. ``users.json`` is
written atomically (a temp file renamed over it, mode 0600, like the token) under an advisory
lock (``.users.lock``), so two ``shadowless rig user`` commands never lose each other's change,
and a coordinator reading it never sees half a file. A :class:`UserStore` re-reads the file
whenever it changed on disk (its size, inode or modification time), so a running coordinator
applies a change made from the command line at the next request: a new role holds at once; a
removed user's sessions end, and so do a user's sessions opened before their password was set
(or before their name was given to someone new).

Names are 1-32 characters: letters, digits, ``_``, ``.``, ``-`` and ``@``, starting with a letter
or a digit; they are kept in lower case (``Alice`` and ``alice`` are one person). ``token`` is
reserved (the rig token's logins carry it). Passwords are 8-1024 characters. Every refusal is one
:class:`UserError` line and changes nothing stored.
"""
from __future__ import annotations

import base64
import enum
import hashlib
import hmac
import json
import logging
import os
import re
import secrets
import threading
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from coordinator.errors import RigError
from protos.store import atomic_file, flocked

log = logging.getLogger(__name__)

__all__ = ["FILE_NAME", "Role", "User", "UserError", "UserStore", "check_name", "check_password", "parse_role"]

#: the users' file in the rig directory, and the lock its writers take
FILE_NAME = "users.json"
LOCK_NAME = ".users.lock"
#: the name the action log gives a login with the rig token
TOKEN_WHO = "token"
NAME_RE = re.compile(r"^[a-z0-9][a-z0-9_.@-]{0,31}$")
RESERVED = frozenset({TOKEN_WHO, "-"})
MIN_PASSWORD, MAX_PASSWORD = 8, 1024
#: scrypt's cost: N = 2**14, r = 8, p = 1 (16 MiB and some tens of milliseconds a hash)
SCRYPT_N, SCRYPT_R, SCRYPT_P, SCRYPT_LEN = 1 << 14, 8, 1, 32
#: the users a rig may hold (the file stays small enough to read on every change)
MAX_USERS = 256
FORMAT = 1


class UserError(RigError):
    """A user command or file refused, in one line."""


class Role(str, enum.Enum):
    """What a console login may do; each role may do what the ones before it may."""

    VIEWER = "viewer"
    OPERATOR = "operator"
    ADMIN = "admin"

    @property
    def rank(self) -> int:
        return _RANK[self]

    def allows(self, needed: "Role") -> bool:
        """Whether this role may do what ``needed`` may."""
        return self.rank >= needed.rank

    def __str__(self) -> str:
        return self.value


_RANK = {Role.VIEWER: 0, Role.OPERATOR: 1, Role.ADMIN: 2}
ROLES = tuple(r.value for r in Role)


def parse_role(text: object) -> Role:
    """``"viewer"``, ``"operator"`` or ``"admin"`` (any case) as a Role; UserError naming the choices."""
    try:
        return Role(str(text).strip().lower())
    except ValueError:
        raise UserError(f"unknown role {text!r}: choose one of {', '.join(ROLES)}") from None


def check_name(name: object) -> str:
    """A user name, in lower case; UserError saying what a name may be."""
    if not isinstance(name, str):
        raise UserError(f"a user name must be text, got {name!r}")
    n = name.strip().lower()
    if n in RESERVED:
        raise UserError(f"the name {n!r} is reserved (the rig token's logins carry it): choose another")
    if not NAME_RE.match(n):
        raise UserError(f"user name {name!r} must be 1-32 letters, digits, '_', '.', '-' or '@', starting with a "
                        "letter or a digit")
    return n


def check_password(password: object) -> str:
    if not isinstance(password, str):
        raise UserError("a password must be text")
    if not MIN_PASSWORD <= len(password) <= MAX_PASSWORD:
        raise UserError(f"a password must be {MIN_PASSWORD}-{MAX_PASSWORD} characters long, got {len(password)}")
    return password


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode("ascii")


def hash_password(password: str, *, salt: bytes | None = None) -> str:
    """``scrypt$N$r$p$<salt>$<hash>`` (base64) of ``password`` under a fresh random salt."""
    salt = salt if salt is not None else secrets.token_bytes(16)
    dk = hashlib.scrypt(password.encode(), salt=salt, n=SCRYPT_N, r=SCRYPT_R, p=SCRYPT_P, dklen=SCRYPT_LEN)
    return f"scrypt${SCRYPT_N}${SCRYPT_R}${SCRYPT_P}${_b64(salt)}${_b64(dk)}"


def password_matches(password: str, stored: str) -> bool:
    """Whether ``password`` hashes to ``stored`` (compared in constant time); False for a damaged hash."""
    try:
        kind, n, r, p, salt, want = stored.split("$")
        if kind != "scrypt":
            return False
        n, r, p = int(n), int(r), int(p)
        if not (2 <= n <= 1 << 20 and n & (n - 1) == 0 and 1 <= r <= 32 and 1 <= p <= 16):
            return False
        salt_b, want_b = base64.b64decode(salt, validate=True), base64.b64decode(want, validate=True)
        dk = hashlib.scrypt(password.encode(), salt=salt_b, n=n, r=r, p=p, dklen=len(want_b),
                            maxmem=256 * r * n + (1 << 20))
    except (ValueError, TypeError):
        return False
    return hmac.compare_digest(dk, want_b)


_dummy: dict[int, str] = {}


def _dummy_hash() -> str:
    """What an unknown name's password is checked against, so that a wrong name costs as long as a
    wrong password (made once per cost setting)."""
    if SCRYPT_N not in _dummy:
        _dummy[SCRYPT_N] = hash_password("not a password of anyone", salt=b"\0" * 16)
    return _dummy[SCRYPT_N]


@dataclass(frozen=True)
class User:
    """One person: their name, role, when the entry was made and last changed, and when its
    password was set (UTC, ISO 8601; a console session opened before that ends)."""

    name: str
    role: Role
    created: str = ""
    changed: str = ""
    password_set: str = ""


def _now_iso() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def _now_iso_us() -> str:
    """Now to the microsecond: what tells one setting of a password (or one user of a name) from the next."""
    return datetime.now(timezone.utc).isoformat(timespec="microseconds")


class UserStore:
    """The users of the rig at ``rig_dir`` (``users.json``; the module docstring says how).

    Reading methods re-read the file when it changed on disk; changing methods (:meth:`add`,
    :meth:`remove`, :meth:`set_role`, :meth:`set_password`) read, change and write it under the
    lock, so they always start from what is stored. Safe to call from several threads.
    """

    def __init__(self, rig_dir: str | os.PathLike[str]):
        self.dir = Path(rig_dir)
        self.path = self.dir / FILE_NAME
        self._lock = threading.Lock()
        self._stamp: tuple[int, int, int] | None = None
        self._users: dict[str, dict] = {}
        self._error = ""      # why the file on disk cannot be used ("" when it can, or is missing)

    # ------------------------------------------------------------------ reading
    def _read_file(self) -> dict[str, dict]:
        """The stored entries (name -> {role, hash, created, changed}); UserError for a damaged file."""
        try:
            raw = self.path.read_bytes()
        except FileNotFoundError:
            return {}
        except OSError as exc:
            raise UserError(f"{self.path}: cannot be read: {exc.strerror or exc}") from None
        try:
            doc = json.loads(raw)
        except ValueError as exc:
            raise UserError(f"{self.path}: not JSON ({exc}); restore it or remove it and add the users again") from None
        users = doc.get("users") if isinstance(doc, dict) else None
        if not isinstance(users, dict) or len(users) > MAX_USERS:
            raise UserError(f"{self.path}: expected {{\"users\": {{NAME: {{role, hash}}, ...}}}} with at most "
                            f"{MAX_USERS} users")
        out = {}
        for name, entry in users.items():
            if (not isinstance(name, str) or not NAME_RE.match(name) or name in RESERVED or not isinstance(entry, dict)
                    or entry.get("role") not in ROLES or not isinstance(entry.get("hash"), str)):
                raise UserError(f"{self.path}: the entry {name!r} is damaged (a role of {', '.join(ROLES)} and a hash "
                                "are needed); remove it with `shadowless rig user rm`")
            out[name] = entry
        return out

    def _stat(self) -> tuple[int, int, int] | None:
        try:
            st = self.path.stat()
        except FileNotFoundError:
            return None
        return (st.st_ino, st.st_size, st.st_mtime_ns)

    def _fresh(self) -> dict[str, dict]:
        """The entries as stored now (re-read when the file changed). A damaged file is logged once
        per change and counts as holding nobody: only the rig token logs in until it is fixed."""
        stamp = self._stat()
        with self._lock:
            if stamp != self._stamp or stamp is None:
                try:
                    self._users, self._error = self._read_file(), ""
                except UserError as exc:
                    if str(exc) != self._error:
                        log.error("%s; until then only the rig token logs in to the console", exc)
                    self._users, self._error = {}, str(exc)
                self._stamp = stamp
            return self._users

    @property
    def error(self) -> str:
        """Why the stored file cannot be used ("" when it can, or when there is none)."""
        self._fresh()
        return self._error

    @staticmethod
    def _user(name: str, e: dict) -> User:
        return User(name, Role(e["role"]), e.get("created", ""), e.get("changed", ""),
                    e.get("password_set", e.get("created", "")))

    def list(self) -> list[User]:
        """Every user, by name."""
        return [self._user(n, e) for n, e in sorted(self._fresh().items())]

    def get(self, name: str) -> User | None:
        """The user ``name`` as stored now, or None."""
        key = name.strip().lower() if isinstance(name, str) else ""
        e = self._fresh().get(key)
        return self._user(key, e) if e else None

    def __len__(self) -> int:
        return len(self._fresh())

    def role_of(self, name: str) -> Role | None:
        """The role ``name`` holds now, or None (no such user)."""
        e = self._fresh().get(name.strip().lower() if isinstance(name, str) else "")
        return Role(e["role"]) if e else None

    def verify(self, name: str, password: str) -> Role | None:
        """The role of ``name`` when ``password`` is theirs, else None. An unknown name costs the
        same hash as a known one (nobody learns which names exist from the time taken). Blocking
        (a scrypt hash: tens of milliseconds): call it from a worker thread on an event loop."""
        key = name.strip().lower() if isinstance(name, str) else ""
        e = self._fresh().get(key)
        if not isinstance(password, str) or len(password) > MAX_PASSWORD:
            return None
        ok = password_matches(password, e["hash"] if e else _dummy_hash())
        return Role(e["role"]) if e and ok else None

    # ------------------------------------------------------------------ changing
    def _change(self, change) -> str:
        """Run ``change(users)`` on the stored entries under the lock and write them back; returns its text."""
        if not self.dir.is_dir():
            raise UserError(f"{self.dir} is not a rig directory (no such folder)")
        with flocked(self.dir / LOCK_NAME):
            users = self._read_file()
            said = change(users)
            doc = {"format": FORMAT, "users": {n: users[n] for n in sorted(users)}}
            with atomic_file(self.path, mode=0o600) as f:
                f.write((json.dumps(doc, indent=2) + "\n").encode())
        self._stamp = None      # read again next time
        return said

    def add(self, name: str, role: Role | str, password: str) -> str:
        """A new user; UserError if the name is taken or anything is invalid. Returns a line saying what was done."""
        name, role, password = check_name(name), parse_role(role), check_password(password)
        digest = hash_password(password)

        def change(users: dict) -> str:
            if name in users:
                raise UserError(f"user {name!r} exists already (role {users[name]['role']}); change it with "
                                f"`shadowless rig user role {name} ROLE` or `... user password {name}`")
            if len(users) >= MAX_USERS:
                raise UserError(f"a rig holds at most {MAX_USERS} users; remove one first")
            now = _now_iso_us()
            users[name] = {"role": role.value, "hash": digest, "created": now, "changed": now, "password_set": now}
            return f"added {name} ({role})"
        return self._change(change)

    def remove(self, name: str) -> str:
        name = check_name(name)

        def change(users: dict) -> str:
            if name not in users:
                raise UserError(f"no user {name!r}" + (f": the users are {', '.join(sorted(users))}" if users
                                                       else ": the rig has no users"))
            del users[name]
            return f"removed {name}"
        return self._change(change)

    def set_role(self, name: str, role: Role | str) -> str:
        name, role = check_name(name), parse_role(role)

        def change(users: dict) -> str:
            if name not in users:
                raise UserError(f"no user {name!r}; add one with `shadowless rig user add {name} --role {role}`")
            old = users[name]["role"]
            users[name] = {**users[name], "role": role.value, "changed": _now_iso()}
            return f"{name}: {old} -> {role}" if old != role.value else f"{name} is already {role}"
        return self._change(change)

    def set_password(self, name: str, password: str) -> str:
        name, password = check_name(name), check_password(password)
        digest = hash_password(password)

        def change(users: dict) -> str:
            if name not in users:
                raise UserError(f"no user {name!r}; add one with `shadowless rig user add {name}`")
            now = _now_iso_us()
            users[name] = {**users[name], "hash": digest, "changed": now, "password_set": now}
            return f"new password for {name}"
        return self._change(change)
