"""`shadowless bench crash`: ``kill -9`` trials across every write path a running coordinator serves.

One rig, one real coordinator process. Each trial runs one operator command (a real
``shadowless … --coordinator`` process) that makes the coordinator write, and kills the
coordinator with SIGKILL at a random moment while the command runs (in some trials the command
is killed first and the coordinator a moment later). Then the coordinator is started again on the
same directory and must serve; what the rig holds is then checked against what was acknowledged
(commands that exited 0 before the kill) and for files left over. The write paths:

* ``content_add``: ``content add FILE`` (announce, 1 MiB chunks, hash check, the asset store's
  staging and commit): the upload and asset paths;
* ``slot``: ``configure --slot S --gain G --lut NPY``: the slot file and its LUT;
* ``content``: ``show IMAGE --persist``: the rig's content image and ``current.json``;
* ``show``: ``play ASSET --start-without --no-wait`` or ``show stop``: ``show.json``;
* ``asset_rm``: ``content rm ID``: the manifest, then its blobs;
* ``coverage``: ``coverage --rig-dir DIR`` (a process of its own beside the coordinator, killed
  too): ``coverage.npz``, then ``coverage.json`` and the picture.

Figures: rigs that failed to start (``failed_starts``, must be 0), acknowledged writes lost
(``lost_writes``, must be 0), files left over after the next start (``leftovers``: temp files,
staged files, blobs no manifest names, uploads without a readable announcement, older LUTs and
content images; must be 0) and quarantined files (a crash needs no quarantine: must be 0), the
start-up recovery's log lines, per path; the time per trial. Bounded by ``--trials`` and
``--max-seconds``. Prints one JSON document.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import re
import signal
import subprocess
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.machine import load, machine
from bench.workdir import run_dir
from coordinator.assets import AssetStore
from coordinator.coverage_store import load_coverage, summary_behind
from coordinator.rig import Content, ProjectionPose, Rig, mesh_with_id
from shadowless.local import LocalRig
from sim.scene import reference_scene

PATHS = ("content_add", "slot", "content", "show", "asset_rm", "coverage")
#: commands that write the rig directory themselves, beside the coordinator (no --coordinator)
LOCAL = ("coverage",)
SLOT = "r0c0"
SIZE = (64, 48)                 # content and output size
RECOVERY_LINE = "start-up recovery:"


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--trials", type=int, default=200, help="kill -9 trials, spread over the write paths (default 200)")
    p.add_argument("--paths", default=",".join(PATHS), help=f"write paths to try (default {','.join(PATHS)})")
    p.add_argument("--upload-mib", type=float, default=8.0, help="size of each file content_add uploads (default 8)")
    p.add_argument("--max-seconds", type=float, default=900.0, help="start no trial after this long (default 900)")
    p.add_argument("--seed", type=int, default=1, help="random kill moments and gains (default 1)")
    p.add_argument("--keep", metavar="DIR", help="keep the rig and its logs in DIR/crash")


# ---------------------------------------------------------------- what the rig holds
def leftovers(rig_dir: Path) -> list[str]:
    """Files a settled rig must not hold (independent of coordinator/recovery.py's own reading):
    temp files of atomic writes, files in assets/tmp, blobs no manifest names, manifests that do
    not load or miss blobs, upload folders without a readable announcement, LUTs of older
    revisions, content images current.json does not name; and anything quarantined."""
    out: list[str] = []
    rel = lambda p: str(p.relative_to(rig_dir))  # noqa: E731
    for p in rig_dir.rglob("*"):
        if p.name.startswith(".") and p.name.endswith(".tmp"):
            out.append(rel(p))
    out += [rel(p) for p in (rig_dir / "assets" / "tmp").glob("*")]
    out += [rel(p) for p in (rig_dir / "quarantine").rglob("*") if p.is_file()]
    store = AssetStore(rig_dir)
    named: set[str] = set()
    for p in sorted((rig_dir / "assets" / "manifests").glob("*.json")):
        try:
            m = store.get(p.stem)
        except Exception:           # noqa: BLE001 - any refusal is a leftover
            out.append(rel(p))
            continue
        if store.verify(p.stem):
            out.append(rel(p))
        named.update(b.sha256 for b in m.blobs)
    out += [rel(p) for p in (rig_dir / "assets" / "blobs").rglob("*") if p.is_file() and p.name not in named]
    for d in (rig_dir / "assets" / "uploads").glob("*"):
        try:
            doc = json.loads((d / "spec.json").read_text())
            assert isinstance(doc["files"], list) and (d / "files").is_dir()
        except Exception:           # noqa: BLE001
            out.append(rel(d))
    slots = {}
    for f in (rig_dir / "slots").glob("*.json"):
        slots[f.stem] = json.loads(f.read_text()).get("lut")
    out += [rel(p) for p in (rig_dir / "luts").glob("*.npy") if f"luts/{p.name}" not in slots.values()]
    try:
        current = json.loads((rig_dir / "content" / "current.json").read_text())["file"]
    except FileNotFoundError:
        current = None
    out += [rel(p) for p in (rig_dir / "content").glob("*.npy") if p.name != current]
    if summary_behind(rig_dir) is not None:
        out.append("coverage/coverage.json (not the summary coverage.npz carries)")
    return sorted(set(out))


@dataclass
class Expect:
    """What was acknowledged, and what was in flight when the coordinator died."""

    assets: set[str] = field(default_factory=set)            # added, acknowledged
    removed: set[str] = field(default_factory=set)           # removed, acknowledged
    gain: float | None = None
    content: str | None = None
    show_revision: int = 0
    coverage: bool = False
    inflight: dict = field(default_factory=dict)


def lost_writes(rig_dir: Path, e: Expect) -> list[str]:
    """Acknowledged writes the rig no longer holds (an in-flight write may or may not have landed)."""
    lost = []
    store = AssetStore(rig_dir)
    have = {aid for aid, _ in store.list()}
    lost += [f"asset {a[:12]} added" for a in e.assets - have - e.removed]
    lost += [f"asset {a[:12]} removed" for a in e.removed & have]
    rig = Rig(rig_dir, read_only=True)
    near = lambda a, b: b is not None and abs(a - b) < 1e-6   # noqa: E731 - the wire carries a float32
    if e.gain is not None and not (near(rig.slot(SLOT).gain, e.gain) or near(rig.slot(SLOT).gain, e.inflight.get("gain"))):
        lost.append(f"gain {e.gain} (rig has {rig.slot(SLOT).gain})")
    if e.content is not None and (rig.content is None or rig.content.content_id not in (e.content, e.inflight.get("content"))):
        lost.append(f"content {e.content}")
    try:
        rev = int(json.loads((rig_dir / "show.json").read_text())["revision"])
    except FileNotFoundError:
        rev = 0
    if rev < e.show_revision:
        lost.append(f"show revision {e.show_revision} (show.json has {rev})")
    if e.coverage:
        try:
            load_coverage(rig_dir / "coverage" / "coverage.npz")
        except Exception as exc:    # noqa: BLE001
            lost.append(f"coverage ({exc})")
    return lost


# ---------------------------------------------------------------- the trials
class Trials:
    """A rig and its coordinator process, and the commands that write through it."""

    def __init__(self, work: Path, *, seed: int = 1, upload_bytes: int = 8 << 20):
        self.work = work
        self.rng = random.Random(seed)
        self.np_rng = np.random.default_rng(seed)
        self.upload_bytes = upload_bytes
        self.rig = LocalRig([SLOT], work, output_size=SIZE, content_size=SIZE, mdns=False)
        self.expect = Expect()
        self.counter = 0
        self.durations: dict[str, float] = {}
        self.rows: list[dict] = []
        self.show_asset = ""

    # -- processes
    def start(self) -> None:
        self.rig.create()
        # a 3D pose onto the room's bust, for `coverage` (what 3D calibration would store)
        scene = reference_scene(projector_scale=0.125, camera_scale=0.125, surface="bust")
        m, pin = scene.mesh, scene.projector("r2c2").pinhole
        Rig(self.rig.rig_dir).update_slot(SLOT, pose=ProjectionPose(pin.P, mesh_with_id(m.vertices, m.uvs, m.faces)))
        self.rig.start_coordinator()
        self.rig.wait_ready(60)
        self.show_asset = self._cli(["content", "add", str(self._still("show")), "--name", "show-asset"]).stdout.strip()
        self.expect.assets.add(self.show_asset)

    def close(self) -> None:
        self.rig.close()

    def _argv(self, args: list[str]) -> list[str]:
        if args[0] in LOCAL:
            return [sys.executable, "-m", "shadowless", *args, "--rig-dir", str(self.rig.rig_dir)]
        return [sys.executable, "-m", "shadowless", *args, "--coordinator", self.rig.coordinator_target,
                "--token-file", str(self.rig.rig_dir / "token")]

    def _cli(self, args: list[str]) -> subprocess.CompletedProcess:
        r = subprocess.run(self._argv(args), capture_output=True, text=True, timeout=120, env=self.rig._env())
        if r.returncode != 0:
            raise RuntimeError(f"shadowless {' '.join(args)}: {r.stderr.strip()[-500:]}")
        return r

    def _file(self, stem: str, array: np.ndarray) -> Path:
        self.counter += 1
        p = self.work / "inputs" / f"{stem}-{self.counter}.npy"
        p.parent.mkdir(exist_ok=True)
        np.save(p, array)
        return p

    def _still(self, stem: str, side: int | None = None) -> Path:
        h = w = side or 8
        if side is None:
            h, w = SIZE[1], SIZE[0]
        return self._file(stem, self.np_rng.random((h, w, 3), dtype=np.float32))

    # -- one command per write path: (argv, what it acknowledges when it exits 0)
    def command(self, path: str) -> tuple[list[str], callable]:
        e = self.expect
        if path == "content_add":
            side = max(8, int((self.upload_bytes / 12) ** 0.5))
            f = self._still("upload", side)

            def ack(out: str) -> None:
                e.assets.add(out.strip().splitlines()[-1])
            return ["content", "add", str(f)], ack
        if path == "slot":
            gain = round(self.rng.uniform(0.2, 1.0), 4)
            lut = self._file("lut", np.sort(self.np_rng.random(64, dtype=np.float32)))
            e.inflight["gain"] = gain

            def ack(out: str) -> None:
                e.gain = gain
            return ["configure", "--slot", SLOT, "--gain", str(gain), "--lut", str(lut)], ack
        if path == "content":
            f = self._still("content")
            e.inflight["content"] = Content(np.load(f)).content_id

            def ack(out: str) -> None:
                m = re.search(r"content ([0-9a-f]{24})", out)
                e.content = m[1] if m else e.inflight["content"]
            return ["show", str(f), "--persist"], ack
        if path == "show":
            args = (["play", self.show_asset, "--start-without", "--no-wait"] if self.rng.random() < 0.6
                    else ["show", "stop"])

            def ack(out: str) -> None:
                m = re.search(r"revision (\d+)", out)
                if m:
                    e.show_revision = max(e.show_revision, int(m[1]))
            return args, ack
        if path == "asset_rm":
            aid = self._cli(["content", "add", str(self._still("doomed", 8))]).stdout.strip()

            def ack(out: str) -> None:
                e.removed.add(aid)
            return ["content", "rm", aid], ack
        if path == "coverage":
            def ack(out: str) -> None:
                e.coverage = True
            return ["coverage", "--texture", "64x64", "--view", "0,20", "--panel", "80x80", "--json"], ack
        raise ValueError(f"unknown write path {path!r} (paths: {', '.join(PATHS)})")

    def duration(self, path: str) -> float:
        """How long the path's command takes without a kill (measured once)."""
        if path not in self.durations:
            argv, ack = self.command(path)
            t0 = time.monotonic()
            ack(self._cli(argv).stdout)
            self.durations[path] = time.monotonic() - t0
        return self.durations[path]

    def startup(self) -> float:
        """How long a command takes to start, connect and make one call (``content list``; measured once)."""
        if "startup" not in self.durations:
            t0 = time.monotonic()
            self._cli(["content", "list"])
            self.durations["startup"] = time.monotonic() - t0
        return self.durations["startup"]

    def _landed(self) -> None:
        """An unacknowledged write that landed before the kill is what later trials must find."""
        e, d = self.expect, self.rig.rig_dir
        rig = Rig(d, read_only=True)
        if e.inflight.get("gain") is not None and abs(rig.slot(SLOT).gain - e.inflight["gain"]) < 1e-6:
            e.gain = e.inflight["gain"]
        if rig.content is not None and rig.content.content_id == e.inflight.get("content"):
            e.content = e.inflight["content"]
        try:
            e.show_revision = max(e.show_revision, int(json.loads((d / "show.json").read_text())["revision"]))
        except FileNotFoundError:
            pass

    def _snapshot(self) -> tuple:
        """Names, sizes and mtimes of the folders the write paths touch (a write shows here first)."""
        d = self.rig.rig_dir
        out = []
        for sub in (d, d / "slots", d / "luts", d / "content", d / "coverage", d / "assets" / "tmp", d / "assets" / "manifests",
                    d / "assets" / "uploads", *(d / "assets" / "uploads").glob("*/files")):
            try:
                with os.scandir(sub) as it:
                    for e in it:
                        st = e.stat(follow_symlinks=False)
                        out.append((e.path, st.st_size, st.st_mtime_ns))
            except OSError:
                pass
        return tuple(sorted(out))

    def _wait_for_write(self, proc: subprocess.Popen, timeout: float) -> bool:
        """Poll (every 2 ms) until the rig directory changes; False when ``proc`` ended or time ran out."""
        before = self._snapshot()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and proc.poll() is None:
            if self._snapshot() != before:
                return True
            time.sleep(0.002)
        return False

    def trial(self, path: str) -> dict:
        span, ready = self.duration(path), self.startup()
        argv, ack = self.command(path)
        client_first = self.rng.random() < 0.3 or argv[0] in LOCAL
        on_write = self.rng.random() < 0.5
        # half the kills come a random 0-50 ms after the coordinator's first write of the command (the
        # moments a crash leaves partial state); the others at a random moment of the command's run
        delay = self.rng.uniform(0.0, 0.05) if on_write else self.rng.uniform(min(0.8 * ready, span), 1.05 * span)
        t0 = time.monotonic()
        proc = subprocess.Popen(self._argv(argv), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env=self.rig._env(), start_new_session=True)
        try:
            if on_write:
                self._wait_for_write(proc, 60.0)
            try:
                proc.wait(timeout=delay)
            except subprocess.TimeoutExpired:
                pass
            if (client_first or argv[0] in LOCAL) and proc.poll() is None:   # a local writer dies with the host
                proc.send_signal(signal.SIGKILL)
                time.sleep(self.rng.uniform(0.0, 0.3))
            coord = self.rig.coordinator
            coord.send_signal(signal.SIGKILL)
            coord.wait(30)
            killed_at = time.monotonic() - t0
            try:
                proc.wait(timeout=30)          # the command fails by itself once its coordinator is gone
            except subprocess.TimeoutExpired:
                proc.send_signal(signal.SIGKILL)
                proc.wait(10)
            out, _ = proc.communicate()
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGKILL)
                proc.wait(10)
        acked = proc.returncode == 0
        if acked:
            ack(out)
        log_before = len(self.rig.log("coordinator"))
        self.rig.start_coordinator()
        started = True
        try:
            self.rig.wait_ready(60)
        except Exception:            # noqa: BLE001 - counted; the bench stops after a failed start
            started = False
        new_log = self.rig.log("coordinator")[log_before:]
        row = {"path": path, "killed_at_s": round(killed_at, 3), "on_write": on_write, "client_first": client_first,
               "acknowledged": acked,
               "started": started, "recovery_lines": new_log.count(RECOVERY_LINE),
               "tracebacks": new_log.count("Traceback")}
        if started:
            row["lost"] = lost_writes(self.rig.rig_dir, self.expect)
            row["leftovers"] = leftovers(self.rig.rig_dir)
            self._landed()
        else:
            row["log_tail"] = new_log[-1500:]
        self.expect.inflight.clear()
        self.rows.append(row)
        return row


