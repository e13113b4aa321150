"""A model of reactive shadow compensation, the prior systems a synthetic aperture is compared with.

Prior multi-projector systems detect the occluder (or its shadow) with a camera,
work out which projectors still reach each point, and boost those to make up for
the blocked ones. That loop takes time: what the projectors show at frame ``t``
was solved for the hand as the camera saw it at ``t - latency``. A synthetic
aperture computes nothing; its soft shadow is wherever the hand is, at once.

The model, per table point ``x`` over the projectors ``i`` of the rig (all
gains relative to the projectors' nominal drive, light 1 = the intended image):

* ``s_i(x) = E_i(x) / sum_j E_j(x)``: projector i's share of the light at x
  (``E``: its full-white irradiance there; the shares sum to 1);
* ``B_i(t)``: the points whose line of sight to projector i the hand crosses at t;
* what the system saw lost at x: ``d(x) = sum of s_i(x) over i with x in B_i(t - latency)``;
* the boost it applies at x to the projectors it saw unblocked:
  ``g(x) = min(cap, 1 / (1 - d(x)))``. ``cap`` is the projectors' headroom: a
  projector driven at ``1 / cap`` of its maximum for the intended image can be
  boosted at most ``cap`` times (default 2: nominal is half the maximum, so a
  point can be restored while it loses up to half its light);
* the projectors it saw blocked at x keep gain 1 (``suppress=False``, boosting
  only, as Sukthankar et al. 2001) or are switched off there so they do not light
  the hand (``suppress=True``, occluder light suppression, as Cham et al. 2003);
* what the table receives at frame t:
  ``light(x, t) = sum of gain_i(x) s_i(x) over i with x not in B_i(t)``.

With the hand still, the light is restored exactly wherever ``d <= 1 - 1/cap``.
When it moves, the compensation lags: the shadow reappears where the hand now is,
and where it was the boosted projectors make over-bright ghosts (``light > 1``).
Boosting only, every gain is at least 1, so the light is never below what the same
projectors give passively: the lag leaves the rig's own passive shadow where the
hand is, plus the ghosts. Suppressing can be worse than passive: a point that the
hand has just reached, whose previously blocked projectors were switched off, loses
those projectors and its newly blocked ones at once.

The model is geometric (the room's ground-truth visibility, no blur, no camera
noise, a perfect detector): the only imperfection is the latency, so what it shows
is the cost of latency alone.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sim.scene import SUBSETS

__all__ = ["DEFAULT_CAP", "PRIOR_RIGS", "ReactiveSpec", "reactive_light", "rig_slots", "shares"]

#: Default boost cap (projector headroom): nominal drive is half the projector's maximum.
DEFAULT_CAP = 2.0

#: Rigs of the size prior reactive systems used (two or three projectors far apart), beside
#: the named subsets of the 5x5 array: P2, the two ends of its middle row, 1 m apart.
PRIOR_RIGS: dict[str, list[str]] = {"P2": ["r2c0", "r2c4"]}


def rig_slots(name: str) -> list[str]:
    """The slots of a named rig: a subset of :data:`sim.scene.SUBSETS` or of :data:`PRIOR_RIGS`."""
    if name in SUBSETS:
        return list(SUBSETS[name])
    if name in PRIOR_RIGS:
        return list(PRIOR_RIGS[name])
    raise ValueError(f"no rig {name!r}; rigs are {', '.join([*SUBSETS, *PRIOR_RIGS])}")


@dataclass(frozen=True)
class ReactiveSpec:
    """One reactive system: its projectors, its end-to-end latency and its compensation rule.

    Attributes
    ----------
    latency_s : float
        Detection to display, seconds (>= 0); applied in whole frames, see :meth:`latency_frames`.
    subset : str
        Name of the projectors it drives (:func:`rig_slots`).
    cap : float
        Largest gain of a projector relative to its nominal drive (>= 1).
    suppress : bool
        Also switch off, at the points where the hand blocked them, the projectors it blocked.
    """

    latency_s: float = 0.1
    subset: str = "P25"
    cap: float = DEFAULT_CAP
    suppress: bool = False

    def __post_init__(self) -> None:
        rig_slots(self.subset)
        if not (math.isfinite(self.latency_s) and self.latency_s >= 0):
            raise ValueError(f"latency must be >= 0 s, got {self.latency_s}")
        if not (math.isfinite(self.cap) and self.cap >= 1):
            raise ValueError(f"cap must be >= 1, got {self.cap}")

    def latency_frames(self, fps: float) -> int:
        """The latency in whole frames at ``fps`` (rounded: a frame shows what was solved that many frames earlier)."""
        return round(self.latency_s * fps)

    def name(self, fps: float) -> str:
        """``reactive_100ms``; ``_P9W`` for another rig than P25, ``_suppress`` when it suppresses.

        The milliseconds are the latency actually modelled (whole frames at ``fps``).
        """
        ms = round(1000.0 * self.latency_frames(fps) / fps)
        out = f"reactive_{ms}ms"
        if self.subset != "P25":
            out += f"_{self.subset}"
        if self.suppress:
            out += "_suppress"
        return out


def shares(weights: np.ndarray) -> np.ndarray:
    """Each projector's share of the light at each point.

    Parameters
    ----------
    weights : (n, P) float
        Full-white irradiance of n projectors at P points (>= 0).

    Returns
    -------
    (n, P) float32: ``weights / weights.sum(axis=0)``; 0 where no projector lights the point.
    """
    w = np.asarray(weights, np.float64)
    if w.ndim != 2:
        raise ValueError(f"weights must be (n, P), got shape {w.shape}")
    total = w.sum(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(total > 0, w / total, 0.0).astype(np.float32)


def _check(share: np.ndarray, blocked: Sequence[np.ndarray], what: str) -> None:
    if len(blocked) != share.shape[0]:
        raise ValueError(f"{what}: {len(blocked)} index arrays for {share.shape[0]} projectors")


def reactive_light(
    share: np.ndarray,
    seen: Sequence[np.ndarray],
    now: Sequence[np.ndarray],
    *,
    cap: float = DEFAULT_CAP,
    suppress: bool = False,
) -> np.ndarray:
    """The light a reactive system puts on each point (1 = the intended image).

    Parameters
    ----------
    share : (n, P) float32
        :func:`shares` of the system's n projectors.
    seen : sequence of n (k_i,) int arrays
        Per projector, the sorted flat point indices it saw blocked (at ``t - latency``).
    now : sequence of n (m_i,) int arrays
        Per projector, the sorted flat point indices blocked at ``t``.
    cap, suppress :
        As :class:`ReactiveSpec`.

    Returns
    -------
    (P,) float64 >= 0: ``sum over i not blocked now of gain_i * share_i`` (module docstring).
    """
    s = np.asarray(share)
    if s.ndim != 2:
        raise ValueError(f"share must be (n, P), got shape {s.shape}")
    _check(s, seen, "seen")
    _check(s, now, "now")
    if cap < 1:
        raise ValueError(f"cap must be >= 1, got {cap}")
    lost = np.zeros(s.shape[1], np.float64)
    for i, idx in enumerate(seen):
        if len(idx):
            lost[idx] += s[i, idx]
    lost = np.clip(lost, 0.0, 1.0)
    with np.errstate(divide="ignore"):
        boost = np.minimum(cap, 1.0 / np.maximum(1.0 - lost, 0.0))
    # Every projector at its gain: the seen-unblocked share at the boost, the seen-blocked share at 1 (or 0).
    light = boost * (1.0 - lost) + (0.0 if suppress else lost)
    # Points with no light at all stay dark (their shares are all 0).
    light[s.sum(axis=0) <= 0] = 0.0
    blocked_gain = 0.0 if suppress else 1.0
    for i, idx in enumerate(now):
        if not len(idx):
            continue
        gain = boost[idx]
        if len(seen[i]):
            gain = np.where(np.isin(idx, seen[i], assume_unique=True), blocked_gain, gain)
        light[idx] -= gain * s[i, idx]
    return np.maximum(light, 0.0)
