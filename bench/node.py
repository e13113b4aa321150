"""`shadowless bench node`: what a node costs its edge computer, on the default OpenGL context and
on the OpenGL 3.1 a Raspberry Pi's V3D offers, side by side.

Each profile runs in a process of its own (Mesa reads its version override when a process makes
its first context), as a node's presenter does: a renderer of the output size on a headless
context, a homography pose, the inverse-response LUT and a gain, and per frame a new content
image uploaded and rendered, then waited for (``finish``: the GPU's work counts, as before a
swap). Printed: upload and render time per frame (p50/p99), CPU per frame, resident memory
(peak), and the installed size of the node's dependencies (``shadowless[node]``), which must not
include SciPy, OpenCV or scikit-image.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from importlib import metadata

import numpy as np

from bench.machine import machine
from protos import cli_types

GL31_ENV = {"MESA_GL_VERSION_OVERRIDE": "3.1", "MESA_GLSL_VERSION_OVERRIDE": "140", "GLCONTEXT_GLVERSION": "310"}
FORBIDDEN = ("scipy", "opencv-python", "opencv-contrib-python", "opencv-contrib-python-headless",
             "opencv-python-headless", "scikit-image")


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--size", type=cli_types.size, default="1920x1080", metavar="WxH", help="output size (default 1920x1080)")
    p.add_argument("--content", type=cli_types.size, default="1920x1080", metavar="WxH",
                   help="content size (default 1920x1080)")
    p.add_argument("--frames", type=cli_types.int_range(2, 100_000), default=120,
                   help="frames per profile (default 120)")
    p.add_argument("--dtype", choices=["uint8", "uint16", "float32"], default="uint8", help="content samples")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)


def _rss_mb(field: str = "VmRSS") -> float:
    """This process's resident memory (``VmRSS``) or its peak (``VmHWM``), MB."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024
    return float("nan")


def _worker(args: argparse.Namespace) -> dict:
    """One profile, in this process: the figures as a dict."""
    rss_start = _rss_mb()
    from node.render import Renderer

    w, h = args.size
    cw, ch = args.content
    r = Renderer.standalone(w, h)
    rss_context = _rss_mb()
    try:
        scale = min(w / cw, h / ch)
        r.set_homography(np.array([[scale, 0.02, 3.0], [-0.01, scale, 2.0], [1e-6, 2e-6, 1.0]]), (cw, ch))
        r.set_lut(np.stack([np.linspace(0, 1, 256) ** (1 / g) for g in (2.1, 2.2, 2.3)]).astype(np.float32))
        r.set_gain(0.9)
        rng = np.random.default_rng(0)
        if args.dtype == "float32":
            images = [rng.random((ch, cw, 3), dtype=np.float32) for _ in range(4)]
        else:
            top = 255 if args.dtype == "uint8" else 65535
            images = [rng.integers(0, top + 1, (ch, cw, 3), dtype=args.dtype) for _ in range(4)]
        rss_before = _rss_mb()
        upload, render, cpu = [], [], []
        for i in range(args.frames + 2):                     # two warm-up frames, not counted
            c0 = time.process_time()
            t0 = time.perf_counter()
            r.upload(f"f{i}", images[i % len(images)])
            t1 = time.perf_counter()
            r.render(f"f{i}")
            r.ctx.finish()
            t2 = time.perf_counter()
            r.forget(f"f{i}")
            if i >= 2:
                upload.append((t1 - t0) * 1e3)
                render.append((t2 - t1) * 1e3)
                cpu.append((time.process_time() - c0) * 1e3)
        image = r.read()
        pct = lambda a, q: round(float(np.percentile(a, q)), 3)  # noqa: E731
        return {"gl": r.gl_profile, "context_version": r.ctx.version_code,
                "upload_ms_p50": pct(upload, 50), "upload_ms_p99": pct(upload, 99),
                "render_ms_p50": pct(render, 50), "render_ms_p99": pct(render, 99),
                "cpu_ms_per_frame_p50": pct(cpu, 50), "rss_mb": round(_rss_mb(), 1),
                "rss_interpreter_mb": round(rss_start, 1), "rss_context_mb": round(rss_context - rss_start, 1),
                "rss_content_mb": round(sum(i.nbytes for i in images) / 2**20, 1),
                "rss_gl_growth_mb": round(_rss_mb() - rss_before, 1), "peak_rss_mb": round(_rss_mb("VmHWM"), 1),
                # a node holds the frame it shows, not the bench's rotating set of content images
                "node_rss_mb": round(_rss_mb() - sum(i.nbytes for i in images[1:]) / 2**20, 1),
                "renderer": str(r.ctx.info.get("GL_RENDERER", "")),
                "frame_mean_level": round(float(image.mean()), 2)}
    finally:
        r.release()


