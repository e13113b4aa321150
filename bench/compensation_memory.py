"""What `shadowless bench compensation` will hold in memory, part by part, before it allocates anything.

Each part of the benchmark (the per-N comparison, the paper-size run, each video size, the noise
sweep) runs after the previous one let go of its arrays, so the process's peak is the largest part's.
:func:`plan` estimates every part from its sizes (:mod:`imaging.compensation.memory_estimate`),
drops the per-projector baseline when only it does not fit (the comparison then reports
``"baseline": "skipped: needs ~X GB"``) and refuses, in one line naming the option to change, a
part that does not fit even without it.
"""
from __future__ import annotations

import argparse
import json
from typing import Any

from imaging.compensation.memory_estimate import (
    RUNTIME_BYTES,
    build_bytes,
    operator_bytes,
    solve_bytes,
    transport_bytes,
)
from coordinator.memory_budget import Budget, MemoryBudgetError, available, ensure_fits, fits, gb

__all__ = ["configure", "per_projectors_bytes", "paper_size_bytes", "video_bytes", "sweep_bytes", "plan", "peak_rss_gib",
           "print_plan"]


def configure(parser: argparse.ArgumentParser) -> None:
    """The benchmark's memory options: ``--no-baseline`` and ``--memory-plan``."""
    parser.add_argument("--no-baseline", dest="baseline", action="store_false",
                        help="leave out the per-projector baseline (it holds every projector's L_i: N times ours); "
                             "it is left out by itself, with one line, when it would not fit in memory")
    parser.add_argument("--memory-plan", action="store_true",
                        help="print each part's memory estimate, the budget and whether the baseline runs, then stop")


def print_plan(args: argparse.Namespace, memory: dict[str, Any]) -> bool:
    """With ``--memory-plan``: print the plan as the benchmark's JSON document and say so (the run stops)."""
    if getattr(args, "memory_plan", False):
        baseline = getattr(args, "baseline_skipped", None) or "runs"
        print(json.dumps({"benchmark": "compensation", "memory": {**memory, "baseline": baseline}}, indent=2))
    return bool(getattr(args, "memory_plan", False))


def peak_rss_gib() -> float:
    """This process's peak resident memory (``VmHWM``), GiB: unlike ``ru_maxrss``, which a process started by
    a large parent begins at the parent's size (Linux carries it across exec), it counts this program only."""
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmHWM:")) / 2**20


def _sizes(w: int, h: int, radius: int) -> tuple[int, int, int, int]:
    n = w * h  # the synthetic rig's camera is its content grid
    return n, transport_bytes(n, n, radius), build_bytes(n, n, radius), operator_bytes(n, n, radius, "float32")


def per_projectors_bytes(w: int, h: int, counts: list[int], *, radius: int, channels: int) -> dict[str, int]:
    """Peak bytes of the per-N comparison at ``w x h`` for rig sizes ``counts``: ``ours`` (the rig's ``L``,
    its measurement and operator for every N, held together) and ``baseline`` (what the per-projector
    baseline adds: the units, their scaled and measured copies and one operator each, for the largest N)."""
    n, csr, build, op = _sizes(w, h, radius)
    k, top = len(set(counts)), max(counts)
    vectors = solve_bytes(n, n, channels) + 8 * 4 * channels * n  # the solves, the target, captures and pictures
    # measured: the generation's and the measurement's arrays do not both go back to the system before the
    # solves take theirs (the allocator keeps freed blocks), so both builds count, and the oracle's operator
    ours = RUNTIME_BYTES + k * (2 * csr + op) + 2 * build + op + vectors
    # generated per projector: every unit stays; at the largest N each has a scaled copy, a measured copy and an
    # operator, and the oracle solves one more operator at a time
    baseline = top * csr + top * (2 * csr + op) + op + top * 4 * channels * n
    return {"ours": ours, "baseline": baseline}


def paper_size_bytes(w: int, h: int, *, radius: int, channels: int) -> int:
    """Peak bytes of the paper-size run: ``L`` and, one at a time, the CSR operator (``L^T``) or a stencil copy
    (with the previous one still held for the reference solve), or the generation of ``L`` itself."""
    n, csr, build, op = _sizes(w, h, radius)
    ops = max(operator_bytes(n, n, radius, "csr"), 2 * op)
    return RUNTIME_BYTES + csr + max(build, ops) + 2 * solve_bytes(n, n, channels)


