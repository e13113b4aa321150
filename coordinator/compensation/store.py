"""What the compensation jobs keep in the rig directory, and when it is still valid.

Layout (every write atomic, :mod:`protos.store`)::

    compensation/responses/<slot>.json   fitted response of a projector (its LUT is in luts/)
    compensation/response.json           brightness match and linearity of the last run
    compensation/transport.npz           L and its metadata (fingerprint, radius, spacing, ...)
    compensation/transport.json          the same metadata, readable
    compensation/black-<fp>.npy          (Hc, Wc, 3) float32 black capture of that measurement
    compensation/baseline/<slot>.npz     the per-projector L_i (baseline only)
    compensation/result.json             figures of the last solve (the result is the content)
    compensation/quality.json, .png      the last evaluation
    compensation/sequence.json           figures of the last compensated sequence

Fingerprints tie a stored result to what it depends on: a response to the slot's size, pose,
the patch layout and the camera (:func:`response_fingerprint`); ``L`` to the rig's state
(content size, camera and its calibration, every slot's size, gain, pose and LUT:
:func:`rig_state_fingerprint`) and the dot grid it was measured with
(:func:`transport_fingerprint`); a baseline ``L_i`` to that ``L`` and its own capture settings
(:func:`baseline_fingerprint`).
"""
from __future__ import annotations

import hashlib
import json
import time
import zipfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from imaging.compensation.errors import TransportFileError
from imaging.compensation.response import FittedResponse
from imaging.compensation.transport import load_transport, save_transport
from coordinator.rig import HomographyPose, Rig, hash_slot_state
from protos.store import atomic_save_npy, atomic_write_json

__all__ = [
    "SUBDIR",
    "compensation_dir",
    "write_result",
    "response_path",
    "response_fingerprint",
    "save_response",
    "load_stored_response",
    "StoredTransport",
    "rig_state_fingerprint",
    "transport_fingerprint",
    "load_valid_transport",
    "save_measured_transport",
    "stored_transport_meta",
    "transport_summary",
    "baseline_fingerprint",
    "load_baseline_transport",
    "stored_baselines",
    "save_baseline_transport",
]

SUBDIR = "compensation"


def compensation_dir(rig: Rig) -> Path:
    """``<rig>/compensation``."""
    return Path(rig.path) / SUBDIR


def write_result(rig: Rig, name: str, doc: Mapping[str, Any]) -> None:
    """Store a job's figures as ``compensation/<name>`` with the time it finished."""
    atomic_write_json(compensation_dir(rig) / name, {**doc, "finished_at": time.time()})


# ---------------------------------------------------------------------- responses
def response_path(rig: Rig, slot: str) -> Path:
    return compensation_dir(rig) / "responses" / f"{slot}.json"


def response_fingerprint(rig: Rig, slot: str, *, mode: str, levels: int, grid: tuple[int, int], repeats: int,
                         seed: int, camera_spec: str, camera: int, frames: int, homography: np.ndarray | None) -> str:
    """What a measured response depends on: the slot's size and pose, the patches shown, the camera."""
    st = rig.slot(slot)
    h = hashlib.blake2b(digest_size=8)
    h.update(repr((slot, st.width, st.height, mode, levels, tuple(grid), repeats, seed, camera_spec, camera,
                   frames)).encode())
    if isinstance(st.pose, HomographyPose):
        h.update(st.pose.matrix.tobytes())
    if homography is not None:
        h.update(np.asarray(homography, np.float64).tobytes())
    return h.hexdigest()


def _response_doc(resp: FittedResponse) -> dict:
    return {"levels": resp.levels.tolist(), "curve": resp.curve.tolist(), "black": resp.black.tolist(),
            "peak": resp.peak.tolist(), "gamma": resp.gamma.tolist()}


