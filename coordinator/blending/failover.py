"""Failover: the maps of the projectors that remain, from the stored contributions, no capture.

A *variant* of the blend is what every projector shows when some are out (``lost``: a node the
coordinator lost, or a lamp the watchdog found dead) or dimmed (``gains``: a lamp's measured
effective gain). It is computed by :func:`imaging.blending.solve.compute_blend` for the
remaining projectors with no headroom (they give all they can), then scaled back per camera-grid
point to the light the full blend made (its *white*, predicted from the stored contributions and
maps): the rig keeps the brightness and white point it had, and only the lost footprint's
neighbours change. Where the others cannot reach the full blend's light, they give what they
can, and :attr:`Variant.kept` says what fraction of the affected footprints stays on target.
(On a mesh rig, whose grid reaches the projectors through the texture, the scaling back is left
out: the remaining projectors show their own blend.)

:class:`Variants` keeps the variants computed so far, computes the single-loss variants of the
current state ahead in a worker thread (so that a loss costs no computation on the event loop),
within a memory budget beyond which a variant is computed when it is needed. The maps are held as
their float16 wire encoding (:meth:`protos.blend.BlendMaps.packed`: half of float32, and nothing to
encode when a loss pushes them); the losses most likely first (nodes lost before in this run), then
those that carry the most light. The first are held ready to push; when the rest would not fit the
budget that way, they are held compressed (about a seventh at 1080p; a loss inflates them in a
worker thread, tens of milliseconds instead of seconds of computation), so that at 1080p map sizes
the single losses of 25 projectors fit in 256 MiB. The variants ahead are background work: their
worker thread is a thread of its own, :data:`AHEAD_NICE` below the event loop's priority, so that
while they compute, the event loop (a switch's pushes, the nodes' heartbeats) and any process of the
same priority on the machine get the CPU first. A blend whose maps are at least 256 texels wide
fails over to maps four times coarser (:func:`variant_scale`): smooth maps sampled bilinearly keep
the light, and a loss pushes a sixteenth of the bytes (at 1080p, 65 KB per node instead of 1 MB).
"""
from __future__ import annotations

import asyncio
import logging
import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Callable, Iterable, Mapping

import numpy as np

from imaging.blending.contributions import Contributions, apply_homography_grid, luma
from imaging.blending.errors import BlendError
from imaging.blending.predict import predict
from imaging.blending.solve import compute_blend
from protos.blend import BlendMaps

__all__ = ["BLACK_MAPS", "DEAD_GAIN", "MAX_PRECOMPUTED_BYTES", "Variant", "VariantKey", "Variants", "base_white", "compute_variant",
           "map_scale_of", "variant_key", "variant_scale"]

log = logging.getLogger(__name__)

#: the maps a lost node's slot holds: it shows nothing until the rig switches back (a node that
#: restarts joins dark, and the others still cover its footprint)
BLACK_MAPS = BlendMaps(np.zeros((1, 1, 3), np.float32), np.zeros((1, 1), np.float32))
#: a lamp whose gain is below this is dead: its projector is left out of the blend as if lost (its
#: node, live, keeps the full blend's maps, so the watchdog sees the lamp come back)
DEAD_GAIN = 0.1
#: the most the precomputed variants' maps may hold (bytes); beyond it a variant is computed on a loss
MAX_PRECOMPUTED_BYTES = 256 * 2 ** 20
#: a point counts as kept when the variant's light reaches this fraction of the full blend's
KEPT_RATIO = 0.98
#: passes of the correction toward the full blend's light (see :func:`compute_variant`)
CORRECTIONS = 3
#: a failover's maps are computed this many times coarser than the full blend's when those are at least
#: VARIANT_COARSE_FROM texels wide (1080p maps of 480x270 give 120x68): the maps are smooth, the shader
#: samples them bilinearly, and a loss then pushes a sixteenth of the bytes (bench uniformity: a P25
#: loss with variant maps at 1/16 of the projector's width kept 0.63 % non-uniformity, 0.59 % at 1/4)
VARIANT_COARSEN = 4
VARIANT_COARSE_FROM = 256

#: (slots whose node is lost, lamp gains other than 1 as sorted (slot, gain) pairs; below DEAD_GAIN: dead)
VariantKey = tuple[frozenset, tuple]


