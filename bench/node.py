"""`shadowless bench node`: what a node costs its edge computer, side by side on the default
desktop OpenGL context, on the OpenGL 3.1 a Raspberry Pi's V3D offers, on OpenGL ES 3 (what Mali
and Adreno drivers offer; the node falls back to it where desktop GL 3.1+ is not offered), and on
a bare OpenGL ES 3.0 without 16-bit normalised textures (16-bit content goes up as float32 there).

Each profile runs in processes of its own (Mesa reads its overrides when a process makes its
first context), as a node's presenter does, in ``--rounds`` rounds that take the profiles in turn
(a 2-core machine shared with other work drifts over a minute; interleaving spreads the drift
over every profile alike), the per-frame times pooled over the rounds: a renderer of the output size on a headless
context, a homography pose, the inverse-response LUT and a gain, and per frame a new content
image uploaded and rendered, then waited for (``finish``: the GPU's work counts, as before a
swap). Printed: upload and render time per frame (p50/p99), CPU per frame, resident memory
(peak), and the installed size of the node's dependencies (``shadowless[node]``), which must not
include SciPy, OpenCV or scikit-image.

What a blend costs (``blend``): each worker then renders as many frames again, in blocks of
``BLEND_BLOCK`` that take turns without and with blend maps of a quarter of the output's resolution
(one RGBA32F texture sampled by the texture unit's bilinear filter, RGBA16F where float32 cannot be
filtered; the node's dithered pipeline). Each block with maps is compared with the
blocks without on either side, so a shared machine's changing load moves both alike; the median of
these ratios over the rounds is ``blend.render_ratio`` (target <= 1.05 at 1080p; the ratio of the
pooled medians, ``median_ratio``, mixes busy and quiet moments). The resident memory grown by the
blended shader's first draw (the driver compiles its variant: ``rss_shader_variant_mb``) and by
decoding, uploading and rendering with the maps (``rss_maps_mb``) is ``blend.rss_delta_mb``
(target <= 10 MB). The top-level figures are the default profile's; each profile's are under
``blend.profiles``.

``--variants`` (:mod:`bench.node_variants`) measures instead llvmpipe's CPU per frame for each
shader variant the node draws (RGB, grey, planar YUV, NV12, with fades, blend maps, without the
LUT), at 640x360 and at ``--size``; ``--against COMMIT`` runs that commit's renderer in turn with
this one's and gives their ratio per variant. ``--ablate`` (:mod:`bench.node_ablation`): llvmpipe's
CPU per output pixel of the warp with one piece of its shader taken out at a time, what a pixel's
draw is made of.
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
#: profile name -> environment of its worker (SHADOWLESS_GL picks the API: node/render/context.py)
PROFILES = {
    "default": {"SHADOWLESS_GL": "gl"},
    "gl31": {**GL31_ENV, "SHADOWLESS_GL": "gl"},
    "gles": {"SHADOWLESS_GL": "gles"},
    "gles30_bare": {"SHADOWLESS_GL": "gles", "MESA_GLES_VERSION_OVERRIDE": "3.0",
                    "MESA_EXTENSION_OVERRIDE": "-GL_EXT_texture_norm16 -GL_EXT_color_buffer_float "
                                               "-GL_EXT_color_buffer_half_float -GL_OES_texture_float_linear"},
}
#: frames in a row with, then without, blend maps (the blend figures' interleaving)
BLEND_BLOCK = 4
#: the blend maps' resolution: the output's divided by this (a quarter, as a blend job makes them)
BLEND_SCALE = 4
FORBIDDEN = ("scipy", "opencv-python", "opencv-contrib-python", "opencv-contrib-python-headless",
             "opencv-python-headless", "scikit-image")


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--size", type=cli_types.size, default="1920x1080", metavar="WxH", help="output size (default 1920x1080)")
    p.add_argument("--content", type=cli_types.size, default="1920x1080", metavar="WxH",
                   help="content size (default 1920x1080)")
    p.add_argument("--frames", type=cli_types.int_range(2, 100_000), default=120,
                   help="frames per profile (default 120)")
    p.add_argument("--rounds", type=cli_types.int_range(1, 50),
                   help="the profiles run in turn this many times, the frames split between the rounds (default: "
                        "one round per 40 frames, at most 3)")
    p.add_argument("--dtype", choices=["uint8", "uint16", "float32"], default="uint8", help="content samples")
    p.add_argument("--video", action="store_true",
                   help="instead: the CPU per frame of a 1080p30 H.264 video (made here) through the node's decoder, "
                        "upload and render, the RGB path (swscale) against the YUV path (planes converted in the "
                        "shader), as ratios in one run, split into decode, convert, upload, render, Python and "
                        "the rasterizer's share; then the resident memory of a presenter-like process playing it, "
                        "before and after, split into its parts (bench/node_video.py); --content is the video's size")
    p.add_argument("--video-frames", type=cli_types.int_range(20, 100_000), default=120, metavar="N",
                   help="frames of the --video run (default 120: 4 s at 30 fps; each path decodes them all)")
    p.add_argument("--memory-only", action="store_true",
                   help="with --video: only the memory part (a presenter-like process playing the video, by part and "
                        "by mapping, and a real node's processes), not the CPU per frame: about a minute instead of "
                        "several")
    p.add_argument("--variants", action="store_true",
                   help="instead: llvmpipe's CPU per frame (the GPU's work here) for each shader variant the node "
                        "draws (RGB, grey, planar YUV, NV12; fades, blend maps, no LUT) at 640x360 and at --size "
                        "(bench/node_variants.py)")
    p.add_argument("--ablate", action="store_true",
                   help="instead: llvmpipe's CPU per output pixel of the warp with one piece of the shader taken "
                        "out at a time (the LUT, the content's fetches, the chroma, the YUV matrix...), at 640x360 and at "
                        "--size, to see what a pixel costs (bench/node_ablation.py)")
    p.add_argument("--against", metavar="COMMIT",
                   help="with --variants: the same figures for that commit's renderer, taking turns with this one's "
                        "in one run, and their ratio")
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
    from node.render.shaders import fallbacks

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
        return {"gl": r.gl_profile, "context_version": r.ctx.version_code,
                **_percentiles(upload, render, cpu), "rss_mb": round(_rss_mb(), 1),
                "samples_ms": {"upload": upload, "render": render, "cpu": cpu},
                "rss_interpreter_mb": round(rss_start, 1), "rss_context_mb": round(rss_context - rss_start, 1),
                "rss_content_mb": round(sum(i.nbytes for i in images) / 2**20, 1),
                "rss_gl_growth_mb": round(_rss_mb() - rss_before, 1), "peak_rss_mb": round(_rss_mb("VmHWM"), 1),
                # a node holds the frame it shows in its texture only: the presenter drops the decoded
                # array once uploaded (node/presenter.py), unlike the bench's rotating set of images
                "node_rss_mb": round(_rss_mb() - sum(i.nbytes for i in images) / 2**20, 1),
                "renderer": str(r.ctx.info.get("GL_RENDERER", "")), "fallbacks": list(fallbacks(r.ctx)),
                "frame_mean_level": round(float(image.mean()), 2),
                "blend": _blend_cost(r, images, args.frames)}
    finally:
        r.release()


def _blend_cost(r, images: list[np.ndarray], frames: int) -> dict:
    """Render ``frames`` more frames, in blocks of BLEND_BLOCK without and with blend maps of a
    BLEND_SCALE-th of the output's resolution: the render times with and without (ms, their medians
    and ratio), and the resident memory the maps cost (made, uploaded, rendered with)."""
    from node.render.shaders import has_float_linear
    from protos.blend import BlendMaps

    # the maps as the wire brings them (float16 bytes), made before the count starts
    w, h = max(1, r.width // BLEND_SCALE), max(1, r.height // BLEND_SCALE)
    x = np.linspace(0.0, 1.0, w, dtype=np.float32)
    y = np.linspace(0.0, 1.0, h, dtype=np.float32)[:, None]
    alpha = np.stack([np.clip(1.2 - x + 0 * y, 0, 1), np.clip(1.1 - x + 0 * y, 0, 1), 0.9 - 0.2 * x * y], axis=2)
    wire = BlendMaps(alpha.astype(np.float32), (0.02 + 0.03 * x * y).astype(np.float32)).encode()
    del x, y, alpha
    rss_before = _rss_mb()
    # the blended shader's first draw compiles the driver's variant of it (a node's presenter does
    # that at its start, see node/presenter.py's warm-up): counted apart, and in the total
    r.set_blend(BlendMaps(np.ones((1, 1, 3), np.float32), np.zeros((1, 1), np.float32)))
    r.upload("warm", images[0])
    r.render("warm")
    r.ctx.finish()
    r.forget("warm")
    r.set_blend(None)
    rss_compiled = _rss_mb()
    maps = BlendMaps.decode(w, h, *wire)      # what the node decodes and keeps
    r.set_blend(maps)
    for i in range(2):                                     # its first draws, not counted
        r.upload(f"b{i}", images[i % len(images)])
        r.render(f"b{i}")
        r.ctx.finish()
        r.forget(f"b{i}")
    rss_delta = _rss_mb() - rss_before
    times: dict[bool, list[float]] = {False: [], True: []}
    blocks: list[list[float]] = []                        # block k: with maps when k is odd
    for i in range(max(3 * BLEND_BLOCK, frames)):
        blended = (i // BLEND_BLOCK) % 2 == 1
        if i % BLEND_BLOCK == 0:
            r.set_blend(maps if blended else None)
            blocks.append([])
        r.upload(f"b{i}", images[i % len(images)])
        t0 = time.perf_counter()
        r.render(f"b{i}")
        r.ctx.finish()
        ms = (time.perf_counter() - t0) * 1e3
        times[blended].append(ms)
        blocks[-1].append(ms)
        r.forget(f"b{i}")
    r.set_blend(None)
    # each block with maps against the blocks without on either side: a machine whose load changes
    # within seconds moves both alike, so the pairs' ratios keep the maps' cost where the pooled
    # medians would mix busy and quiet moments
    med = [float(np.median(b)) for b in blocks]
    pairs = [med[k] / float(np.mean([med[j] for j in (k - 1, k + 1) if j < len(med)]))
             for k in range(1, len(med), 2)]
    return {"maps": [w, h], "rss_delta_mb": round(rss_delta, 2),
            "rss_shader_variant_mb": round(rss_compiled - rss_before, 2),
            "rss_maps_mb": round(rss_delta - (rss_compiled - rss_before), 2),
            # what the node holds for the maps by construction (decoded float32 arrays, an RGBA32F texture,
            # RGBA16F where float32 cannot be filtered): the measured growth can be smaller where the heap
            # reuses memory freed before
            "held_mb": round((maps.alpha.nbytes + maps.beta.nbytes
                              + w * h * 4 * (4 if has_float_linear(r.ctx) else 2)) / 2**20, 2),
            "samples_ms": {"without": times[False], "with": times[True]}, "pair_ratios": pairs}


def _blend_ratio(blend: dict, without: list[float], with_maps: list[float], pairs: list[float]) -> dict:
    """A profile's blend figures pooled over the rounds: the render times' medians without and with
    maps (ms) and their ratio, and ``render_ratio``, the median of each block's ratio to its neighbours."""
    plain, blended = float(np.median(without)), float(np.median(with_maps))
    return {**blend, "render_ms_p50_without": round(plain, 3), "render_ms_p50_with": round(blended, 3),
            "median_ratio": round(blended / plain, 3) if plain > 0 else None,
            "render_ratio": round(float(np.median(pairs)), 3), "blocks": len(pairs),
            "frames": len(without) + len(with_maps)}


