"""The frame half of deploy/check-arm64.sh: an x86 node and the arm64 node join one coordinator
on this machine, are given the same pose, LUT and gain, show the same still, and their frames are
compared with each other and with an independent reference (OpenCV's warp, NumPy's LUT).

Run by check-arm64.sh with the checkout's Python (``.venv/bin/python``, which has OpenCV) after
the arm64 root holds an installed node; prints one JSON document on stdout and exits 0 if the
frames agree within the tolerances below, 1 if not, 2 if a node never joined or showed the still.

Tolerances (8-bit values, per channel):

* arm64 against x86: both nodes are the same Python and GLSL on the same Mesa release (Debian 12's
  llvmpipe), so the only difference is llvmpipe's code generation for each CPU (8-wide AVX2 against
  4-wide NEON, fused multiply-adds on aarch64): a value that lands near a rounding boundary may round
  the other way. So at most 1 apart on 99.9 % of the values, and a mean difference under 0.05.
* each against the reference: the tolerance of tests/shadowless/test_local_rig.py (99th percentile
  at most 2, mean under 0.3): OpenCV snaps its warp's coordinates to 1/32 pixel and the LUT's slope
  near black amplifies that, while the renderer interpolates in float.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from shadowless.local import LocalRig, card_image  # noqa: E402

SIZE = (320, 180)                 # projector output and content, (w, h)
X86, ARM = "r0c0", "r0c1"
ARM_SNAPSHOTS = "/var/lib/shadowless/snapshots"
GAIN = 0.9
PAIR_P999_MAX, PAIR_MEAN_MAX = 1.0, 0.05
REF_P99_MAX, REF_MEAN_MAX = 2.0, 0.3


def homography() -> np.ndarray:
    """A perspective warp, content px -> projector px, (3, 3) float64."""
    w, h = SIZE
    src = np.float32([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]])
    dst = np.float32([[9, 5], [w - 14, 3], [w - 4, h - 11], [3, h - 6]])
    return cv2.getPerspectiveTransform(src, dst).astype(np.float64)


def lut() -> np.ndarray:
    """An inverse-response LUT per channel, (3, 1024) float32 in [0, 1]."""
    x = np.linspace(0, 1, 1024, dtype=np.float32)
    return np.stack([x ** 0.45, x ** 0.5, x ** 0.41]).astype(np.float32)


def reference(content_u16: np.ndarray) -> np.ndarray:
    """(h, w, 3) uint8: OpenCV's bilinear warp, the gain, NumPy's LUT, 8-bit rounding."""
    f = content_u16.astype(np.float32) / 65535.0
    warped = cv2.warpPerspective(f, homography(), SIZE, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    v = np.clip(warped * GAIN, 0, 1)
    table = lut()
    xs = np.linspace(0, 1, table.shape[1])
    return np.round(np.stack([np.interp(v[..., c], xs, table[c]) for c in range(3)], axis=-1) * 255).astype(np.uint8)


def read_rgb(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise FileNotFoundError(path)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def frame_id(meta: Path) -> int:
    try:
        return int(json.loads(meta.read_text()).get("frame_id", 0))
    except (OSError, ValueError):
        return 0


def differences(a: np.ndarray, b: np.ndarray) -> dict:
    """How far apart two frames are, the 1-pixel border left out (the warp's edge)."""
    d = np.abs(a.astype(int) - b.astype(int))[1:-1, 1:-1]
    return {"max": int(d.max()), "mean": round(float(d.mean()), 4), "p99": float(np.percentile(d, 99)),
            "p99_9": float(np.percentile(d, 99.9)), "values_off_by_more_than_1": int((d > 1).sum()),
            "values": int(d.size)}


def arm_user(root: Path) -> tuple[int, int]:
    for line in (root / "etc/passwd").read_text().splitlines():
        f = line.split(":")
        if f[0] == "shadowless":
            return int(f[2]), int(f[3])
    raise SystemExit("the arm64 root has no shadowless user: did the install run?")


def arm_node(rig: LocalRig, root: Path) -> subprocess.Popen:
    """The installed node in the arm64 root, as the shadowless user, found through the PATH."""
    uid, gid = arm_user(root)
    env = ["PATH=/usr/local/bin:/usr/bin:/bin", "HOME=/var/lib/shadowless", "LP_NUM_THREADS=1",
           "PYTHONUNBUFFERED=1", "LANG=C.UTF-8"]
    argv = ["chroot", f"--userspec={uid}:{gid}", str(root), "/usr/bin/env", "-i", *env,
            "shadowless", "node", "--slot", ARM, "--coordinator", rig.coordinator_target,
            "--token-file", "/etc/shadowless/token", "--output", "offscreen", "--snapshot-dir", ARM_SNAPSHOTS,
            "--cache-dir", f"/var/lib/shadowless/cache/{ARM}", "--no-realtime"]
    log = open(rig.log_dir / f"node-{ARM}.log", "ab")
    rig._logs.append(log)
    return subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)