def summarize(rows: list[dict]) -> dict:
    """Counts per write path; a leftover file or a lost write counts once, in the trial it first appears."""
    per: dict[str, Counter] = {}
    seen_left: set[str] = set()
    seen_lost: set[str] = set()
    for r in rows:
        c = per.setdefault(r["path"], Counter())
        c["trials"] += 1
        c["acknowledged"] += r["acknowledged"]
        c["killed_mid_write"] += not r["acknowledged"]
        c["failed_starts"] += not r["started"]
        new_lost = set(r.get("lost", [])) - seen_lost
        new_left = set(r.get("leftovers", [])) - seen_left
        seen_lost |= new_lost
        seen_left |= new_left
        c["lost_writes"] += len(new_lost)
        c["leftovers"] += len(new_left)
        c["recovery_lines"] += r["recovery_lines"]
        c["tracebacks"] += r["tracebacks"]
    total = Counter()
    for c in per.values():
        total.update(c)
    return {"total": dict(total), "per_path": {k: dict(v) for k, v in per.items()}}


def run_trials(work: Path, trials: int, *, paths: tuple[str, ...] = PATHS, seed: int = 1, upload_bytes: int = 8 << 20,
               max_seconds: float = 900.0) -> tuple[list[dict], dict]:
    """Run up to ``trials`` kill -9 trials round-robin over ``paths`` in ``work``; (rows, timings)."""
    t = Trials(work, seed=seed, upload_bytes=upload_bytes)
    t0 = time.monotonic()
    try:
        t.start()
        for i in range(trials):
            if time.monotonic() - t0 > max_seconds:
                break
            row = t.trial(paths[i % len(paths)])
            if not row["started"]:
                break
    finally:
        t.close()
    return t.rows, {"seconds": round(time.monotonic() - t0, 1), "command_seconds": {k: round(v, 3) for k, v in t.durations.items()}}


