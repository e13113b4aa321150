"""The blend: a target every covered point can reach, and each projector's alpha and beta maps.

**The physics.** A node shows linear content ``p`` as ``y_i = alpha_i * p + beta_i`` (its blend
maps, then its inverse-response LUT), so the camera sees ``sum_i black_i + T_i * (alpha_i p +
beta_i)`` (:mod:`imaging.blending.contributions`). The blend asks, per channel ``c``,

* ``sum_i T_ic alpha_ic = target_c`` (white even in luminance and colour), and
* ``sum_i black_i + T_i beta_i = black target`` (the black floor raised where fewer projectors
  reach, so that it is even too; beta is one map, a luminance offset).

**Weights.** Each projector gets a weight ``r_i`` that ramps smoothly (smoothstep over ``ramp`` of
its smaller side) from its frame's edge to 1 inside, floored at 1e-3 inside the frame. Then
``alpha_ic = r_i target_c / S_c`` with ``S_c = sum_j r_j T_jc``, which meets the sum exactly, and a
footprint edge inside another projector's light is faded in and out instead of stepping (a
seam). ``alpha_i <= 1`` everywhere exactly when ``target_c <= S_c / max_j r_j`` =: the *reach*
``R_c``; beta shares the same weights and takes its part of the reach (``alpha + beta <= 1``).

**The target** follows Majumder and Stevens' perceptually seamless approach: the eye does not see
a luminance that varies slowly, only one that varies fast, so the target need not be flat, only
smooth. It is the largest luminance surface that lies under what every point can reach (with the
headroom kept in reserve) and whose logarithm changes by at most ``smoothness`` over the grid's
diagonal: the lower Lipschitz envelope of ``log(reach)``
(:func:`~imaging.blending.envelope.lower_envelope`). Colour: one white point for the whole rig
(the median chromaticity of the reach), each channel's target the luminance target times it.
Why not "the darkest pixel everywhere" (the flat minimum of the reach)? The reach varies a lot: a
footprint's corner with lens fall-off, or the edge of the covered area where one projector
reaches against twenty-five in the middle, sets a minimum that may be a small fraction of what
most of the surface can give; a flat target at that level throws that light away everywhere,
while the envelope is limited by a dark point only in its neighbourhood and rises away from it
slowly enough not to be seen.

**Headroom.** ``headroom=None`` ("auto"): the target also lies under what the others reach when
any one projector is lost, wherever others reach (so a lost node or dead lamp is covered by
re-blending without a visible change); a number ``h`` in 0..0.9: the target lies under
``(1 - h) * reach``. ``brightness_cost`` is what that costs: ``1 - mean(target) / mean(target
without headroom)`` over the covered area.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Iterable, Mapping

import numpy as np

from imaging.blending.contributions import LUMA, Contributions, apply_homography_grid
from imaging.blending.envelope import lower_envelope, upper_envelope
from imaging.blending.errors import BlendError

__all__ = ["BlendSolution", "compute_blend", "map_size", "frame_weight", "HEADROOM_MAX",
           "DEFAULT_SMOOTHNESS", "DEFAULT_RAMP", "validate_headroom"]

#: the largest headroom a blend keeps in reserve
HEADROOM_MAX = 0.9
#: log-luminance change the target may make over the grid's diagonal
DEFAULT_SMOOTHNESS = 1.0
#: the weights' ramp, as a fraction of a projector's smaller side
DEFAULT_RAMP = 0.15
#: points reaching less than this fraction of the median reach are left out of the target
DEFAULT_MIN_REACH = 0.2
#: the weight's floor inside a projector's frame (keeps alpha defined where it alone reaches)
WEIGHT_FLOOR = 1e-3


@dataclass(frozen=True, eq=False)
class BlendSolution:
    """What :func:`compute_blend` returns.

    Attributes
    ----------
    maps : dict slot -> (alpha (mh, mw, 3) float32, beta (mh, mw) float32)
        In each projector's map grid (:func:`map_size`), for the slots not lost.
    target : (h, w, 3) float32
        The white target on the camera grid (light above black; 0 where not covered).
    black_target : (h, w) float32
        The black floor's luminance target (0 where not covered).
    covered : (h, w) bool
        Where some projector of the blend reaches.
    headroom : float
        The reserve used (for "auto": the median over the covered area of the fraction held back).
    brightness_cost : float
        ``1 - mean(target) / mean(target without headroom)`` over the covered area.
    uncovered : dict slot -> float
        Per slot of the blend, the fraction of its footprint that no other projector of the blend reaches.
    white_point : (3,) float32
        The common white, luminance 1.
    lost : tuple of str
    seconds : float
        Compute time.
    """

    maps: dict[str, tuple[np.ndarray, np.ndarray]]
    target: np.ndarray
    black_target: np.ndarray
    covered: np.ndarray
    headroom: float
    brightness_cost: float
    uncovered: dict[str, float]
    white_point: np.ndarray
    lost: tuple[str, ...] = ()
    seconds: float = 0.0
    info: dict = field(default_factory=dict)


def validate_headroom(headroom: float | str | None) -> float | None:
    """``headroom`` as a float in 0..0.9, or None for None or "auto"; :class:`BlendError` (one line) otherwise."""
    if headroom is None or (isinstance(headroom, str) and headroom.strip().lower() == "auto"):
        return None
    try:
        h = float(headroom)
    except (TypeError, ValueError):
        raise BlendError(f"headroom must be 'auto' or a number in 0..{HEADROOM_MAX}, got {headroom!r}") from None
    if not (math.isfinite(h) and 0.0 <= h <= HEADROOM_MAX):
        raise BlendError(f"headroom must be 'auto' or a number in 0..{HEADROOM_MAX}, got {headroom!r}")
    return h


def map_size(projector_size: tuple[int, int], map_scale: int) -> tuple[int, int]:
    """``(mw, mh)`` of a projector's blend maps: its size over ``map_scale``, rounded up."""
    W, H = projector_size
    return max(1, int(math.ceil(W / map_scale))), max(1, int(math.ceil(H / map_scale)))


