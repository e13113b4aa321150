"""`shadowless bench compensation_cluster`: a video compensated on a Dask cluster of 1 and of 2
workers against the same segments solved here, through the coordinator's ``compensate_video``
job in the virtual room.

One calibrated room rig (4 projectors) with a measured ``L``; a generated H.264 video (a picture
panning, a keyframe every 12 frames) added as an asset. Then, in one run so the ratios compare
like with like, ``compensate_video --segment-frames N`` on this machine (the reference) and
``--cluster`` on a local Dask cluster (worker processes on 127.0.0.1, one thread each) of 1 and
of 2 workers, the order interleaved over ``--repeats``. Reported per mode: wall seconds per frame
(the job's whole run: connecting, sending ``L`` and the source, solving, joining, storing), the
solve time per frame the workers measured, and whether the asset's bytes are the reference's
(else the largest difference in 16-bit codes and the share of samples that differ). The
speed-ups are the reference's seconds per frame over each cluster's, and 2 workers over 1.

This machine has 2 cores, shared: 2 workers cannot beat 2 cores, and the single-machine run
already spreads its sparse products over 2 threads, so the speed-up per worker measured here is
a floor, not what a cluster of machines gives (there each worker brings its own cores and memory
bandwidth).
"""
from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import sys
import time
from fractions import Fraction
from pathlib import Path

import numpy as np

from bench.calibration import make_rig, table_points_from_truth
from bench.compensation_room import demo_image, points_doc
from bench.machine import machine
from bench.workdir import run_dir
from protos import cli_types

RATE = Fraction(24, 1)
SLOTS = ["r1c1", "r1c3", "r3c1", "r3c3"]


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "compensate_video on a local Dask cluster of 1 and 2 worker processes against the same segments solved\n"
        "on this machine (--segment-frames): seconds per frame, speed-ups, and whether the bytes are the same.\n"
        "One JSON document on stdout; progress on stderr."
    )
    parser.epilog = ("examples:\n"
                     "  shadowless bench compensation_cluster                 # 96 frames, segments of 24\n"
                     "  shadowless bench compensation_cluster --frames 48 --repeats 1   # quicker\n")
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("--frames", type=cli_types.int_range(2, 100_000), default=96, help="frames of the video (default 96)")
    parser.add_argument("--segment-frames", type=cli_types.int_range(1), default=24,
                        help="frames per segment (default 24: 4 segments of 96 frames)")
    parser.add_argument("--content-size", type=cli_types.size, default="320x160", metavar="WxH",
                        help="rig content size (default 320x160)")
    parser.add_argument("--iterations", type=cli_types.int_range(1), default=4, help="APG iterations per frame")
    parser.add_argument("--first-iterations", type=cli_types.int_range(1), default=60,
                        help="APG iterations of a segment's first frame")
    parser.add_argument("--repeats", type=cli_types.int_range(1), default=2, help="runs of each mode, interleaved")
    parser.add_argument("--worker-malloc-trim", type=cli_types.int_range(0), default=None, metavar="BYTES",
                        help="MALLOC_TRIM_THRESHOLD_ of the worker processes (default: Dask's, 65536, which returns "
                             "every freed block over 64 KiB to the system: the solver's temporaries then page-fault "
                             "anew each iteration; e.g. 1000000000 keeps them)")
    parser.add_argument("--keep", default=None, metavar="DIR", help="keep the rig directory under DIR")


def _log(msg: str) -> None:
    print(f"[bench compensation_cluster] {msg}", file=sys.stderr, flush=True)


def _video(path: Path, frames: int, size: tuple[int, int]) -> None:
    """A picture panning one pixel in three per frame, H.264 (MPEG-4 without libx264), keyframe every 12."""
    import av

    w, h = size
    wide = demo_image((w + 3 * frames, h))
    codec = "libx264" if "libx264" in av.codecs_available else "mpeg4"
    with av.open(str(path), "w") as c:
        s = c.add_stream(codec, rate=RATE)
        s.width, s.height, s.pix_fmt = w, h, "yuv420p"
        s.options = {"g": "12"}
        for k in range(frames):
            f = np.ascontiguousarray(wide[:, 3 * k:3 * k + w])
            for pkt in s.encode(av.VideoFrame.from_ndarray(f, format="rgb24")):
                c.mux(pkt)
        for pkt in s.encode():
            c.mux(pkt)


def _frames(store, name: str):
    """An asset's frames one at a time, each (H, W, C) uint16 (a whole video never sits in memory: at
    ``--frames 100000`` it would be tens of GB)."""
    import av

    m = store.get(name)
    with av.open(str(store.blob_path(m.blobs[0].sha256))) as c:
        for f in c.decode(c.streams.video[0]):
            yield f.to_ndarray(format="rgb48le")