def variant_key(lost: Iterable[str], gains: Mapping[str, float] | None = None) -> VariantKey:
    """The cache key of a state: gains of 1 (or of lost slots) are left out, the rest rounded to 1 %."""
    lost = frozenset(lost)
    g = tuple(sorted((s, round(float(v), 2)) for s, v in (gains or {}).items()
                     if s not in lost and round(float(v), 2) != 1.0))
    return lost, g


@dataclass(frozen=True, eq=False)
class Variant:
    """The maps of one state of the rig.

    Attributes
    ----------
    key : VariantKey
    maps : dict slot -> BlendMaps
        Every slot of the blend: the remaining ones' new maps, a lost node's :data:`BLACK_MAPS`,
        a dead lamp's slot its full-blend maps (its node is live and shows them: when the lamp
        comes back, the watchdog sees it).
    kept : float
        Fraction of the affected footprints (those of the lost and dimmed slots, within the full
        blend's covered area) where the variant's light is within 2 % of the full blend's.
    helpers : dict slot -> int
        Per lost or dimmed slot, how many remaining projectors reach its footprint.
    seconds : float
        Compute time.
    """

    key: VariantKey
    maps: dict[str, BlendMaps]
    kept: float = 1.0
    helpers: dict[str, int] = field(default_factory=dict)
    seconds: float = 0.0

    @property
    def nbytes(self) -> int:
        """What its maps hold in memory (bytes)."""
        return sum(m.nbytes for m in self.maps.values())

    @property
    def compressed(self) -> bool:
        """Its maps are held compressed (:meth:`inflated` before they are pushed)."""
        return any(m.compressed for m in self.maps.values())

    def packed(self, *, compress: bool = False) -> "Variant":
        """The same variant with its maps held as their float16 encoding (compressed or not)."""
        return replace(self, maps={s: m.packed(compress=compress) if m is not BLACK_MAPS else m
                                   for s, m in self.maps.items()})

    def inflated(self) -> "Variant":
        """The same variant ready to push (itself when not compressed)."""
        if not self.compressed:
            return self
        return replace(self, maps={s: m.inflated() for s, m in self.maps.items()})


def variant_scale(maps: Mapping[str, BlendMaps], contributions: Contributions) -> int:
    """The map scale of a blend's failover variants: :func:`map_scale_of` the full blend's maps, times
    :data:`VARIANT_COARSEN` when they are at least :data:`VARIANT_COARSE_FROM` texels wide (at most 64).
    A mesh rig's maps keep their scale: they follow a grazed surface's detail pixel by pixel (the bust's
    crown), which maps four times coarser would lose during the failover."""
    scale = map_scale_of(maps, contributions)
    if getattr(contributions, "projector_xy", None):
        return scale
    widest = max((m.size[0] for m in maps.values() if m is not BLACK_MAPS), default=0)
    return min(64, scale * VARIANT_COARSEN) if widest >= VARIANT_COARSE_FROM else scale


def map_scale_of(maps: Mapping[str, BlendMaps], contributions: Contributions) -> int:
    """The map scale the stored maps were made with (projector width / map width, rounded)."""
    for s, m in maps.items():
        if s in contributions.projector_size:
            return max(1, min(64, int(round(contributions.projector_size[s][0] / m.size[0]))))
    return 4


def base_white(contributions: Contributions, maps: Mapping[str, BlendMaps]) -> np.ndarray:
    """(h, w, 3) float32: the light above black the full blend makes on the camera grid at white
    (its maps through the contributions: :func:`imaging.blending.predict.predict` at 1 less at 0)."""
    pairs = {s: (m.alpha, m.beta) for s, m in maps.items() if s in contributions.white}
    return (predict(contributions, pairs, 1.0) - predict(contributions, pairs, 0.0)).astype(np.float32)