async def drive(rig: LocalRig, root: Path, timeout: float) -> dict:
    started = time.monotonic()
    async with await rig.client() as c:
        await rig.wait_live(c, timeout=timeout)
        joined_s = time.monotonic() - started
        revisions = {s: await c.configure(s, gain=GAIN, homography=homography(), lut=lut()) for s in (X86, ARM)}
        deadline = time.monotonic() + timeout
        while True:
            got = {n.slot: n.assignment_revision for n in (await c.status()).nodes}
            if all(got.get(s, 0) >= r for s, r in revisions.items()):
                break
            if time.monotonic() > deadline:
                raise TimeoutError(f"the nodes did not apply their pose (revisions {got}, wanted {revisions})")
            await asyncio.sleep(0.5)
        content = card_image(*SIZE)
        shown = await c.show(content, name="check-arm64")
    metas = {X86: rig.snapshot_dir / f"{X86}.json", ARM: root / ARM_SNAPSHOTS.lstrip("/") / f"{ARM}.json"}
    deadline = time.monotonic() + timeout
    while not all(frame_id(m) >= shown.frame_id for m in metas.values()):
        if time.monotonic() > deadline:
            raise TimeoutError(f"no snapshot of frame {shown.frame_id} from both nodes")
        await asyncio.sleep(0.5)
    frames = {s: read_rgb(m.with_suffix(".png")) for s, m in metas.items()}
    want = reference(content)
    pair = differences(frames[ARM], frames[X86])
    refs = {s: differences(frames[s], want) for s in frames}
    ok = (pair["p99_9"] <= PAIR_P999_MAX and pair["mean"] < PAIR_MEAN_MAX
          and all(r["p99"] <= REF_P99_MAX and r["mean"] < REF_MEAN_MAX for r in refs.values()))
    return {"ok": ok, "size": list(SIZE), "arm64_joined_after_s": round(joined_s, 1),
            "arm64_vs_x86": pair, "arm64_vs_reference": refs[ARM], "x86_vs_reference": refs[X86],
            "tolerance": {"arm64_vs_x86": {"p99_9_max": PAIR_P999_MAX, "mean_below": PAIR_MEAN_MAX},
                          "vs_reference": {"p99_max": REF_P99_MAX, "mean_below": REF_MEAN_MAX}},
            "frames": {X86: str(metas[X86].with_suffix(".png")), ARM: str(metas[ARM].with_suffix(".png"))}}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--root", type=Path, required=True, help="the arm64 root holding an installed node")
    p.add_argument("--work", type=Path, required=True, help="the rig directory's parent (its token: WORK/rig/token)")
    p.add_argument("--timeout", type=float, default=900.0, help="seconds to wait for each step (default 900)")
    args = p.parse_args()
    rig = LocalRig([X86, ARM], args.work, output_size=SIZE, content_size=SIZE, snapshots=True, mdns=False,
                   rig_name="check-arm64")
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(3))
    try:
        rig.create()
        rig.start_coordinator()
        rig.start_node(X86)
        rig.nodes[ARM] = arm_node(rig, args.root)     # stopped by rig.close(), by its pid
        result = asyncio.run(drive(rig, args.root, args.timeout))
    except (TimeoutError, RuntimeError) as exc:
        print(json.dumps({"ok": False, "error": str(exc).splitlines()[0],
                          "arm64_log_tail": rig.log(f"node-{ARM}")[-3000:]}, indent=1))
        return 2
    finally:
        rig.close()
    print(json.dumps(result, indent=1))
    return 0 if result["ok"] else 1


if __name__ == "__main__":
    os.umask(0o022)
    sys.exit(main())