def _compare(store, name: str, reference: str) -> dict:
    """How far ``name``'s frames are from ``reference``'s, compared one frame at a time."""
    if store.get(name).blobs[0].sha256 == store.get(reference).blobs[0].sha256:
        return {"identical_bytes": True, "max_code_diff": 0, "differing_samples": 0.0}
    worst, differing, samples, done = 0, 0, 0, 0
    end = object()
    a_frames, b_frames = _frames(store, name), _frames(store, reference)
    try:
        while True:
            a, b = next(a_frames, end), next(b_frames, end)
            if a is end or b is end:
                if a is not b:   # one video is longer: count both
                    more_a = (a is not end) + sum(1 for _ in a_frames)
                    more_b = (b is not end) + sum(1 for _ in b_frames)
                    return {"identical_bytes": False, "frames": [done + more_a, done + more_b]}
                break
            if a.shape != b.shape:
                return {"identical_bytes": False, "shapes": [list(a.shape), list(b.shape)]}
            d = np.abs(a.astype(np.int32) - b.astype(np.int32))
            worst, differing, samples = max(worst, int(d.max())), differing + int(np.count_nonzero(d)), samples + d.size
            done += 1
    finally:
        a_frames.close()
        b_frames.close()
    return {"identical_bytes": False, "max_code_diff": worst, "differing_samples": round(differing / max(samples, 1), 6)}


def run(args: argparse.Namespace) -> int:
    try:
        import distributed
    except ImportError:
        raise SystemExit("bench compensation_cluster: needs Dask distributed: pip install 'shadowless[cluster]'")
    from coordinator.assets import AssetStore
    from shadowless.room_driver import RoomDriver
    from sim.room import Room
    from sim.scene import reference_scene

    t0 = time.perf_counter()
    doc: dict = {"benchmark": "compensation_cluster", "machine": machine(),
                 "parameters": {"frames": args.frames, "segment_frames": args.segment_frames,
                                "content_size": list(args.content_size), "iterations": args.iterations,
                                "first_iterations": args.first_iterations, "repeats": args.repeats,
                                "workers_threads": 1, "projectors": len(SLOTS),
                                "worker_malloc_trim": args.worker_malloc_trim}}
    with run_dir(args.keep, "compensation-cluster") as work:
        room = Room(reference_scene(projector_scale=0.25, camera_scale=0.25), seed=0)
        rig = make_rig(work / "rig", room, SLOTS, content_size=tuple(args.content_size))
        driver = RoomDriver(room, rig)
        go = lambda kind, params: asyncio.run(driver.run(kind, params))   # noqa: E731
        go("calibrate", {"mode": "multiplexed", "settle_s": 0.0, "table_points": points_doc(table_points_from_truth(room))})
        tr = go("transport", {"settle_s": 0.0})
        _log(f"rig calibrated, L measured ({tr['nnz']} non-zeros)")
        _video(work / "show.mp4", args.frames, (int(args.content_size[0] * 1.2), int(args.content_size[1] * 1.2)))
        store = AssetStore(rig.path)
        store.add(work / "show.mp4", name="show")
        base = {"asset": "show", "iterations": args.iterations, "first_iterations": args.first_iterations,
                "segment_frames": args.segment_frames, "psnr": False}
        modes: dict[str, dict] = {"here": {"runs": []}, "cluster_1": {"runs": []}, "cluster_2": {"runs": []}}
        import dask

        trim = {} if args.worker_malloc_trim is None else {
            "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": str(args.worker_malloc_trim)}
        with dask.config.set(trim):
            clusters = {n: distributed.LocalCluster(n_workers=n, processes=True, threads_per_worker=1,
                                                    host="127.0.0.1", dashboard_address=None) for n in (1, 2)}
        try:
            for r in range(args.repeats):
                for mode in modes if r % 2 == 0 else reversed(list(modes)):
                    name = f"{mode} {r}"
                    params = {**base, "name": name, "resume": False}
                    if mode != "here":
                        params["cluster"] = clusters[int(mode[-1])].scheduler_address
                    t = time.perf_counter()
                    out = go("compensate_video", params)
                    wall = time.perf_counter() - t
                    modes[mode]["runs"].append({"wall_s": round(wall, 3), "s_per_frame": round(wall / out["frames"], 4),
                                                "solve_ms_per_frame": out["ms_per_frame_mean"], "name": name})
                    _log(f"{name}: {wall / out['frames']:.3f} s/frame")
        finally:
            for c in clusters.values():
                c.close()
        reference = modes["here"]["runs"][0]["name"]
        for mode, m in modes.items():
            m["s_per_frame_median"] = statistics.median(x["s_per_frame"] for x in m["runs"])
            m["matches_here"] = _compare(store, m["runs"][-1]["name"], reference)
            for x in m["runs"]:
                x.pop("name")
    here, one, two = (modes[k]["s_per_frame_median"] for k in ("here", "cluster_1", "cluster_2"))
    doc["modes"] = modes
    doc["speedup"] = {"cluster_1_over_here": round(here / one, 3), "cluster_2_over_here": round(here / two, 3),
                      "cluster_2_over_cluster_1": round(one / two, 3),
                      "note": "2 shared cores bound it: two workers cannot beat two cores, and the run here already "
                              "uses 2 threads for its sparse products"}
    doc["wall_s"] = round(time.perf_counter() - t0, 1)
    print(json.dumps(doc, indent=2))
    return 0
