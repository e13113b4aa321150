"""`shadowless room`: run the virtual room as a gRPC service on this machine."""
from __future__ import annotations

import argparse
import asyncio
import signal
import sys
import time
from dataclasses import replace
from pathlib import Path

from protos import cli_types
from sim.errors import SimError
from sim.hand import Hand, HandPath
from sim.photometry import Photometry
from sim.rigs import LAYOUTS, layout_path
from sim.room import Room
from sim.scene import SUBSETS, load_layout, reference_scene, write_layout
from sim.specular import parse_gloss
from sim.observer import parse_point, with_observer
from sim.wire.service import DEFAULT_PORT, NO_SIGNAL, serve

EPILOG = """\
what it serves (one port, 127.0.0.1 by default):
  Room       nodes send what they show:     shadowless node --slot r0c0 --output room://127.0.0.1:50070 ...
             the coordinator captures:      camera room://127.0.0.1:50070 (rig.toml `cameras` or --camera)
  RoomTruth  ground truth for tests and benchmarks (poses, light transport, light drop, hands);
             --no-truth leaves it out. Health and reflection are served too.

examples:
  shadowless room                                   # the paper's 5x5 rig over the table, scaled down
  shadowless room --surface bust --port 50071       # the procedural bust on the table
  shadowless room --surface bust --cameras 3        # ... seen by 3 cameras: room://HOST:PORT?camera=0|1|2
  shadowless room --hand 0,0 --hand-height 200      # a hand 0.2 m above the table centre
  shadowless room --hand 100,50 --hand-height 0 --hand-pose point   # a fingertip touching the table
  shadowless room --hand-path -400,0:400,0 --hand-period 4          # a hand sweeping across
  shadowless room --subset P9D                      # only the dense central 3x3 projectors lit
  shadowless room --write-layout my-room.toml       # dump the reference layout, edit it, then:
  shadowless room --layout my-room.toml
  shadowless room --layout wall-3x1                 # 3 projectors side by side, footprints overlapping by 20 %
  shadowless room --layout bust-walls               # 6 projectors on the walls around the bust, 3 cameras
  shadowless room --gloss table:0.1:0.02 --observer 0,-60,900   # a varnished table, and an eye (the last camera)
                                                    # that sees each lens's highlight: room://HOST:PORT?camera=1
  shadowless room --brightness-spread 0.15 --white-spread 0.15 --hotspot 0.2 --vignetting 0.3
                                                    # units that differ, and uneven light across each image

uneven light (all off by default; the room is then exactly as even as it always was):
  --brightness-spread F  each projector's peak output times a factor uniform in 1 +- F (0.15: +-15 %)
  --white-spread F       each projector's red, green and blue gains, each uniform in 1 +- F (its white point)
  --hotspot F            F more light at each image's centre (0.2: +20 %), a Gaussian bump ...
  --hotspot-width W      ... of sigma W in half-diagonals of the image (default 0.35)
  --vignetting F         F less light in each image's corners (0.3: -30 %), falling as the squared radius
  The spreads are drawn from --seed and each slot's name. A layout's [photometry] section sets the same
  (brightness_spread, white_spread, hotspot, hotspot_width, vignetting); these flags replace its keys.
  A lamp is dimmed or killed while its node keeps running with RoomTruth's SetLamp
  (sim.link.RoomClient.set_lamp(slot, 0.5)).

subsets (paper section 5.2): P1 (one bright unit at the centre), P9D, P9W, P13, P17, P20, P25;
see `python -c "import sim.scene; help(sim.scene)"` for the pictures.
"""


