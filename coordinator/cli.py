"""`shadowless coordinator`: serve a rig directory to nodes and operators."""
from __future__ import annotations

import argparse
import asyncio
import logging
import os
import signal
from pathlib import Path

from coordinator.console.hosts import allowed_host
from coordinator.errors import OPERATOR_ERRORS, CoordinatorError, RigError
from protos.store import atomic_write_text
from protos.auth import TokenError, resolve_token

log = logging.getLogger("coordinator")


def configure(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Run the coordinator of a rig: it holds calibration, LUTs and content (persisted in the rig\n"
        "directory), advertises itself over mDNS as _shadowless._tcp, lets nodes join with the rig\n"
        "token, streams frames and schedules synchronized swaps. Stop it with Ctrl-C or SIGTERM:\n"
        "it unregisters from mDNS and closes node streams gracefully; restart it on the same rig\n"
        "directory and every node comes back by itself."
    )
    p.epilog = (
        "examples:\n"
        "  shadowless rig init rigs/table --grid 5x5\n"
        "  shadowless coordinator --rig rigs/table\n"
        "  shadowless coordinator --rig rigs/table --listen 10.0.0.2:7600 --mdns-interface 10.0.0.2\n"
        "  shadowless coordinator --rig rigs/table --tls-cert cert.pem --tls-key key.pem\n"
        "  shadowless coordinator --rig rigs/table --console 0.0.0.0:7680 --tls-cert cert.pem --tls-key key.pem\n"
        "  shadowless coordinator --rig rigs/table --mtc-port list"
    )
    p.add_argument("--rig", required=True, metavar="DIR", help="rig directory (with rig.toml; see `shadowless rig init`)")
    p.add_argument("--listen", default="0.0.0.0:7600", metavar="HOST:PORT",
                   help="gRPC address (default 0.0.0.0:7600; port 0 picks a free one, mDNS tells nodes)")
    p.add_argument("--token-file", metavar="FILE",
                   help="rig token file (default: $SHADOWLESS_TOKEN_FILE, else DIR/token)")
    p.add_argument("--mdns-interface", action="append", metavar="IP",
                   help="advertise only on this IPv4 address (repeatable; default: every interface)")
    p.add_argument("--no-mdns", action="store_true", help="do not advertise; nodes then need --coordinator HOST:PORT")
    p.add_argument("--latency-ms", type=float, help="schedule frames this far ahead (default: rig.toml's latency_ms)")
    p.add_argument("--tls-cert", metavar="PEM", help="serve TLS with this certificate chain (with --tls-key)")
    p.add_argument("--tls-key", metavar="PEM", help="private key for --tls-cert")
    p.add_argument("--camera", action="append", metavar="SPEC",
                   help="camera for calibration jobs: room://HOST:PORT, opencv:INDEX, a device path or folder:DIR "
                        "(repeatable; default: rig.toml's cameras)")
    p.add_argument("--port-file", metavar="FILE", help="write the bound port here once listening (for scripts)")
    p.add_argument("--console", default="127.0.0.1:7680", metavar="HOST:PORT",
                   help="serve the operator console (a web page) here (default 127.0.0.1:7680, this machine only; "
                        "0.0.0.0:7680 opens it to the network, with TLS when --tls-cert is given; port 0 picks one)")
    p.add_argument("--console-host", action="append", default=[], type=allowed_host, metavar="NAME[:PORT]",
                   help="a name browsers use for the console (repeatable; e.g. console.venue.lan): requests must name "
                        "an address the console listens on or one of these, else they are refused")
    p.add_argument("--no-console", action="store_true", help="do not serve the operator console")
    p.add_argument("--console-optional", action="store_true",
                   help="if the console's port is taken, run on without the console (status then says "
                        "'console: NOT SERVED'); by default the coordinator refuses to start")
    p.add_argument("--console-port-file", metavar="FILE", help="write the console's bound port here (for scripts)")
    p.add_argument("--mtc-port", metavar="NAME",
                   help="chase MIDI timecode from this MIDI input port (its name or a part naming one port; "
                        "overrides rig.toml's [osc] mtc_port; `list` prints the ports and exits; needs "
                        "pip install 'shadowless[midi]')")


async def serve(args: argparse.Namespace) -> int:
    # imported here, not above: `shadowless coordinator --help` (and a mistyped option) need no server
    from coordinator.app import CoordinatorApp
    from coordinator.rig import Rig

    rig = Rig(args.rig)
    token_file = args.token_file
    if not token_file:
        token_file = os.environ.get("SHADOWLESS_TOKEN_FILE") or str(Path(args.rig) / "token")
    token = resolve_token(token_file)
    tls = None
    if args.tls_cert or args.tls_key:
        if not (args.tls_cert and args.tls_key):
            raise CoordinatorError("TLS needs both --tls-cert and --tls-key")
        tls = (Path(args.tls_cert).read_bytes(), Path(args.tls_key).read_bytes())
    app = CoordinatorApp(rig, token, listen=args.listen, mdns_interfaces=args.mdns_interface,
                         advertise=not args.no_mdns, tls=tls, latency_ms=args.latency_ms,
                         cameras=args.camera, console=None if args.no_console else args.console,
                         console_hosts=args.console_host, console_optional=args.console_optional,
                         mtc_port=args.mtc_port)
    await app.start()
    if args.port_file:
        atomic_write_text(args.port_file, f"{app.port}\n")
    if args.console_port_file and app.console_port:
        atomic_write_text(args.console_port_file, f"{app.console_port}\n")
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    await stop.wait()
    log.info("shutting down")
    await app.stop()
    return 0


def list_midi_ports() -> int:
    """``--mtc-port list``: the MIDI input ports, one a line (a line saying why there are none)."""
    from coordinator.osc.mtc_input import port_names
    names = port_names()
    print("\n".join(names) if names else "no MIDI input ports on this machine")
    return 0


def run(args: argparse.Namespace) -> int:
    try:
        if args.mtc_port == "list":
            return list_midi_ports()
        return asyncio.run(serve(args))
    except (*OPERATOR_ERRORS, RigError, TokenError, OSError) as exc:
        log.error("%s", exc)
        return 2
