"""What a calibration run keeps in the rig directory, under ``calibration/``.

* ``run.json``: the run's id, status (``running``, ``complete``, ``incomplete``,
  ``interrupted``) and the fingerprint of its settings. A run that did not complete is
  resumed by the next one with the same fingerprint: projectors it already calibrated
  are skipped (``force`` starts afresh).
* ``cameras.json``: per camera the table -> camera mapping and/or its pinhole in the
  world (3D), and the registered mesh; a later run without known points reuses the
  table mappings (:func:`saved_table`), the alignment check and compensation read them.
* ``<slot>.json``: a projector's figures, written with its pose (:func:`save_slot`).
"""
from __future__ import annotations

import hashlib
import json
import math
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from coordinator.jobs import JobContext, JobError
from protos.store import atomic_write_json

if TYPE_CHECKING:   # named in annotations only: a coordinator's start (recovery) loads no calibration options
    from coordinator.calibration.options import CalibrateOptions, Inputs

#: Files of ``calibration/`` that are not a projector's figures.
_NOT_SLOTS = ("run.json", "cameras.json", "alignment.json")


def calibration_dir(rig_dir: str | Path) -> Path:
    return Path(rig_dir) / "calibration"


def rounded(x: float | None, nd: int = 4) -> float | None:
    """A figure for a JSON document: rounded, None when missing or not finite."""
    return None if x is None or not math.isfinite(x) else round(float(x), nd)


# ---------------------------------------------------------------------- the run
@dataclass
class Run:
    run_id: str
    resumed: bool
    done: set[str]      # slots this run calibrated before it was interrupted


def fingerprint(opts: CalibrateOptions, inputs: Inputs, saved_table: dict[int, dict]) -> str:
    """Identifies the settings a run's poses depend on (a run resumes only with the same)."""
    h = hashlib.blake2b(digest_size=8)
    for part in (opts.mode, opts.surface, opts.table_mm, opts.use_table, opts.seed, opts.rounds,
                 inputs.charuco, inputs.mesh_path):
        h.update(repr(part).encode())
    for s in inputs.table_points + inputs.landmarks:
        h.update(s.frame.encode() + bytes([s.camera]) + s.xyz.tobytes() + s.pixels.tobytes())
    if inputs.mesh_path and Path(inputs.mesh_path).exists():
        h.update(Path(inputs.mesh_path).read_bytes())
    for i in sorted(saved_table):
        h.update(np.asarray(saved_table[i]["H"], np.float64).tobytes())
    return h.hexdigest()


def start_run(rig_dir: str | Path, opts: CalibrateOptions, *, fingerprint: str, content_size: tuple[int, int],
              camera_specs: list[str]) -> Run:
    """Resume the interrupted run with the same settings, or start a new one (``opts.force``: always new)."""
    cdir = calibration_dir(rig_dir)
    fp = f"{fingerprint}:{content_size}:{','.join(camera_specs)}"
    f = cdir / "run.json"
    prev = _read(f)
    if prev and not opts.force and prev.get("status") != "complete" and prev.get("fingerprint") == fp:
        run_id = prev["run"]
        done = set()
        for p in cdir.glob("*.json"):
            if p.name in _NOT_SLOTS:
                continue
            doc = _read(p)
            if doc and doc.get("run") == run_id and doc.get("slot"):
                done.add(doc["slot"])
        atomic_write_json(f, {**prev, "status": "running", "resumed_at": time.time()})
        return Run(run_id, True, done)
    run_id = time.strftime("%Y%m%dT%H%M%S") + "-" + uuid.uuid4().hex[:6]
    atomic_write_json(f, {"run": run_id, "status": "running", "started_at": time.time(), "fingerprint": fp,
                          "mode": opts.mode, "surface": opts.surface})
    return Run(run_id, False, set())


def finish_run(rig_dir: str | Path, run: Run, status: str) -> None:
    f = calibration_dir(rig_dir) / "run.json"
    doc = _read(f) or {"run": run.run_id}
    atomic_write_json(f, {**doc, "status": status, "finished_at": time.time()})


def mark_interrupted(rig_dir: str | Path) -> Path | None:
    """At a coordinator's start: a run left ``running`` was stopped by a crash; mark it ``interrupted``
    (the next run with its settings still resumes it). The file changed, or None."""
    f = calibration_dir(rig_dir) / "run.json"
    doc = _read(f)
    if doc is None or doc.get("status") != "running":
        return None
    atomic_write_json(f, {**doc, "status": "interrupted", "interrupted_at": time.time()})
    return f


def _read(f: Path) -> dict | None:
    try:
        doc = json.loads(f.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    return doc if isinstance(doc, dict) else None


# ---------------------------------------------------------------------- cameras.json
def save_cameras(rig_dir: str | Path, doc: dict) -> None:
    atomic_write_json(calibration_dir(rig_dir) / "cameras.json", doc)


def saved_table(rig_dir: str | Path) -> dict[int, dict]:
    """The table -> camera mappings a previous run saved (calibration/cameras.json), by camera:
    ``{"H": (3, 3), "size": (w, h), "saved_at": time}``."""
    f = calibration_dir(rig_dir) / "cameras.json"
    if not f.exists():
        return {}
    try:
        doc = json.loads(f.read_text())
        return {int(c["camera"]): {"H": np.array(c["table_to_camera"], np.float64), "size": tuple(c["size"]),
                                   "saved_at": doc.get("saved_at")}
                for c in doc.get("cameras", []) if "table_to_camera" in c}
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise JobError(f"{f}: cannot read the saved table mapping ({exc}); give table points or a board again") from exc


# ---------------------------------------------------------------------- per projector
def slot_doc(run: Run, slot: str, opts: CalibrateOptions, *, rms: float, mx: float, points: int, **extra) -> dict:
    """A projector's figures: residual rms/max (projector px) over ``points``; ``extra`` keys ending
    in ``rms`` get ``_px``."""
    doc = {"run": run.run_id, "slot": slot, "mode": opts.mode, "surface": opts.surface,
           "rms_px": rounded(rms), "max_px": rounded(mx), "points": int(points), "finished_at": time.time()}
    for k, v in extra.items():
        doc[k if not k.endswith("rms") else k + "_px"] = rounded(v) if isinstance(v, float) else v
    return doc


def save_slot(ctx: JobContext, slot: str, pose, doc: dict) -> None:
    """Persist a projector's pose (pushed to its node at once) and its figures."""
    ctx.set_pose(slot, pose, source="calibration")
    atomic_write_json(calibration_dir(ctx.rig.path) / f"{slot}.json", doc)


def resumed_results(rig_dir: str | Path, slots: list[str]) -> dict[str, dict]:
    """The figures of ``slots`` saved by an earlier part of the run, marked ``resumed``."""
    out = {}
    for s in slots:
        doc = _read(calibration_dir(rig_dir) / f"{s}.json")
        if doc is not None:
            out[s] = {**doc, "resumed": True}
    return out