def _response_from_doc(doc: dict) -> FittedResponse:
    return FittedResponse(levels=np.asarray(doc["levels"], np.float64), curve=np.asarray(doc["curve"], np.float64),
                          black=np.asarray(doc["black"], np.float64), peak=np.asarray(doc["peak"], np.float64),
                          gamma=np.asarray(doc["gamma"], np.float64))


def save_response(rig: Rig, slot: str, resp: FittedResponse, doc: Mapping[str, Any]) -> dict:
    """Store a slot's fitted response with its figures ``doc``; the stored document."""
    out = {**doc, "response": _response_doc(resp)}
    atomic_write_json(response_path(rig, slot), out)
    return out


def load_stored_response(path: Path, fingerprint: str | None) -> tuple[FittedResponse, dict] | None:
    """A stored response and its document, if readable and (unless ``fingerprint`` is None) still valid."""
    try:
        doc = json.loads(Path(path).read_text())
        if fingerprint is not None and doc.get("fingerprint") != fingerprint:
            return None
        return _response_from_doc(doc["response"]), doc
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError):
        return None


# ---------------------------------------------------------------------- light transport
@dataclass
class StoredTransport:
    """A measured (or reloaded) rig light transport and what it was measured with."""

    L: sp.csr_matrix
    meta: dict
    black: np.ndarray           # (Hc, Wc, 3) float32
    H: np.ndarray               # (3, 3) content -> camera; on a mesh the camera's (3, 4) projection
    camera_shape: tuple[int, int]
    slots: list[str]
    reused: bool

    @property
    def content_shape(self) -> tuple[int, int]:
        return int(self.meta["content_size"][1]), int(self.meta["content_size"][0])


def rig_state_fingerprint(rig: Rig, slots: Sequence[str], H: np.ndarray, camera: int) -> str:
    """What a measured ``L`` depends on in the rig: content size, camera, and each slot's size, gain, pose, LUT."""
    h = hashlib.blake2b(digest_size=10)
    # the camera is identified by its index and its calibration (H), not by how it is reached (its spec)
    h.update(repr((rig.config.content_width, rig.config.content_height, camera)).encode())
    h.update(np.asarray(H, np.float64).tobytes())
    for s in sorted(slots):
        h.update(f"{s}:".encode())
        hash_slot_state(h, rig.slot(s))
    return h.hexdigest()


def transport_fingerprint(state: str, radius: int, spacing: int | None, frames: int, *, core: int | None = None) -> str:
    """One measurement: the rig's state and the dot grid it was measured with (names its black capture and
    ties the baseline's ``L_i`` to it); ``core``: the windows' radius kept per texel when the tails beyond it
    are averaged over neighbours (:mod:`imaging.compensation.psf_tails`)."""
    key = (state, radius, spacing, frames) if core is None else (state, radius, spacing, frames, "tails", core)
    return hashlib.blake2b(repr(key).encode(), digest_size=10).hexdigest()


def load_valid_transport(rig: Rig, state: str, wanted: Mapping[str, Any], H: np.ndarray, slots: list[str], *,
                         log: Callable[[str], None]) -> StoredTransport | None:
    """The stored ``L`` if it was measured with the rig as it is now and with every option in ``wanted``
    (the measurement options the caller set: radius, spacing, frames)."""
    d = compensation_dir(rig)
    f = d / "transport.npz"
    if not f.exists():
        return None
    try:
        L, meta = load_transport(f)
    except TransportFileError as exc:
        log(f"stored light transport ignored: {exc}")
        return None
    if meta.get("rig_state") != state:
        return None
    if any(meta.get(k) != v for k, v in wanted.items()):
        return None
    try:
        black = np.load(d / str(meta["black_file"]), allow_pickle=False).astype(np.float32)
        cam = (int(meta["camera_size"][1]), int(meta["camera_size"][0]))
    except (OSError, KeyError, ValueError, TypeError) as exc:
        log(f"stored light transport ignored: its black capture is unreadable ({exc})")
        return None
    if black.shape != (*cam, 3) or L.shape[0] != cam[0] * cam[1]:
        return None
    return StoredTransport(L, meta, black, H, cam, slots, True)