def _percentiles(upload: list[float], render: list[float], cpu: list[float]) -> dict:
    """p50/p99 of the per-frame upload and render times and the p50 of CPU per frame, ms."""
    pct = lambda a, q: round(float(np.percentile(a, q)), 3)  # noqa: E731
    return {"upload_ms_p50": pct(upload, 50), "upload_ms_p99": pct(upload, 99),
            "render_ms_p50": pct(render, 50), "render_ms_p99": pct(render, 99), "cpu_ms_per_frame_p50": pct(cpu, 50)}


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
    if args.ablate:
        from bench import node_ablation

        sizes = [(640, 360)] + ([tuple(args.size)] if tuple(args.size) != (640, 360) else [])
        res = node_ablation.ablate(sizes, args.rounds or 3, 12)
        print(json.dumps({"benchmark": "node", "machine": machine(), "load": os.getloadavg(), "ablation": res},
                         indent=2))
        print("\n".join(node_ablation.summary(res)), file=sys.stderr)
        return 0
    if args.variants:
        from bench import node_variants

        sizes = [(640, 360)] + ([tuple(args.size)] if tuple(args.size) != (640, 360) else [])
        rounds = args.rounds or 3
        print(f"bench node --variants: {len(node_variants.VARIANTS)} variants at "
              f"{', '.join(f'{w}x{h}' for w, h in sizes)}, {rounds} round{'s' if rounds != 1 else ''} of "
              f"{node_variants.FRAMES} frames each, {args.content[0]}x{args.content[1]} content"
              + (f", against {args.against}" if args.against else ""),
              file=sys.stderr)
        res = node_variants.variants(sizes, rounds, node_variants.FRAMES, args.against, tuple(args.content))
        print(json.dumps({"benchmark": "node", "machine": machine(), "load": os.getloadavg(), "variants": res},
                         indent=2))
        print("\n".join(node_variants.summary(res)), file=sys.stderr)
        return 0
    if args.memory_only and not args.video:
        raise SystemExit("--memory-only goes with --video: it measures the memory of a presenter playing a video")
    if args.video:
        from bench import node_video

        mem = args.memory_only
        clip = f"{args.content[0]}x{args.content[1]} H.264"
        what = (f"the memory of a presenter playing {clip}, and of a node's processes" if mem else
                f"{args.video_frames} frames of {clip}, RGB and YUV paths in turn, then the memory of a presenter "
                "playing it")
        print(f"bench node --video{' --memory-only' if mem else ''}: {what}", file=sys.stderr)
        load = os.getloadavg()
        video = (node_video.memory_only if mem else node_video.timed)(args.size, args.content, args.video_frames)
        print(json.dumps({"benchmark": "node", "machine": machine(), "load": {"start": load, "end": os.getloadavg()},
                          "video": video}, indent=2))
        lines = node_video.memory_summary(video["memory"]) if mem else node_video.summary(video)
        print("\n".join(lines), file=sys.stderr)
        return 0
    profiles: dict[str, dict] = {}
    pooled = {name: {"upload": [], "render": [], "cpu": [], "without": [], "with": [], "pairs": []}
              for name in PROFILES}
    if args.rounds is None:
        args.rounds = min(3, max(1, args.frames // 40))
    per_round = max(2, -(-args.frames // args.rounds))
    for k in range(args.rounds):
        for name, env in PROFILES.items():
            # the worker imports what a node's presenter imports, and nothing of the CLI's other commands
            cmd = [sys.executable, "-m", "bench.node", "--worker", "--size", "x".join(map(str, args.size)),
                   "--content", "x".join(map(str, args.content)), "--frames", str(per_round), "--dtype", args.dtype]
            print(f"bench node: round {k + 1}/{args.rounds}, profile {name}", file=sys.stderr)
            done = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, **env}, timeout=1800)
            if done.returncode != 0:
                print(f"bench node: the {name} profile failed:\n{done.stderr[-3000:]}", file=sys.stderr)
                return 1
            result = json.loads(done.stdout.strip().splitlines()[-1])
            for key, values in result.pop("samples_ms").items():
                pooled[name][key] += values
            for key, values in result["blend"].pop("samples_ms").items():
                pooled[name][key] += values
            pooled[name]["pairs"] += result["blend"].pop("pair_ratios")
            profiles[name] = result   # memory and the picture: the last round's (they do not drift)
    for name, p in profiles.items():
        p.update(_percentiles(pooled[name]["upload"], pooled[name]["render"], pooled[name]["cpu"]))
        p["frames"] = len(pooled[name]["render"])
        p["blend"] = _blend_ratio(p["blend"], pooled[name]["without"], pooled[name]["with"], pooled[name]["pairs"])
    d = profiles["default"]

    def vs_default(name: str, key: str) -> float | None:
        return round(profiles[name][key] / d[key], 3) if d[key] else None

    print(json.dumps({
        "benchmark": "node", "machine": machine(),
        "params": {"size": list(args.size), "content": list(args.content), "frames": args.frames, "rounds": args.rounds,
                   "dtype": args.dtype},
        "profiles": profiles,
        "gl31_vs_default_render_p50": vs_default("gl31", "render_ms_p50"),
        "gles_vs_default_render_p50": vs_default("gles", "render_ms_p50"),
        "gles_vs_default_upload_p50": vs_default("gles", "upload_ms_p50"),
        "gles30_bare_vs_default_upload_p50": vs_default("gles30_bare", "upload_ms_p50"),
        "same_picture": len({p["frame_mean_level"] for p in profiles.values()}) == 1,
        "blend": {"render_ratio": d["blend"]["render_ratio"], "rss_delta_mb": d["blend"]["rss_delta_mb"],
                  "targets": {"render_ratio": 1.05, "rss_delta_mb": 10.0}, "maps": d["blend"]["maps"],
                  "profiles": {name: p["blend"] for name, p in profiles.items()}},
        "node_install": node_install(),
    }, indent=2))
    return 0


if __name__ == "__main__":   # the worker (see run): a process as lean as a node's presenter
    _parser = argparse.ArgumentParser(prog="bench.node")
    configure(_parser)
    sys.exit(run(_parser.parse_args()))
