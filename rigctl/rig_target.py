"""Which rig an operator's command talks to, and connecting to that rig only.

The rig is named by what the operator has on this machine: ``--rig-dir DIR`` gives both
the rig's id (from ``DIR/rig.toml``) and its token (``DIR/token``); ``--token-file`` and
``--rig NAME_OR_ID`` say the same for a rig whose directory lives elsewhere. Over mDNS,
every advertised coordinator of that rig is tried at once and the first that proves it
knows the token (and, with a rig directory, serves that rig's id) is used; advertisers
of other rigs or with another token are passed over and named in the error when
nothing else answers. An explicit ``--coordinator`` is checked the same way.
"""
from __future__ import annotations

import argparse
import asyncio
import os
from dataclasses import dataclass
from pathlib import Path

from rigctl.client import OperatorError
from rigctl.link import Client
from coordinator.errors import RigError
from coordinator.rig import parse_config
from coordinator.schema import read_text
from protos import auth
from protos.discovery import Discovery, DiscoveryError

__all__ = ["RigTarget", "resolve", "connect", "discover", "open_client"]


@dataclass(frozen=True)
class RigTarget:
    """The rig a command wants: its token (and where it came from), and, when known, its id and
    name (from a rig directory) or the name/id given with ``--rig``."""
    token: bytes
    token_source: str
    rig_id: str = ""
    rig_name: str = ""
    wanted: str = ""          # --rig: a name or an id, matched against advertisements

    def describe(self) -> str:
        if self.rig_id:
            return f"rig {self.rig_name!r} (id {self.rig_id})"
        return f"rig {self.wanted!r}" if self.wanted else "the rig"


def resolve(args: argparse.Namespace) -> RigTarget:
    """The rig named by the connection options (see :func:`rigctl.client.add_connection_args`)."""
    rig_dir = getattr(args, "rig_dir", None)
    rig_id = rig_name = ""
    if rig_dir:
        toml = Path(rig_dir) / "rig.toml"
        if not Path(rig_dir).is_dir():
            raise OperatorError(f"--rig-dir {rig_dir}: no such directory")
        try:
            cfg = parse_config(read_text(toml), source=str(toml))
        except RigError as exc:
            raise OperatorError(str(exc)) from exc
        rig_id, rig_name = cfg.rig_id, cfg.name
    token_file = getattr(args, "token_file", None) or os.environ.get("SHADOWLESS_TOKEN_FILE")
    if not token_file and rig_dir:
        token_file = str(Path(rig_dir) / "token")
    if not token_file:
        raise OperatorError("no rig token: pass --rig-dir DIR, --token-file FILE or set SHADOWLESS_TOKEN_FILE")
    token = auth.read_token(token_file)
    wanted = getattr(args, "rig", None) or ""
    if rig_id and wanted and wanted not in (rig_id, rig_name):
        raise OperatorError(f"--rig {wanted!r} is not the rig in {rig_dir} ({rig_name!r}, id {rig_id}); "
                            "drop one of the two")
    return RigTarget(token=token, token_source=token_file, rig_id=rig_id, rig_name=rig_name, wanted=wanted)


async def _first_proven(rig: RigTarget, targets: list[str], tls: dict) -> Client | list[str]:
    """The first of ``targets`` that proves ``rig``'s token (and serves its id, when known), all
    tried at once so that an unreachable or rogue one never delays the right one; or, when
    none does, why each failed."""
    async def one(target: str) -> Client:
        return await Client.connect(target, rig.token, rig_id=rig.rig_id, token_source=rig.token_source, **tls)

    tasks = [asyncio.ensure_future(one(t)) for t in targets]
    failures: list[str] = []
    winner: Client | None = None
    try:
        for done in asyncio.as_completed(tasks):
            try:
                winner = await done
                return winner
            except OperatorError as exc:
                failures.append(str(exc))
    finally:
        for task in tasks:
            task.cancel()
        for c in await asyncio.gather(*tasks, return_exceptions=True):
            if isinstance(c, Client) and c is not winner:     # only the first that answered is kept
                await c.close()
    return failures