def save_measured_transport(rig: Rig, L: sp.csr_matrix, meta: dict, black: np.ndarray) -> None:
    """Store a new ``L`` (``meta["black_file"]`` names its black capture); older black captures go."""
    d = compensation_dir(rig)
    atomic_save_npy(d / meta["black_file"], black)
    save_transport(d / "transport.npz", L, meta)
    atomic_write_json(d / "transport.json", meta)
    for old in d.glob("black-*.npy"):
        if old.name != meta["black_file"]:
            old.unlink(missing_ok=True)


def stored_transport_meta(comp_dir: str | Path) -> dict | None:
    """The metadata ``transport.npz`` in ``comp_dir`` carries, read without its arrays; None when there
    is none or it cannot be read (:func:`load_valid_transport` says why when a job asks for it)."""
    try:
        with np.load(Path(comp_dir) / "transport.npz", allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None
    if not isinstance(meta, dict):
        return None
    meta.pop("format", None)
    return meta


def transport_summary(tr: StoredTransport) -> dict:
    """The figures of a light-transport measurement a job reports."""
    m = tr.meta
    return {"reused": tr.reused, "captures": m["captures"], "patterns": m["patterns"], "spacing": m["spacing"],
            "radius": m["radius"], "frames": m["frames"], "seconds": m["seconds"], "nnz": m["nnz"],
            "edge_energy": m.get("edge_energy"),
            **({"core": m["core"], "tails_averaged": m["tails_averaged"]} if "tails_averaged" in m else {}),
            **({"exposure": m["exposure"], "white_peak": m["white_peak"]} if "exposure" in m else {}),
            **({"dot_gain": m["dot_gain"], "patterns_captured_again": m["patterns_captured_again"]}
               if "dot_gain" in m else {}),
            "shape": list(tr.L.shape), "slots": len(tr.slots), "date": m["date"], "fingerprint": m["fingerprint"],
            "file": f"{SUBDIR}/transport.npz"}


# ---------------------------------------------------------------------- the baseline's L_i
def baseline_fingerprint(transport: str, frames: int, exposure: float) -> str:
    """A baseline ``L_i``: the rig's ``L`` measurement it belongs to and its own capture settings."""
    return hashlib.blake2b(f"{transport}:{frames}:{exposure!r}".encode(), digest_size=10).hexdigest()


def _baseline_path(rig: Rig, slot: str) -> Path:
    return compensation_dir(rig) / "baseline" / f"{slot}.npz"


def load_baseline_transport(rig: Rig, slot: str, fingerprint: str, shape: tuple[int, int]) -> sp.csr_matrix | None:
    """A slot's stored ``L_i`` if it carries ``fingerprint`` and has ``shape``."""
    try:
        Li, meta = load_transport(_baseline_path(rig, slot))
    except TransportFileError:
        return None
    return Li if meta.get("fingerprint") == fingerprint and Li.shape == tuple(shape) else None


def stored_baselines(rig: Rig, slots: list[str], fingerprint: str,
                     shape: tuple[int, int]) -> tuple[dict[str, sp.csr_matrix], list[str]]:
    """The slots' stored ``L_i`` that are still valid (:func:`load_baseline_transport`), and the
    slots, in order, whose ``L_i`` must be measured."""
    found: dict[str, sp.csr_matrix] = {}
    todo: list[str] = []
    for s in slots:
        Li = load_baseline_transport(rig, s, fingerprint, shape)
        if Li is None:
            todo.append(s)
        else:
            found[s] = Li
    return found, todo


def save_baseline_transport(rig: Rig, slot: str, Li: sp.csr_matrix, meta: Mapping[str, Any]) -> None:
    save_transport(_baseline_path(rig, slot), Li, dict(meta))
