"""The rig-token handshake, shared by coordinator, node and operator tools.

Both sides prove they know the rig's secret token before any pose or frame
moves, without sending it: the client sends a random nonce, the coordinator
answers with its own nonce and ``HMAC(token, "coordinator", rig_id, nonces)``,
the client checks that proof (a rogue advertiser without the token fails here)
and answers with ``HMAC(token, role, rig_id, slot, nonces)`` (a node without the
token fails there). Nonces are single use.
"""
from __future__ import annotations

import grp
import hashlib
import hmac
import os
import secrets
from pathlib import Path

NONCE_BYTES = 32
MIN_TOKEN_BYTES = 16
#: bytes of a proof (an HMAC-SHA-256)
PROOF_BYTES = hashlib.sha256().digest_size


class TokenError(ValueError):
    """The rig token is missing or unusable; the message names the file."""


def new_nonce() -> bytes:
    return secrets.token_bytes(NONCE_BYTES)


def new_token() -> str:
    """A fresh rig token (256 bits, URL-safe text)."""
    return secrets.token_urlsafe(32)


def _mac(token: bytes, *parts: bytes | str) -> bytes:
    h = hmac.new(token, digestmod=hashlib.sha256)
    for part in parts:
        b = part.encode() if isinstance(part, str) else part
        h.update(len(b).to_bytes(4, "big"))
        h.update(b)
    return h.digest()


def coordinator_proof(token: bytes, rig_id: str, client_nonce: bytes, server_nonce: bytes) -> bytes:
    return _mac(token, "shadowless/v1/coordinator", rig_id, client_nonce, server_nonce)


def client_proof(token: bytes, role: str, rig_id: str, slot: str, client_nonce: bytes, server_nonce: bytes) -> bytes:
    return _mac(token, "shadowless/v1/" + role, rig_id, slot, client_nonce, server_nonce)


def verify(expected: bytes, given: bytes) -> bool:
    return hmac.compare_digest(expected, given)


#: the group whose members may read a rig token (deploy's install scripts make the token mode 0640 with it)
OPERATORS_GROUP = "shadowless"


def _operators_group(p: Path) -> bool:
    """Whether ``p`` belongs to the operators' group: readable by that group only is allowed."""
    try:
        return grp.getgrgid(p.stat().st_gid).gr_name == OPERATORS_GROUP
    except (KeyError, OSError):
        return False


def read_token(path: str | os.PathLike[str]) -> bytes:
    """Read a rig token from ``path`` (whitespace stripped); refuse short or world-readable files, and
    files its group may read unless that group is the operators' (OPERATORS_GROUP, read only)."""
    p = Path(path)
    if p.is_dir():
        raise TokenError(f"rig token file {p} is a directory, not a file (pass the token file inside it?)")
    try:
        raw = p.read_bytes()
        mode = p.stat().st_mode & 0o777
        text = raw.decode("utf-8").strip()
    except FileNotFoundError:
        raise TokenError(f"rig token file {p} does not exist (create one with `shadowless rig init`)") from None
    except OSError as exc:
        raise TokenError(f"cannot read rig token file {p}: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise TokenError(f"rig token file {p} is not text (is it the right file?)") from None
    if not text:
        raise TokenError(f"rig token file {p} is empty (copy the rig's token into it, or run `shadowless rig init`)")
    if "\x00" in text or not text.isprintable() or len(text.split()) != 1:
        raise TokenError(f"rig token file {p} is not a token (binary data or several words; is it the right file?)")
    if len(text.encode()) < MIN_TOKEN_BYTES:
        raise TokenError(f"rig token in {p} is shorter than {MIN_TOKEN_BYTES} bytes")
    if mode & 0o077 and not (mode & 0o077 == 0o040 and _operators_group(p)):
        who = " and ".join(w for w, bits in (("its group", 0o070), ("every user", 0o007)) if mode & bits)
        raise TokenError(f"rig token file {p} can be read by {who} (mode {mode:04o}): anyone who reads it can join "
                         f"or drive the rig; fix it with: chmod 600 {p}")
    return text.encode()


def resolve_token(token_file: str | None, env: str = "SHADOWLESS_TOKEN_FILE") -> bytes:
    """The token from ``--token-file`` or the ``SHADOWLESS_TOKEN_FILE`` environment variable."""
    path = token_file or os.environ.get(env)
    if not path:
        raise TokenError(f"no rig token: pass --token-file or set {env}")
    return read_token(path)
