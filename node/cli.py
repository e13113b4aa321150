"""`shadowless node`: the edge runtime, one process per projector."""
from __future__ import annotations

import argparse
import asyncio
import logging
import os
import signal
from pathlib import Path
from typing import TYPE_CHECKING

from node.asset_cache import default_cache_dir
from node.decoders import ENV as DECODER_ENV, check_wish
from node.display_check import DISPLAY_HELD_EXIT, display_conflict, running_programs
from node.output_spec import parse_output_spec
from node.render.context import GL_CHOICES, GL_ENV
from protos.auth import TokenError, resolve_token
from protos import cli_types
from protos.version import PROTOCOL_VERSION

if TYPE_CHECKING:
    from node.app import NodeConfig


def output_spec(text: str) -> str:
    """An ``--output`` spec, checked (not opened) here: a typo costs one line, not a renderer start."""
    try:
        parse_output_spec(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def decoder_wish(text: str) -> str:
    """--decoder's argparse type (node.decoders.check_wish)."""
    try:
        return check_wish(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def configure(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Run the node for one projector. It finds the coordinator over mDNS (or --coordinator),\n"
        "proves the rig token, joins with its slot name, keeps its clock in step with the rig,\n"
        "renders every frame with its pose and LUT, swaps at the scheduled instant and reports it.\n"
        "It survives coordinator restarts and network loss by itself; the projector keeps the\n"
        "last image meanwhile. It fetches the rig's content assets ahead of use into its cache\n"
        "(resuming partial downloads) and reports its readiness (see `shadowless status`)."
    )
    p.epilog = (
        "examples:\n"
        "  shadowless node --slot r0c0 --token-file /etc/shadowless/token --output window\n"
        "  shadowless node --slot r2c2 --coordinator 10.0.0.2:7600 --token-file token\n"
        "  shadowless node --slot r0c0 --output room://127.0.0.1:7700   # the virtual room\n"
        "  shadowless node --slot r0c0 --cache-dir /var/cache/shadowless --cache-max 20G\n"
        "  shadowless node --slot r0c0 --gl gles   # a Mali or Adreno board: OpenGL ES 3 even if desktop GL is offered\n"
        "  shadowless node --slot r0c0 --discovery-timeout 20   # does mDNS find the coordinator from here?\n"
        "\n"
        "exit status: 0 stopped, 2 a wrong option or token file, 3 the output could not be opened or the\n"
        "renderer stopped, 4 no coordinator found within --discovery-timeout, 78 a desktop holds the\n"
        "display the output needs (the line says what to do; the service is not restarted for it)"
    )
    p.add_argument("--slot", required=True, help="this projector's slot in the rig (e.g. r0c0)")
    p.add_argument("--token-file", metavar="FILE", help="rig token file (default: $SHADOWLESS_TOKEN_FILE)")
    p.add_argument("--coordinator", metavar="HOST:PORT", help="skip mDNS and use this coordinator")
    p.add_argument("--rig", metavar="ID", help="join only a coordinator advertising this rig (its id in rig.toml, or "
                                               "its name); empty or absent: any coordinator that proves the token")
    p.add_argument("--mdns-interface", action="append", metavar="IP",
                   help="browse mDNS only on this IPv4 address (repeatable; default: every interface)")
    p.add_argument("--discovery-timeout", type=cli_types.number(1, 86400), metavar="S",
                   help="give up with exit status 4 if no coordinator is found over mDNS within S seconds of the "
                        "start (a check of the network; default: keep looking, as a service should)")
    p.add_argument("--output", type=output_spec, default="offscreen", metavar="SPEC",
                   help="offscreen (default), window[:MONITOR] (fullscreen on a display through X), kms[:DISPLAY] "
                        "(fullscreen without X, KMS/DRM: a display index or connector such as kms:HDMI-A-1), or "
                        "room://HOST:PORT (the virtual room)")
    p.add_argument("--gl", choices=GL_CHOICES, metavar="{auto,gl,gles}",
                   help="the OpenGL the node renders with: auto (default, or $SHADOWLESS_GL) takes desktop "
                        "OpenGL 3.1+ where the driver offers it, else OpenGL ES 3.0+ (offscreen, room and kms "
                        "outputs; the window output is desktop GL only); gl or gles forces one. "
                        "`shadowless status` shows what each node got")
    p.add_argument("--decoder", type=decoder_wish, metavar="auto|software|NAME",
                   help="the video decoder: auto (default, or $SHADOWLESS_DECODER) takes a hardware decoder where "
                        "one opens here (h264_v4l2m2m, hevc_v4l2m2m on a Raspberry Pi; VAAPI, DRM), else software; "
                        "software forces FFmpeg's own; NAME a decoder (h264_v4l2m2m), a family (v4l2m2m) or a "
                        "hardware device type (vaapi, drm, cuda), software when it cannot open, with one log line "
                        "saying why. `shadowless status` shows each node's decoder")
    p.add_argument("--snapshot-dir", type=Path, metavar="DIR",
                   help="write every shown still to DIR/<slot>.png (for inspection)")
    p.add_argument("--tls-ca", metavar="PEM", help="connect with TLS, trusting this CA certificate")
    p.add_argument("--tls-server-name", metavar="NAME", help="expected name in the coordinator's certificate")
    p.add_argument("--ping-hz", type=cli_types.number(0.1, 100), default=4.0,
                   help="clock exchanges per second until the clock estimate is settled, about 20 s (default 4)")
    p.add_argument("--ping-settled-s", type=cli_types.number(1, 60), default=10.0, metavar="S",
                   help="then one clock exchange every S seconds (1..60, default 10; each costs the coordinator ~0.5 ms)")
    p.add_argument("--no-realtime", action="store_true",
                   help="do not raise the swap to real-time priority (SCHED_FIFO needs CAP_SYS_NICE)")
    cache = p.add_argument_group("assets fetched ahead of use")
    cache.add_argument("--cache-dir", metavar="DIR",
                       help=f"where fetched assets are kept (default: {default_cache_dir()}/SLOT; one node per "
                            "directory)")
    cache.add_argument("--cache-max", type=cli_types.byte_size, default="8G", metavar="SIZE",
                       help="cap on the cache's size, e.g. 20G or 500M (powers of 1024; default 8G); the least "
                            "recently used assets the rig no longer wants are evicted to stay under it")
    cache.add_argument("--fetch-rate", type=cli_types.byte_size, metavar="BYTES_PER_S",
                       help="fetch assets at most this fast, e.g. 20M for 20 MiB/s (default: as fast as the "
                            "network goes)")
    test = p.add_argument_group("test hooks (make this node deliberately wrong)")
    test.add_argument("--clock-offset-ms", type=cli_types.number(-1e9, 1e9), default=0.0, help="offset this node's clock by this much (default 0)")
    test.add_argument("--clock-drift-ppm", type=cli_types.number(-10000, 10000), default=0.0, help="make this node's clock run fast/slow (default 0)")
    test.add_argument("--protocol-version", type=int, default=PROTOCOL_VERSION, help=argparse.SUPPRESS)
    test.add_argument("--refusal-backoff-s", type=cli_types.number(0.1, 3600), default=10.0, help=argparse.SUPPRESS)


def node_config(args: argparse.Namespace, token: bytes, tls_ca: bytes | None) -> NodeConfig:
    """The node's configuration from its parsed options (the cache directory defaults per slot)."""
    # node.app (gRPC, the wire, the presenter) is imported here, not above: `shadowless node --help`
    # and a mistyped option need none of it
    from node.app import NodeConfig

    return NodeConfig(slot=args.slot, token=token, coordinator=args.coordinator, rig=args.rig or None,
                      mdns_interfaces=args.mdns_interface, output=args.output, snapshot_dir=args.snapshot_dir,
                      clock_offset_ms=args.clock_offset_ms, clock_drift_ppm=args.clock_drift_ppm,
                      protocol_version=args.protocol_version, tls_ca=tls_ca, tls_server_name=args.tls_server_name,
                      ping_hz=args.ping_hz, ping_settled_s=args.ping_settled_s, realtime=not args.no_realtime,
                      cache_dir=Path(args.cache_dir) if args.cache_dir else default_cache_dir() / args.slot,
                      cache_max_bytes=args.cache_max,
                      fetch_rate=float(args.fetch_rate) if args.fetch_rate else None,
                      discovery_timeout_s=args.discovery_timeout, refusal_backoff_s=args.refusal_backoff_s)


def log_name(args: argparse.Namespace) -> str:
    """How this node's log lines are tagged (the presenter's too)."""
    return f"node {args.slot}"


def run(args: argparse.Namespace) -> int:
    log = logging.getLogger("node")
    try:
        token = resolve_token(args.token_file)
        tls_ca = Path(args.tls_ca).read_bytes() if args.tls_ca else None
    except (TokenError, OSError) as exc:
        log.error("%s", exc)
        return 2
    problem = display_conflict(parse_output_spec(args.output).kind, os.environ, running_programs())
    if problem:     # said once; the unit does not restart the node for this status
        log.error("%s", problem)
        return DISPLAY_HELD_EXIT
    cfg = node_config(args, token, tls_ca)
    if args.gl:  # the presenter process, which makes the context, inherits the environment
        os.environ[GL_ENV] = args.gl
    if args.decoder:
        os.environ[DECODER_ENV] = args.decoder

    from node.app import Node

    async def main() -> int:
        node = Node(cfg)
        loop = asyncio.get_running_loop()
        for sig, why in ((signal.SIGINT, "interrupted (Ctrl-C)"), (signal.SIGTERM, "stopped (SIGTERM)")):
            loop.add_signal_handler(sig, node.stop, why)
        return await node.run()

    return asyncio.run(main())