def _failed(rig: RigTarget, failures: list[str]) -> OperatorError:
    if len(failures) == 1:
        return OperatorError(failures[0])
    return OperatorError(f"none of the {len(failures)} coordinators found is {rig.describe()}: " + "; ".join(failures))


async def connect(rig: RigTarget, target: str, *, tls_ca: bytes | None = None,
                  tls_server_name: str | None = None) -> Client:
    """A client of ``rig``'s coordinator at ``target`` (OperatorError if it is not that rig's)."""
    got = await _first_proven(rig, [target], {"tls_ca": tls_ca, "tls_server_name": tls_server_name})
    if isinstance(got, Client):
        return got
    raise _failed(rig, got)


async def discover(rig: RigTarget, *, interfaces: list[str] | None = None, timeout: float = 3.0,
                   tls_ca: bytes | None = None, tls_server_name: str | None = None) -> Client:
    """A client of ``rig``'s coordinator found over mDNS. Advertisements of the rig (by id, or by
    the ``--rig`` name) are tried as they arrive, for up to ``timeout`` seconds: a rogue that answers
    first is passed over and the right one, answering a moment later, still found. When only
    refused coordinators of the rig have answered by then, the right one is waited for up to
    ``timeout`` seconds more (a loaded network or host answers late; the rig is evidently out there)."""
    tls = {"tls_ca": tls_ca, "tls_server_name": tls_server_name}
    disc = Discovery(interfaces=interfaces)
    try:
        await disc.start()
    except DiscoveryError as exc:
        raise OperatorError(str(exc)) from None
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    extended = False
    tried: set[str] = set()
    failures: list[str] = []
    try:
        while True:
            ads = await disc.find(rig=rig.rig_id or rig.wanted or None, timeout=max(0.0, deadline - loop.time()))
            new = sorted({a.target for a in ads} - tried)
            if new:
                tried.update(new)
                got = await _first_proven(rig, new, tls)
                if isinstance(got, Client):
                    return got
                failures += got
            if loop.time() >= deadline:
                if not failures or extended:
                    break
                deadline, extended = loop.time() + timeout, True
            await asyncio.sleep(0.2)
        if failures:
            raise _failed(rig, failures)
        searched = f"searched {disc.service_type} on {', '.join(interfaces) if interfaces else 'every interface'} " \
                   f"for {timeout * (2 if extended else 1):g} s"
        others = await disc.find(timeout=0) if (rig.rig_id or rig.wanted) else []
        if others:
            listed = ", ".join(sorted(f"{a.name!r} (id {a.rig_id}) at {a.target}" for a in others))
            raise OperatorError(f"no coordinator of {rig.describe()} is advertised over mDNS ({searched}); found only "
                                f"{listed}. Start its coordinator, or pass --coordinator HOST:PORT")
        raise OperatorError(f"no coordinator of {rig.describe()} found over mDNS: {searched}; start its "
                            "coordinator, check SHADOWLESS_MDNS_SERVICE and --mdns-interface, or pass --coordinator "
                            "HOST:PORT")
    finally:
        await disc.close()


async def open_client(args: argparse.Namespace) -> Client:
    """A client of the rig named by the connection options: the one at ``--coordinator``, or the
    rig's coordinator advertised over mDNS."""
    rig = resolve(args)
    tls_ca = None
    if getattr(args, "tls_ca", None):
        try:
            tls_ca = Path(args.tls_ca).read_bytes()
        except OSError as exc:
            raise OperatorError(f"--tls-ca {args.tls_ca}: {exc.strerror or exc}") from exc
    tls = {"tls_ca": tls_ca, "tls_server_name": getattr(args, "tls_server_name", None)}
    if getattr(args, "coordinator", None):
        return await connect(rig, args.coordinator, **tls)
    return await discover(rig, interfaces=getattr(args, "mdns_interface", None), **tls)
