"""`shadowless node`: the edge runtime, one process per projector."""
from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys
from pathlib import Path

from node.app import Node, NodeConfig
from protos.auth import TokenError, resolve_token
from protos.version import PROTOCOL_VERSION


def configure(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Run the node for one projector. It finds the coordinator over mDNS (or --coordinator),\n"
        "proves the rig token, joins with its slot name, keeps its clock in step with the rig,\n"
        "renders every frame with its pose and LUT, swaps at the scheduled instant and reports it.\n"
        "It survives coordinator restarts and network loss by itself; the projector keeps the\n"
        "last image meanwhile."
    )
    p.epilog = (
        "examples:\n"
        "  shadowless node --slot r0c0 --token-file /etc/shadowless/token --output window\n"
        "  shadowless node --slot r2c2 --coordinator 10.0.0.2:7600 --token-file token\n"
        "  shadowless node --slot r0c0 --output room://127.0.0.1:7700   # the virtual room"
    )
    p.add_argument("--slot", required=True, help="this projector's slot in the rig (e.g. r0c0)")
    p.add_argument("--token-file", metavar="FILE", help="rig token file (default: $SHADOWLESS_TOKEN_FILE)")
    p.add_argument("--coordinator", metavar="HOST:PORT", help="skip mDNS and use this coordinator")
    p.add_argument("--rig", metavar="NAME", help="with several rigs on the network, join this one (name or id)")
    p.add_argument("--mdns-interface", action="append", metavar="IP",
                   help="browse mDNS only on this IPv4 address (repeatable; default: every interface)")
    p.add_argument("--output", default="offscreen", metavar="SPEC",
                   help="offscreen (default), window[:MONITOR] (fullscreen on a display), or room://HOST:PORT")
    p.add_argument("--snapshot-dir", type=Path, metavar="DIR",
                   help="write every shown still to DIR/<slot>.png (for inspection)")
    p.add_argument("--tls-ca", metavar="PEM", help="connect with TLS, trusting this CA certificate")
    p.add_argument("--tls-server-name", metavar="NAME", help="expected name in the coordinator's certificate")
    p.add_argument("--ping-hz", type=float, default=4.0, help="clock exchanges per second (default 4)")
    p.add_argument("--no-realtime", action="store_true",
                   help="do not raise the swap to real-time priority (SCHED_FIFO needs CAP_SYS_NICE)")
    p.add_argument("--log-level", default="info", choices=["debug", "info", "warning", "error"])
    test = p.add_argument_group("test hooks (make this node deliberately wrong)")
    test.add_argument("--clock-offset-ms", type=float, default=0.0, help="offset this node's clock by this much")
    test.add_argument("--clock-drift-ppm", type=float, default=0.0, help="make this node's clock run fast/slow")
    test.add_argument("--protocol-version", type=int, default=PROTOCOL_VERSION, help=argparse.SUPPRESS)


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=getattr(logging, args.log_level.upper()), stream=sys.stderr, force=True,
                        format=f"%(asctime)s %(levelname)-7s node {args.slot}: %(message)s")
    log = logging.getLogger("node")
    try:
        token = resolve_token(args.token_file)
        tls_ca = Path(args.tls_ca).read_bytes() if args.tls_ca else None
    except (TokenError, OSError) as exc:
        log.error("%s", exc)
        return 2
    cfg = NodeConfig(slot=args.slot, token=token, coordinator=args.coordinator, rig=args.rig,
                     mdns_interfaces=args.mdns_interface, output=args.output, snapshot_dir=args.snapshot_dir,
                     clock_offset_ms=args.clock_offset_ms, clock_drift_ppm=args.clock_drift_ppm,
                     protocol_version=args.protocol_version, tls_ca=tls_ca, tls_server_name=args.tls_server_name,
                     ping_hz=args.ping_hz, realtime=not args.no_realtime)

    async def main() -> int:
        node = Node(cfg)
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, node.stop)
        return await node.run()

    return asyncio.run(main())