#: a fraction of the native resolution
_scale = cli_types.number(0, 1, lo_open=True)


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Run the virtual room: simulated projectors, camera, table, objects and hands, served over\n"
        "gRPC. Nodes send it the frames they show; the coordinator captures from it as from a camera."
    )
    parser.epilog = EPILOG
    g = parser.add_argument_group("the room")
    g.add_argument("--layout", metavar="FILE|NAME",
                   help="room layout (TOML: any projectors, cameras, surfaces), or a shipped one by name: "
                        f"{', '.join(LAYOUTS)}; default: the paper's 5x5 rig")
    g.add_argument("--surface", default="table", metavar="table|bust|MESH",
                   help="what the reference rig projects on: the table (default), the procedural bust on it, or an OBJ/PLY mesh in mm")
    g.add_argument("--projector-scale", type=_scale, default=0.25, metavar="S",
                   help="projector resolution relative to native 1280x800 (default 0.25: 320x200, fast)")
    g.add_argument("--camera-scale", type=_scale, default=0.25, metavar="S",
                   help="camera resolution relative to native 2592x1944 (default 0.25: 648x486)")
    g.add_argument("--full-resolution", action="store_true", help="native resolutions (same as both scales 1; slow)")
    g.add_argument("--pitch", type=cli_types.number(0, 10000, lo_open=True), default=250.0, metavar="MM", help="spacing of the reference 5x5 array (default 250 mm)")
    g.add_argument("--aperture", type=cli_types.number(0, 1000), default=10.0, metavar="MM", help="projector lens aperture: more is more defocus blur (default 10)")
    g.add_argument("--seed", type=int, default=0, help="unit-to-unit variation and sensor noise (default 0)")
    g.add_argument("--no-noise", action="store_true", help="captures without shot and read noise (still quantised)")
    g.add_argument("--subset", metavar="NAME", help="power only a named subset: P1, P9D, P9W, P13, P17, P20 or P25")
    g.add_argument("--cameras", type=int, choices=(1, 3), default=1,
                   help="cameras of the reference rig: 1 (on the ceiling) or 3 (plus front-left and back-right of the "
                        "bust, cameras 1 and 2: room://HOST:PORT?camera=N); a layout file lists its own (default 1)")
    g.add_argument("--gloss", type=_gloss, action="append", metavar="SURFACE:STRENGTH:ROUGHNESS",
                   help="a glossy coat (Blinn-Phong highlights) on the table or the mesh, e.g. table:0.1:0.02 (strength 0..1, "
                        "roughness 0..1, 0.02 varnish); none by default")
    g.add_argument("--observer", type=_point, metavar="X,Y,Z",
                   help="an eye at X,Y,Z mm looking at the table's centre, served as the last camera (sees the highlights)")
    g.add_argument("--write-layout", metavar="FILE", help="write the room's layout as TOML and exit (a starting point for --layout)")
    u = parser.add_argument_group("uneven light (off by default; see below)")
    u.add_argument("--brightness-spread", type=cli_types.number(0, 0.9), default=None, metavar="F",
                   help="unit-to-unit brightness: each projector's peak times 1 +- F, uniform (0.15 = +-15 %%; default 0)")
    u.add_argument("--white-spread", type=cli_types.number(0, 0.9), default=None, metavar="F",
                   help="unit-to-unit white point: each channel's gain 1 +- F, uniform, per projector (default 0)")
    u.add_argument("--hotspot", type=cli_types.number(0, 4), default=None, metavar="F",
                   help="a hot spot: F more light at the image centre, as a fraction (0.2 = +20 %%; default 0)")
    u.add_argument("--hotspot-width", type=cli_types.number(0.05, 4), default=None, metavar="W",
                   help="the hot spot's sigma in half-diagonals of the image (default 0.35)")
    u.add_argument("--vignetting", type=cli_types.number(0, 0.95), default=None, metavar="F",
                   help="light lost in the image corners beyond the lens's cos fall-off, as a fraction (0.3 = -30 %%; default 0)")
    h = parser.add_argument_group("a hand over the table")
    h.add_argument("--hand", type=cli_types.pair, metavar="X,Y", help="place a hand (palm centre, or fingertip with --hand-pose point) at table mm X,Y")
    h.add_argument("--hand-height", type=cli_types.number(0, 2000), default=200.0, metavar="MM", help="height of the hand's lowest point (default 200; 0 touches)")
    h.add_argument("--hand-pose", choices=["flat", "point"], default="flat", help="flat (the default): palm parallel to the table; point: index finger down")
    h.add_argument("--hand-yaw", type=cli_types.number(-360, 360), default=0.0, metavar="DEG", help="direction the fingers point, counter-clockwise from +y (default 0)")
    h.add_argument("--hand-path", type=cli_types.points_path, metavar="X0,Y0:X1,Y1[:...]", help="move the hand along these points and back, repeatedly")
    h.add_argument("--hand-period", type=cli_types.number(0, 3600, lo_open=True), default=4.0, metavar="S", help="seconds for one round trip of --hand-path (default 4)")
    n = parser.add_argument_group("network")
    n.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: this machine only)")
    n.add_argument("--port", type=cli_types.int_range(0, 65535), default=None, help="port (default 50070; 0 picks a free one, printed at start)")
    n.add_argument("--no-truth", action="store_true", help="do not serve the RoomTruth service")
    n.add_argument("--no-signal", choices=NO_SIGNAL, default="keep",
                   help="what a projector shows once no stream feeds it (its node died or stopped): keep its last frame "
                        "(default) or black, as a real projector that lost its source (its black level stays)")