def video_bytes(w: int, h: int, frames: int, *, radius: int) -> int:
    """Peak bytes of one video size: ``L``, both operators (CSR and stencil) and the two clips' frames."""
    n, csr, build, op = _sizes(w, h, radius)
    clips = 4 * n * (3 * frames + 8)  # pan (a wide picture and views), overlay copies, the solves' frames
    return RUNTIME_BYTES + csr + max(build, operator_bytes(n, n, radius, "csr") + op) + clips + 2 * solve_bytes(n, n)


def sweep_bytes(w: int, h: int, *, radius: int, channels: int) -> int:
    """Peak bytes of the camera-noise sweep: 25 exact ``L_i`` and their sum, 25 measured ones and one operator."""
    n, csr, build, op = _sizes(w, h, radius)
    # (26 exact and 26 measured, plus the sums the generation adds up on the way, and two builds as above)
    return RUNTIME_BYTES + 56 * csr + 2 * build + 2 * op + solve_bytes(n, n, channels)


def _refuse(estimate: int, what: str, hint: str, budget: Budget) -> None:
    try:
        ensure_fits(estimate, what=what, hint=hint, budget=budget)
    except MemoryBudgetError as exc:
        raise SystemExit(f"shadowless bench compensation: {exc}") from None


def plan(args: argparse.Namespace, budget: Budget | None = None, log=None) -> dict[str, Any]:
    """Estimate every part the options ask for; drop the baseline (``args.baseline = False``, with one
    line to ``log``) when only it does not fit; ``SystemExit`` with one line for a part that cannot fit.
    Returns the estimates (GB) and the budget, for the benchmark's JSON document."""
    try:
        budget = available() if budget is None else budget
    except MemoryBudgetError as exc:
        raise SystemExit(f"shadowless bench compensation: {exc}") from None
    out: dict[str, Any] = {"available_gib": None if budget.bytes is None else round(budget.bytes / 2**30, 2),
                           "source": budget.source, "estimates_gib": {}}
    est = out["estimates_gib"]
    r, c = args.radius, args.channels
    if args.size:
        w, h = args.size
        counts = sorted(set(args.projectors))
        parts = per_projectors_bytes(w, h, counts, radius=r, channels=c)
        est["per_projectors_ours"] = round(parts["ours"] / 2**30, 3)
        est["per_projectors_baseline"] = round(parts["baseline"] / 2**30, 3)
        _refuse(parts["ours"], f"the rig's transport at {w}x{h} for {','.join(map(str, counts))} projectors",
                "use a smaller --size or fewer --projectors", budget)
        total = parts["ours"] + parts["baseline"]
        if args.baseline and not fits(total, budget):
            args.baseline = False
            args.baseline_skipped = f"skipped: needs ~{gb(total)}, {gb(budget.bytes)} available"
            if log is not None:
                log(f"per-projector baseline at {w}x{h} for {max(counts)} projectors skipped: it needs about "
                    f"{gb(total)}, {gb(budget.bytes)} available ({budget.source}); ours runs alone")
        elif not args.baseline:
            args.baseline_skipped = "skipped: --no-baseline"
    if args.paper_size:
        w, h = args.paper_size
        need = paper_size_bytes(w, h, radius=r, channels=args.paper_channels)
        est["paper_size"] = round(need / 2**30, 3)
        _refuse(need, f"the paper-size run at {w}x{h}", "use a smaller --paper-size or --paper-size none", budget)
    if args.video_frames > 0 and args.video_size:
        for w, h in args.video_size:
            need = video_bytes(w, h, args.video_frames, radius=r)
            est[f"video_{w}x{h}"] = round(need / 2**30, 3)
            _refuse(need, f"the {args.video_frames}-frame video at {w}x{h}",
                    "use a smaller --video-size, fewer --video-frames or --video-frames 0", budget)
    if args.sweep_frames and args.sweep_size:
        w, h = args.sweep_size
        need = sweep_bytes(w, h, radius=r, channels=c)
        est["noise_sweep"] = round(need / 2**30, 3)
        _refuse(need, f"the noise sweep at {w}x{h}", "use a smaller --sweep-size or --sweep-frames ''", budget)
    return out
