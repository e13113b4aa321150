"""`shadowless bench image_bombs`: small image files whose headers declare a huge image, handed to
the console's upload decoder as it was before the one decoder (Pillow's size check where Pillow
knows the format, then OpenCV's imdecode) and as it is now (coordinator.image_decode). Each
decode runs in a fresh process; the figures are its peak RSS growth (ru_maxrss after minus
before the call, MiB), its time, and what came of it (refused, or the shape decoded).

Besides each format's small file (a valid 32x24 file with its header patched), a whole Radiance
HDR of the declared size, run-length encoded (6.4 MB at 10000x10000, as in issue 35), shows what
a decoder that trusts the header costs: it really fills the pixels.

Prints one JSON document: per format the file's size and both decoders' figures, the machine and
the parameters. A format whose "before" decode allocates gigabytes needs that much free memory.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

from bench import image_headers
from bench.machine import machine
from bench.workdir import run_dir
from protos import cli_types

# the console's decode_upload before the one decoder (commit d130b7f), as it ran then
BEFORE = '''
import io, warnings
import cv2, numpy as np
from PIL import Image, UnidentifiedImageError
MAX_SIDE, MAX_UPLOAD_PIXELS = 16384, 64 * 2**20
def declared_size(data):
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(io.BytesIO(data)) as im:
                return im.size
    except Image.DecompressionBombError:
        return (MAX_SIDE + 1, MAX_SIDE + 1)
    except (UnidentifiedImageError, OSError, ValueError):
        return None
def decode(data, name):
    size = declared_size(data)
    if size is not None:
        w, h = size
        if not (1 <= w <= MAX_SIDE and 1 <= h <= MAX_SIDE and w * h <= MAX_UPLOAD_PIXELS):
            raise ValueError(f"{name} is {w}x{h} pixels: refused")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{name} is not an image the coordinator can read")
    return img
'''

AFTER = '''
from coordinator.console.actions import decode_upload as decode
'''

MEASURE = '''
import json, resource, sys, time
from pathlib import Path
path = Path(sys.argv[1])
data = path.read_bytes()
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0 = time.perf_counter()
try:
    img = decode(data, path.name)
    outcome = "decoded " + "x".join(map(str, img.shape))
except ValueError as exc:
    outcome = "refused: " + str(exc)[:160]
ms = (time.perf_counter() - t0) * 1e3
grew = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before
print(json.dumps({"rss_growth_mib": round(grew / 1024, 1), "ms": round(ms, 2), "outcome": outcome}))
'''


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--size", type=cli_types.int_range(8193, 16383), default=10000, metavar="SIDE",
                   help="the square size every header declares, 8193..16383 (above 64 Mpx, within WebP's 14 bits; "
                        "default 10000: 100 megapixels)")
    p.add_argument("--formats", default=",".join(image_headers.FORMATS),
                   help=f"comma-separated formats (default all: {','.join(image_headers.FORMATS)})")
    p.add_argument("--no-before", action="store_true", help="measure only the current decoder")
    p.add_argument("--keep", metavar="DIR", help="keep the crafted files in DIR/image_bombs")


def _measure(code: str, path) -> dict:
    r = subprocess.run([sys.executable, "-c", code + MEASURE, str(path)], capture_output=True, text=True, timeout=600)
    if r.returncode != 0:
        return {"error": (r.stderr.strip().splitlines() or [f"exit {r.returncode}"])[-1][:200]}
    return json.loads(r.stdout.strip().splitlines()[-1])


def run(args: argparse.Namespace) -> int:
    formats = [f.strip() for f in str(args.formats).split(",") if f.strip()]
    unknown = [f for f in formats if f not in image_headers.FORMATS]
    if unknown:
        raise SystemExit(f"--formats: unknown {', '.join(unknown)}; choose from {', '.join(image_headers.FORMATS)}")
    t0 = time.monotonic()
    rows = {}
    with run_dir(args.keep, "image_bombs") as work:
        for fmt in formats:
            path = work / f"bomb{image_headers.SUFFIX[fmt]}"
            path.write_bytes(image_headers.huge(fmt, args.size, args.size))
            row = {"file_bytes": path.stat().st_size, "after": _measure(AFTER, path)}
            if not args.no_before:
                row["before"] = _measure(BEFORE, path)
            rows[fmt] = row
        # the file: a whole, run-length-encoded HDR that a blind decoder fills pixel by pixel
        path = work / "bomb-whole.hdr"
        path.write_bytes(image_headers.hdr_whole(args.size, args.size))
        row = {"file_bytes": path.stat().st_size, "after": _measure(AFTER, path)}
        if not args.no_before:
            row["before"] = _measure(BEFORE, path)
        rows["HDR (whole file, RLE)"] = row
    print(json.dumps({"benchmark": "image_bombs", "declared": f"{args.size}x{args.size}",
                      "megapixels": round(args.size ** 2 / 1e6, 1), "formats": rows,
                      "after_max_rss_growth_mib": max((r["after"].get("rss_growth_mib", 0) for r in rows.values()),
                                                      default=0),
                      "wall_s": round(time.monotonic() - t0, 1), "machine": machine(),
                      "parameters": {"size": args.size, "formats": formats, "before": not args.no_before}},
                     indent=2))
    return 0