def run(args: argparse.Namespace) -> int:
    paths = tuple(p.strip() for p in args.paths.split(",") if p.strip())
    unknown = [p for p in paths if p not in PATHS]
    if unknown or not paths:
        raise SystemExit(f"bench crash: unknown write path(s) {', '.join(unknown) or '(none)'}; paths: {', '.join(PATHS)}")
    if args.trials < 1:
        raise SystemExit("bench crash: --trials must be at least 1")
    with run_dir(args.keep, "crash") as work:
        rows, timing = run_trials(work, args.trials, paths=paths, seed=args.seed,
                                  upload_bytes=int(args.upload_mib * (1 << 20)), max_seconds=args.max_seconds)
    s = summarize(rows)
    doc = {
        "benchmark": "crash",
        "figures": {
            "trials": len(rows),
            "failed_starts": s["total"].get("failed_starts", 0),
            "lost_writes": s["total"].get("lost_writes", 0),
            "leftovers": s["total"].get("leftovers", 0),
            "tracebacks": s["total"].get("tracebacks", 0),
            "recovery_lines": s["total"].get("recovery_lines", 0),
            "seconds": timing["seconds"],
            "seconds_per_trial": round(timing["seconds"] / max(1, len(rows)), 2),
            "per_path": s["per_path"],
            "command_seconds": timing["command_seconds"],
            "problems": [r for r in rows if not r["started"] or r.get("lost") or r.get("leftovers") or r["tracebacks"]][:10],
        },
        "machine": {**machine(), "load": load()},
        "parameters": {"trials": args.trials, "paths": list(paths), "upload_mib": args.upload_mib, "seed": args.seed,
                       "max_seconds": args.max_seconds},
    }
    print(json.dumps(doc, indent=2))
    return 0