def frame_weight(u: np.ndarray, size: tuple[int, int], ramp: float) -> np.ndarray:
    """``(...) float32`` weight of projector pixels ``u`` (``(..., 2)``): 0 outside the frame, a smoothstep
    from the frame's edge to 1 at ``ramp`` x the smaller side inside, never below 1e-3 inside."""
    W, H = size
    x, y = u[..., 0], u[..., 1]
    with np.errstate(invalid="ignore"):
        d = np.minimum(np.minimum(x + 0.5, W - 0.5 - x), np.minimum(y + 0.5, H - 0.5 - y))
    width = max(ramp * min(W, H), 1e-9)
    t = np.clip(np.nan_to_num(d, nan=-1.0) / width, 0.0, 1.0)
    r = t * t * (3.0 - 2.0 * t)
    inside = np.nan_to_num(d, nan=-1.0) > 0
    return np.where(inside, np.maximum(r, WEIGHT_FLOOR), 0.0).astype(np.float32)


def _weight(c: Contributions, slot: str, ramp: float) -> np.ndarray:
    """``slot``'s weight on the grid (cached on ``c``: failover variants share it)."""
    key = ("weight", slot, float(ramp))
    hit = c._coords.get(key)
    if hit is None:
        fp = c.footprint(slot)
        hit = frame_weight(c.projector_coords(slot), c.projector_size[slot], ramp) * fp
        if c.projector_xy is not None and slot in c.projector_xy and fp.any():
            # a mesh: the footprint also ends where the object hides the surface from the projector; ramp there too
            from scipy import ndimage    # at use: the coordinator imports this module at start (SciPy: ~48 MB)
            d = ndimage.distance_transform_edt(fp)
            t = np.clip(d / max(ramp * math.sqrt(float(fp.sum())), 1.0), 0.0, 1.0)
            hit = np.where(fp, np.maximum(hit * (t * t * (3.0 - 2.0 * t)), WEIGHT_FLOOR), 0.0).astype(np.float32)
        c._coords[key] = hit
    return hit


def _texel_grid(c: Contributions, slot: str, map_scale: int) -> tuple[np.ndarray, np.ndarray]:
    """``(mapx, mapy)`` float32 (mh, mw): the grid position of each of ``slot``'s map texels (cached on ``c``)."""
    key = ("texels", slot, int(map_scale))
    hit = c._coords.get(key)
    if hit is None:
        W, H = c.projector_size[slot]
        gh, gw = c.shape
        cam_W, cam_H = c.camera_size
        mw, mh = map_size((W, H), map_scale)
        if c.projector_xy is not None and slot in c.projector_xy:
            hit = c._coords[key] = _texels_from_points(c.projector_xy[slot], (W, H), (mw, mh))
            return hit
        ux = (np.arange(mw) + 0.5) * (W / mw) - 0.5
        uy = (np.arange(mh) + 0.5) * (H / mh) - 0.5
        x = apply_homography_grid(np.linalg.inv(c.camera_to_projector[slot]), np.stack(np.meshgrid(ux, uy), axis=-1))
        gx = (x[..., 0] + 0.5) * (gw / cam_W) - 0.5
        gy = (x[..., 1] + 0.5) * (gh / cam_H) - 0.5
        ok = np.isfinite(gx) & np.isfinite(gy)
        hit = c._coords[key] = (np.where(ok, gx, 0).astype(np.float32), np.where(ok, gy, 0).astype(np.float32))
    return hit