def _gloss(text: str):
    try:
        return parse_gloss(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _point(text: str):
    try:
        return parse_point(text, what="observer")
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def photometry_args(args: argparse.Namespace) -> dict:
    """The uneven-light flags given (name -> value), for :class:`sim.photometry.Photometry`."""
    names = ("brightness_spread", "white_spread", "hotspot", "hotspot_width", "vignetting")
    return {n: getattr(args, n) for n in names if getattr(args, n, None) is not None}


def layout_file(text: str) -> Path:
    """The layout file ``--layout`` names: a path, or a shipped layout's name when no such file exists."""
    path = Path(text)
    if not path.exists() and text in LAYOUTS:
        return layout_path(text)
    return path


def build_room(args: argparse.Namespace):
    """The Room the arguments describe (shared with the demo wiring)."""
    ps, cs = (1.0, 1.0) if args.full_resolution else (args.projector_scale, args.camera_scale)
    light = photometry_args(args)
    if args.layout:
        scene = load_layout(layout_file(args.layout), projector_scale=ps, camera_scale=cs, seed=args.seed, photometry=light)
    else:
        scene = reference_scene(ps, cs, args.surface, args.seed, pitch=args.pitch, aperture=args.aperture,
                                cameras=args.cameras, photometry=Photometry(**light) if light else None)
    if getattr(args, "gloss", None):
        scene = replace(scene, gloss=tuple(args.gloss))
    if getattr(args, "observer", None):
        scene = with_observer(scene, args.observer)
    room = Room(scene, seed=args.seed, noise=not args.no_noise)
    if args.subset:
        if args.subset not in SUBSETS:
            raise SimError(f"unknown subset {args.subset!r}; choose one of {', '.join(SUBSETS)}")
        room.set_active(SUBSETS[args.subset])
    template = Hand(height=args.hand_height, pose=args.hand_pose, yaw_deg=args.hand_yaw)
    if args.hand_path:
        pts = args.hand_path + args.hand_path[-2::-1]  # there and back
        dt = args.hand_period / (len(pts) - 1)
        keys = tuple((i * dt, x, y, args.hand_height) for i, (x, y) in enumerate(pts))
        room.set_occluders(HandPath(keys, loop=True, template=template))
    elif args.hand:
        room.set_occluders([Hand(position=args.hand, height=args.hand_height, pose=args.hand_pose, yaw_deg=args.hand_yaw)])
    return room


def run(args: argparse.Namespace) -> int:
    try:
        room = build_room(args)
        if args.write_layout:
            write_layout(room.scene, args.write_layout)
            print(f"wrote {args.write_layout}")
            return 0
        t0 = time.monotonic()
        for camera in range(len(room.scene.cameras)):
            room.prepare(camera)
        prep = time.monotonic() - t0
    except (SimError, OSError) as exc:
        print(f"shadowless room: {exc}", file=sys.stderr)
        return 2
    port = DEFAULT_PORT if args.port is None else args.port

    def ready(server) -> None:
        scene = room.scene
        w, h = room.projector_size(room.slots[0])
        W, H = room.camera_size(0)
        print(
            f"room: listening on {server.address} — {len(room.slots)} projectors {w}x{h}, "
            f"{len(scene.cameras)} camera(s) {W}x{H}, powered {len(room.active)}, prepared in {prep:.1f} s"
            + ("" if args.no_truth else "; RoomTruth on"),
            flush=True,
        )

    async def main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                loop.add_signal_handler(sig, stop.set)
            except (NotImplementedError, RuntimeError):  # pragma: no cover - non-main thread / platform
                pass
        await serve(room, host=args.host, port=port, truth=not args.no_truth, on_ready=ready, stop=stop, no_signal=args.no_signal)

    try:
        asyncio.run(main())
    except SimError as exc:
        print(f"shadowless room: {exc}", file=sys.stderr)
        return 2
    print("room: stopped", flush=True)
    return 0