def _grid_field_in_map(values: np.ndarray, contributions: Contributions, slot: str,
                       size: tuple[int, int]) -> np.ndarray:
    """A camera-grid field (h, w, C) float32 sampled at the centres of ``slot``'s map texels
    (``size`` = (mw, mh)): bilinear, edges replicated. (mh, mw, C) float32."""
    import cv2  # lazy: the blend state loads this module at every coordinator's start

    W, H = contributions.projector_size[slot]
    cam_W, cam_H = contributions.camera_size
    gh, gw = contributions.shape
    mw, mh = size
    ux = (np.arange(mw) + 0.5) * (W / mw) - 0.5
    uy = (np.arange(mh) + 0.5) * (H / mh) - 0.5
    x = apply_homography_grid(np.linalg.inv(contributions.camera_to_projector[slot]), np.stack(np.meshgrid(ux, uy), -1))
    gx = (x[..., 0] + 0.5) * (gw / cam_W) - 0.5
    gy = (x[..., 1] + 0.5) * (gh / cam_H) - 0.5
    ok = np.isfinite(gx) & np.isfinite(gy)
    out = cv2.remap(np.ascontiguousarray(values, np.float32), np.where(ok, gx, 0).astype(np.float32),
                    np.where(ok, gy, 0).astype(np.float32), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return np.asarray(out, np.float32).reshape(mh, mw, -1)


def compute_variant(contributions: Contributions, base_maps: Mapping[str, BlendMaps], white: np.ndarray,
                    key: VariantKey, *, map_scale: int | None = None) -> Variant:
    """The variant ``key`` of the blend ``base_maps`` (its light ``white``, :func:`base_white`).

    Parameters
    ----------
    contributions : Contributions
        As measured (all lamps at 1).
    base_maps : dict slot -> BlendMaps
        The full blend's maps.
    white : (h, w, 3) float32
        The full blend's light above black on the camera grid.
    key : VariantKey
        ``(lost, gains)`` (:func:`variant_key`).

    Raises
    ------
    BlendError
        No projector left (one line).
    """
    t0 = time.perf_counter()
    lost, gains = key
    if not lost and not gains:
        return Variant(key, dict(base_maps), 1.0, {}, time.perf_counter() - t0)
    scale = map_scale or map_scale_of(base_maps, contributions)
    measured = [s for s in contributions.slots if s in base_maps]
    dead = {s for s, g in gains if g < DEAD_GAIN}
    dim = {s: g for s, g in gains if s not in dead}
    lost_measured = frozenset(s for s in set(lost) | dead if s in contributions.white)
    sol = compute_blend(contributions.without([s for s in contributions.slots if s not in base_maps]),
                        lost=lost_measured, headroom=0.0, map_scale=scale, lamp_gains=dim or None)
    dimmed = contributions.with_gains(dim) if dim else contributions
    pairs = {s: sol.maps[s] for s in sol.maps}
    gone = tuple(lost_measured)

    def light(p: Mapping[str, tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        return predict(dimmed, p, 1.0, lost=gone) - predict(dimmed, p, 0.0, lost=gone)

    # per grid point and channel, the factor that brings the remaining projectors' light back to the
    # full blend's, applied in each map's own grid; a second pass corrects what resampling the factor
    # into the maps missed near footprint edges, where the light changes fast
    # a mesh rig's grid points reach the projectors through the texture, not a homography: its maps
    # are the remaining projectors' own blend (their target, not the full blend's light)
    passes = 0 if getattr(contributions, "projector_xy", None) else CORRECTIONS
    for _ in range(passes):
        made = light(pairs)
        with np.errstate(divide="ignore", invalid="ignore"):
            factor = np.where(made > 1e-9, white / made, 1.0)
        factor = np.where(np.isfinite(factor), factor, 1.0).astype(np.float32)
        scaled = {}
        for s, (alpha, beta) in pairs.items():
            f = _grid_field_in_map(factor, contributions, s, (alpha.shape[1], alpha.shape[0]))
            scaled[s] = (np.clip(alpha * f, 0.0, 1.0).astype(np.float32), beta)
        pairs = scaled
    maps: dict[str, BlendMaps] = {}
    for s in measured:
        if s in pairs:
            maps[s] = BlendMaps(*pairs[s])
        elif s in lost:
            maps[s] = BLACK_MAPS
        elif s in dead:
            maps[s] = base_maps[s]
    for s in lost:          # a lost slot the contributions never measured (added since): dark too
        if s in base_maps and s not in maps:
            maps[s] = BLACK_MAPS
    # what is kept: the variant's light against the full blend's over the affected footprints
    got = light({s: (m.alpha, m.beta) for s, m in maps.items() if s in pairs})
    affected_slots = [s for s in set(lost_measured) | set(dim) if s in contributions.white]
    affected = np.zeros(contributions.shape, bool)
    for s in affected_slots:
        affected |= contributions.footprint(s)
    wy = luma(white)
    affected &= wy > 1e-3 * max(float(wy.max()), 1e-12)
    ratio = luma(got)[affected] / wy[affected]
    kept = float(np.mean(ratio >= KEPT_RATIO)) if ratio.size else 1.0
    helpers = {s: sum(1 for o in pairs if o != s and np.any(contributions.footprint(o) & contributions.footprint(s)))
               for s in affected_slots}
    return Variant(key, maps, kept, helpers, time.perf_counter() - t0)


#: how much lower the variants-ahead thread's priority is (nice value added; Linux has per-thread nice)
AHEAD_NICE = 10


def _background_thread() -> None:
    """The variants-ahead thread lowers its own priority (raising a nice value needs no privilege)."""
    if not hasattr(os, "setpriority"):
        return
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, min(19, os.getpriority(os.PRIO_PROCESS, tid) + AHEAD_NICE))
    except OSError:
        pass


class Variants:
    """The variants of one blend: computed on demand or ahead, kept within a memory budget.

    Parameters
    ----------
    contributions, base_maps :
        The blend (as stored).
    budget_bytes : int
        What the variants' maps may hold together; the full blend is always kept.
    """

    def __init__(self, contributions: Contributions, base_maps: Mapping[str, BlendMaps], *,
                 budget_bytes: int = MAX_PRECOMPUTED_BYTES):
        self.contributions = contributions
        self.base_maps = dict(base_maps)
        self.map_scale = variant_scale(self.base_maps, contributions)
        self.budget_bytes = budget_bytes
        self._white: np.ndarray | None = None
        self._shares: dict[str, float] | None = None
        self._ratio: float | None = None       # packed bytes over compressed bytes, once measured
        base = variant_key(())
        self._cache: dict[VariantKey, Variant] = {base: Variant(base, dict(self.base_maps))}
        self._failed: dict[VariantKey, str] = {}
        self._ahead: asyncio.Task | None = None
        self._pool: ThreadPoolExecutor | None = None     # the variants-ahead thread (low priority)
        #: the order of the last run ahead (its keys), for reports
        self.planned: list[VariantKey] = []

    @property
    def white(self) -> np.ndarray:
        if self._white is None:
            self._white = base_white(self.contributions, self.base_maps)
        return self._white

    def light_shares(self) -> dict[str, float]:
        """slot -> the fraction of the full blend's light it carries (its measured white over the
        camera grid times its mean gain in the blend): how much a loss of it takes away."""
        if self._shares is None:
            c = self.contributions
            raw = {s: float(luma(c.white[s]).sum()) * float(np.mean(m.alpha)) for s, m in self.base_maps.items()
                   if s in c.white}
            total = sum(raw.values()) or 1.0
            self._shares = {s: v / total for s, v in raw.items()}
        return self._shares

    def get(self, key: VariantKey) -> Variant | None:
        """The variant if it is ready to push (no computation; None when held compressed)."""
        v = self._cache.get(key)
        return None if v is None or v.compressed else v

    def held(self, key: VariantKey) -> Variant | None:
        """The variant if it is held, ready or compressed."""
        return self._cache.get(key)

    def failure(self, key: VariantKey) -> str | None:
        """Why the variant cannot be made (e.g. no projector left), if it was tried."""
        return self._failed.get(key)

    def compute(self, key: VariantKey) -> Variant:
        """The variant ready to push: inflated when held compressed, computed now if not held
        (blocking: a worker thread). BlendError: none possible."""
        hit = self._cache.get(key)
        if hit is not None:
            return hit.inflated()
        try:
            v = compute_variant(self.contributions, self.base_maps, self.white, key, map_scale=self.map_scale)
        except BlendError as exc:
            self._failed[key] = str(exc)
            raise
        v = v.packed()
        self._keep(v)
        return v

    def _keep(self, v: Variant, *, remaining: int = 0) -> None:
        """Hold ``v`` (packed) ready when that leaves room for the ``remaining`` variants planned
        after it, held compressed; else compressed; else not at all."""
        used = self.held_bytes()
        reserve = 0
        if remaining:
            if self._ratio is None:
                self._ratio = max(1.0, v.nbytes / max(1, v.packed(compress=True).nbytes))
            reserve = int(remaining * v.nbytes / self._ratio)
        if used + v.nbytes + reserve <= self.budget_bytes:
            self._cache[v.key] = v
            return
        small = v.packed(compress=True)
        self._ratio = max(1.0, v.nbytes / max(1, small.nbytes))
        if used + small.nbytes <= self.budget_bytes:
            self._cache[v.key] = small

    def held_bytes(self) -> int:
        return sum(x.nbytes for k, x in self._cache.items() if k != variant_key(()))

    def ahead_counts(self) -> dict[str, int]:
        """Of the last run ahead's variants: how many are held ready, held compressed, not held."""
        ready = sum(1 for k in self.planned if self.get(k) is not None)
        small = sum(1 for k in self.planned if k in self._cache and self._cache[k].compressed)
        return {"planned": len(self.planned), "ready": ready, "compressed": small,
                "not_held": len(self.planned) - ready - small}

    def order(self, current: VariantKey, likely: Mapping[str, int] | None = None) -> list[VariantKey]:
        """The variants one change away from ``current``, in the order they are computed ahead: the
        state it came from first (each loss undone), then each further loss, the most likely first
        (``likely``: slot -> how often its node was lost in this run), then the most light lost."""
        lost, gains = current
        likely = likely or {}
        shares = self.light_shares()
        keys = [variant_key(lost - {s}, dict(gains)) for s in sorted(lost)]
        rest = sorted((s for s in self.base_maps if s not in lost),
                      key=lambda s: (-int(likely.get(s, 0)), -shares.get(s, 0.0), s))
        return keys + [variant_key(lost | {s}, dict(gains)) for s in rest]

    def start_ahead(self, current: VariantKey, *, likely: Mapping[str, int] | None = None,
                    on_done: Callable[[int, float], None] | None = None) -> None:
        """Compute, in a worker thread, the variants one change away from ``current`` in
        :meth:`order`; the previous run stops."""
        self.stop_ahead()
        keys = self.order(current, likely)
        self.planned = keys
        self._ahead = asyncio.get_running_loop().create_task(self._run_ahead(keys, on_done), name="blend-variants")

    async def _run_ahead(self, keys: list[VariantKey], on_done: Callable[[int, float], None] | None) -> None:
        t0 = time.perf_counter()
        made = 0
        for i, key in enumerate(keys):
            if key in self._cache or key in self._failed:
                continue
            if self.held_bytes() >= self.budget_bytes:
                log.info("blend: precomputed variants hold %.0f MiB, the budget: the next losses are computed "
                         "when they happen", self.held_bytes() / 2 ** 20)
                break
            left = sum(1 for k in keys[i + 1:] if k not in self._cache and k not in self._failed)
            try:
                if self._pool is None:
                    self._pool = ThreadPoolExecutor(1, thread_name_prefix="blend-ahead", initializer=_background_thread)
                await asyncio.get_running_loop().run_in_executor(self._pool, self._compute_ahead, key, left)
                made += 1
            except BlendError:
                continue
        if on_done is not None:
            on_done(made, time.perf_counter() - t0)

    def _compute_ahead(self, key: VariantKey, remaining: int) -> None:
        try:
            v = compute_variant(self.contributions, self.base_maps, self.white, key, map_scale=self.map_scale)
        except BlendError as exc:
            self._failed[key] = str(exc)
            raise
        self._keep(v.packed(), remaining=remaining)

    def stop_ahead(self) -> None:
        if self._ahead is not None and not self._ahead.done():
            self._ahead.cancel()
        self._ahead = None
        pool, self._pool = self._pool, None
        if pool is not None:        # its thread ends after the variant it computes, if any
            pool.shutdown(wait=False, cancel_futures=True)

    async def wait_ahead(self) -> None:
        """Until the current run ahead ended (tests and benchmarks)."""
        if self._ahead is not None:
            await asyncio.gather(self._ahead, return_exceptions=True)