def _texels_from_points(xy: np.ndarray, size: tuple[int, int], msize: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """A mesh rig's texel -> grid positions: the mean grid position of the grid points each texel holds
    (``xy``: (h, w, 2) projector coordinates of the grid points), the nearest such texel's elsewhere."""
    W, H = size
    mw, mh = msize
    gh, gw = xy.shape[:2]
    gy, gx = np.mgrid[0:gh, 0:gw]
    tx = np.floor((xy[..., 0] + 0.5) * (mw / W))
    ty = np.floor((xy[..., 1] + 0.5) * (mh / H))
    ok = np.isfinite(tx) & np.isfinite(ty) & (tx >= 0) & (tx < mw) & (ty >= 0) & (ty < mh)
    mapx = np.full((mh, mw), -1.0, np.float32)
    mapy = np.full((mh, mw), -1.0, np.float32)
    if not ok.any():
        return mapx, mapy
    idx = (ty[ok].astype(np.int64) * mw + tx[ok].astype(np.int64))
    n = np.bincount(idx, minlength=mw * mh).reshape(mh, mw)
    sx = np.bincount(idx, weights=gx[ok], minlength=mw * mh).reshape(mh, mw)
    sy = np.bincount(idx, weights=gy[ok], minlength=mw * mh).reshape(mh, mw)
    held = n > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        both = np.stack([sx / n, sy / n], axis=-1)
    both = _fill_nearest(both, held)
    return np.ascontiguousarray(both[..., 0], np.float32), np.ascontiguousarray(both[..., 1], np.float32)


def _fill_nearest(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``values`` with every invalid pixel set to its nearest valid pixel's value (leading axes (h, w))."""
    if valid.all() or not valid.any():
        return values
    from scipy import ndimage
    idx = ndimage.distance_transform_edt(~valid, return_distances=False, return_indices=True)
    return values[idx[0], idx[1]]


def _reach(S: np.ndarray, M: np.ndarray, S_y: np.ndarray, lift: np.ndarray) -> np.ndarray:
    """Per channel the largest white target the weights allow once beta took ``lift`` (0 where M == 0)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        R = S / M[..., None] - lift[..., None] * S / S_y[..., None]
    R[~(M > 0)] = 0.0
    return np.nan_to_num(np.maximum(R, 0.0), nan=0.0)


@dataclass
class _Plan:
    """The grid fields of one blend: weights, sums, the targets and what they cost."""

    r: dict
    S: np.ndarray          # (h, w, 3) sum of weighted white
    S_y: np.ndarray        # (h, w) its luminance
    covered: np.ndarray    # (h, w) bool
    lift: np.ndarray       # (h, w) black raised by beta (luminance)
    black_target: np.ndarray
    white: np.ndarray      # (3,) luminance 1
    L: np.ndarray          # (h, w) luminance target
    used: float
    cost: float


def _plan(c: Contributions, active: list[str], h_fixed: float | None, slope: float, ramp: float,
          reference: _Plan | None = None, min_reach: float = 0.0) -> _Plan:
    shape = c.shape
    gh, gw = shape
    luma64 = LUMA.astype(np.float64)
    r = {s: _weight(c, s, ramp) for s in active}
    S = np.zeros((gh, gw, 3), np.float64)
    B = np.zeros((gh, gw, 3), np.float64)
    M1 = np.zeros(shape, np.float64)  # the largest weight and the second largest (a lost slot's reach)
    M2 = np.zeros(shape, np.float64)
    arg = np.full(shape, -1, np.int32)
    for k, s in enumerate(active):
        S += r[s][..., None] * c.white[s]
        B += c.black[s]
        rs = r[s].astype(np.float64)
        bigger = rs > M1
        M2 = np.where(bigger, M1, np.maximum(M2, rs))
        arg = np.where(bigger, k, arg)
        M1 = np.where(bigger, rs, M1)
    S_y = S @ luma64
    covered = (M1 > 0) & (S_y > 0)
    if not covered.any():
        raise BlendError("the projectors of the blend light no point the camera sees: calibrate again, "
                         "or check the camera's view")

    # the black floor: the smallest smooth surface above the total black (log), never below an earlier blend's
    B_y = B @ luma64
    logb = np.where(covered & (B_y > 0), np.log(np.maximum(B_y, 1e-30)), -np.inf)
    black_target = np.where(covered, np.exp(upper_envelope(logb, slope)), 0.0) if np.isfinite(logb).any() \
        else np.zeros(shape)
    if reference is not None:
        black_target = np.maximum(black_target, reference.black_target)
    black_target = np.where(covered, np.maximum(black_target, B_y), 0.0)
    lift = np.where(covered, black_target - B_y, 0.0)

    R = _reach(S, M1, S_y, lift)
    if h_fixed is not None:
        cap = (1.0 - h_fixed) * R
    else:
        cap = R.copy()
        for k, s in enumerate(active if len(active) > 1 else []):
            Sk = S - r[s][..., None] * c.white[s]
            Mk = np.where(arg == k, M2, M1)
            Sk_y = Sk @ luma64
            Rk = _reach(Sk, Mk, Sk_y, np.where(Mk > 0, lift + c.black[s] @ LUMA, 0.0))
            others = (Mk > 0) & (Sk_y > 0)
            np.minimum(cap, np.where(others[..., None], Rk, cap), out=cap)

    # a common white point, then the luminance target (the log-Lipschitz envelope of what every point reaches)
    if reference is not None:
        white = reference.white
    else:
        R_y = np.maximum(R @ luma64, 1e-30)
        white = np.median(R[covered] / R_y[covered][:, None], axis=0)
        white = white / float(white @ luma64)
    reach_all = np.min(R / white[None, None, :], axis=-1)
    # points that reach too little to be held to the target (a fringe, a surface turned away from every
    # projector) are left out of it: they get all they can, and do not drag the whole target down
    floor = max(float(min_reach), 1e-3) * float(np.median(reach_all[covered]))
    covered &= reach_all > floor
    if not covered.any():
        raise BlendError("the projectors of the blend reach no point the camera sees with light to spare")

    def luminance_target(bound: np.ndarray) -> np.ndarray:
        reach_y = np.min(bound / white[None, None, :], axis=-1)
        if reference is not None:
            reach_y = np.minimum(reach_y, np.where(reference.covered, reference.L, np.inf))
        logr = np.where(covered, np.log(np.maximum(reach_y, floor)), np.inf)
        return np.where(covered, np.exp(lower_envelope(logr, slope)), 0.0)

    L = luminance_target(cap)
    L0 = luminance_target(R) if (h_fixed is None or h_fixed > 0) else L
    total0 = float(L0[covered].sum())
    cost = 1.0 - float(L[covered].sum()) / total0 if total0 > 0 else 0.0
    if h_fixed is None:
        with np.errstate(divide="ignore", invalid="ignore"):
            held = 1.0 - np.min(np.where(R > 0, cap / R, 1.0), axis=-1)
        used = float(np.median(held[covered]))
    else:
        used = h_fixed
    return _Plan(r, S, S_y, covered, lift, black_target, white, L, used, max(cost, 0.0))


def compute_blend(contributions: Contributions, *, lost: Iterable[str] = frozenset(), headroom: float | str | None = None,
                  map_scale: int = 4, lamp_gains: Mapping[str, float] | None = None,
                  smoothness: float = DEFAULT_SMOOTHNESS, ramp: float = DEFAULT_RAMP,
                  min_reach: float = DEFAULT_MIN_REACH) -> BlendSolution:
    """The blend of the projectors not ``lost`` (see the module docstring).

    With ``lost`` or ``lamp_gains`` (a failover), the blend of the whole rig as measured is computed first
    and its target (and black floor and white point) kept wherever the remaining projectors reach it, so
    that losing a projector changes nothing anyone sees where the headroom covers it; elsewhere the target
    is the largest smooth one under what they reach.

    Parameters
    ----------
    contributions : Contributions
    lost : slots left out (a lost node, a dead lamp); no capture is needed.
    headroom : None or "auto", or 0..0.9
    map_scale : int
        Map grid = projector size / map_scale (rounded up).
    lamp_gains : slot -> measured lamp gain (scales that slot's contribution).
    smoothness : float > 0
        Log-luminance change the target may make over the grid's diagonal.
    ramp : float in (0, 0.5]
        The weights' ramp as a fraction of each projector's smaller side.
    min_reach : float in 0..0.9
        Points whose reach is below this fraction of the median reach are left out of the target (not
        ``covered``): they get all the light they can (a surface turned away from every projector).
    """
    t0 = time.perf_counter()
    h_fixed = validate_headroom(headroom)
    if not (isinstance(map_scale, int) and not isinstance(map_scale, bool) and 1 <= map_scale <= 64):
        raise BlendError(f"map_scale must be an integer in 1..64, got {map_scale!r}")
    if not (0.0 < float(smoothness) <= 100.0):
        raise BlendError(f"smoothness must be in (0, 100], got {smoothness!r}")
    if not (0.0 < float(ramp) <= 0.5):
        raise BlendError(f"ramp must be in (0, 0.5], got {ramp!r}")
    if not (0.0 <= float(min_reach) <= 0.9):
        raise BlendError(f"min_reach must be in 0..0.9, got {min_reach!r}")
    lost = tuple(sorted(set(lost)))
    unknown = [s for s in lost if s not in contributions.slots]
    if unknown:
        raise BlendError(f"lost slot(s) {', '.join(unknown)} are not in the measured contributions "
                         f"({', '.join(contributions.slots)})")
    c = contributions.with_gains(lamp_gains) if lamp_gains else contributions
    active = [s for s in c.slots if s not in lost]
    if not active:
        raise BlendError("no projector left to blend: every measured projector is lost "
                         f"({', '.join(lost)}); bring one back or measure again")
    shape = c.shape
    gh, gw = shape
    slope = float(smoothness) / max(math.hypot(gh, gw), 1.0)
    gains_differ = bool(lamp_gains) and any(abs(float(g) - 1.0) > 1e-9 for g in lamp_gains.values())
    if lost or gains_differ:
        reference = _plan(contributions, contributions.slots, h_fixed, slope, ramp, min_reach=min_reach)
        plan = _plan(c, active, 0.0, slope, ramp, reference=reference, min_reach=min_reach)
        plan.used, plan.cost = reference.used, reference.cost
    else:
        plan = _plan(c, active, h_fixed, slope, ramp, min_reach=min_reach)
    covered = plan.covered
    target = plan.L[..., None] * plan.white[None, None, :]
    S, S_y, lift, r = plan.S, plan.S_y, plan.lift, plan.r

    import cv2  # lazy: a coordinator's start loads this module; OpenCV only when a blend is solved

    # per slot, alpha = r_i Q_c and beta = r_i P on the grid (exact there), then resampled into its map grid
    with np.errstate(divide="ignore", invalid="ignore"):
        Q = np.where(covered[..., None], target / np.where(S > 0, S, np.inf), 0.0).astype(np.float32)
        P = np.where(covered, lift / np.where(S_y > 0, S_y, np.inf), 0.0).astype(np.float32)
    maps: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    uncovered: dict[str, float] = {}
    count = np.zeros(shape, np.int32)
    for s in active:
        count += c.footprint(s)
    for s in active:
        fp = c.footprint(s)
        valid = fp & covered
        grid_maps = np.concatenate([r[s][..., None] * Q, (r[s] * P)[..., None]], axis=-1)
        grid_maps = np.ascontiguousarray(_fill_nearest(grid_maps, valid) if valid.any() else np.zeros_like(grid_maps))
        mapx, mapy = _texel_grid(c, s, map_scale)
        sampled = cv2.remap(grid_maps, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        maps[s] = (np.clip(sampled[..., :3], 0.0, 1.0).astype(np.float32),
                   np.clip(sampled[..., 3], 0.0, 1.0).astype(np.float32))
        n = int(fp.sum())
        uncovered[s] = float(((count == 1) & fp).sum() / n) if n else 1.0
    if c.projector_xy is not None and all(s in c.projector_xy for s in active):
        # a mesh: sampled maps miss the target where a texel spans surfaces or fast shading; fit them instead
        from imaging.blending.mesh_maps import fit_alpha_maps
        alphas = fit_alpha_maps({s: c.white[s] for s in active}, {s: c.projector_coords(s) for s in active},
                                {s: c.projector_size[s] for s in active}, {s: maps[s][0] for s in active},
                                {s: r[s][..., None] * Q for s in active}, target, covered)
        maps = {s: (alphas[s], maps[s][1]) for s in active}
    return BlendSolution(maps=maps, target=target.astype(np.float32),
                         black_target=np.where(covered, plan.black_target, 0.0).astype(np.float32),
                         covered=covered, headroom=float(plan.used), brightness_cost=float(plan.cost),
                         uncovered=uncovered, white_point=plan.white.astype(np.float32), lost=lost,
                         seconds=time.perf_counter() - t0,
                         info={"slope_per_px": slope, "grid": [gw, gh], "active": active})