def node_install() -> dict:
    """The distributions ``shadowless[node]`` pulls in (from this environment's metadata) and
    their installed size."""
    seen: dict[str, int] = {}
    todo = [("shadowless", {"node"})]
    while todo:
        name, extras = todo.pop()
        key = re.sub(r"[-_.]+", "-", name).lower()
        try:
            dist = metadata.distribution(name)
        except metadata.PackageNotFoundError:
            seen.setdefault(key, -1)
            continue
        if key not in seen:
            seen[key] = sum((f.size or 0) for f in (dist.files or ()))
        for req in dist.requires or ():
            m = re.match(r"([A-Za-z0-9_.-]+)(\[[^\]]*\])?", req)
            marker = req.split(";", 1)[1] if ";" in req else ""
            wanted = not marker or any(f'extra == "{e}"' in marker for e in extras)
            if "extra ==" not in marker and marker:
                wanted = True     # platform markers: count it, as an edge install on Linux would
            if m and wanted:
                dep = re.sub(r"[-_.]+", "-", m.group(1)).lower()
                if dep not in seen and dep != "shadowless":
                    todo.append((m.group(1), set()))
    sizes = {k: v for k, v in sorted(seen.items(), key=lambda kv: -kv[1]) if k != "shadowless"}
    return {"distributions": {k: round(v / 2**20, 2) for k, v in sizes.items()},
            "total_mb": round(sum(v for v in sizes.values() if v > 0) / 2**20, 1),
            "forbidden_present": sorted(k for k in sizes if k in FORBIDDEN)}


def run(args: argparse.Namespace) -> int:
    if args.worker:
        print(json.dumps(_worker(args)))
        return 0
    profiles = {}
    for name, env in (("default", {}), ("gl31", GL31_ENV)):
        # the worker imports what a node's presenter imports, and nothing of the CLI's other commands
        cmd = [sys.executable, "-m", "bench.node", "--worker", "--size", "x".join(map(str, args.size)),
               "--content", "x".join(map(str, args.content)), "--frames", str(args.frames), "--dtype", args.dtype]
        done = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, **env}, timeout=1800)
        if done.returncode != 0:
            print(f"bench node: the {name} profile failed:\n{done.stderr[-3000:]}", file=sys.stderr)
            return 1
        profiles[name] = json.loads(done.stdout.strip().splitlines()[-1])
    d, g = profiles["default"], profiles["gl31"]
    print(json.dumps({
        "benchmark": "node", "machine": machine(),
        "params": {"size": list(args.size), "content": list(args.content), "frames": args.frames, "dtype": args.dtype},
        "profiles": profiles,
        "gl31_vs_default_render_p50": round(g["render_ms_p50"] / d["render_ms_p50"], 3) if d["render_ms_p50"] else None,
        "same_picture": d["frame_mean_level"] == g["frame_mean_level"],
        "node_install": node_install(),
    }, indent=2))
    return 0


if __name__ == "__main__":   # the worker (see run): a process as lean as a node's presenter
    _parser = argparse.ArgumentParser(prog="bench.node")
    configure(_parser)
    sys.exit(run(_parser.parse_args()))
