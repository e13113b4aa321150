"""Where a rig keeps its coverage: ``coverage/`` in the rig directory, every write atomic.

* ``coverage/coverage.npz``: the per-texel arrays (``slots``, ``mask``, ``area``, ``count``,
  ``reach`` packed one bit per slot along the first axis, ``irradiance`` as float16, ``points``,
  ``normals``), compressed, and the summary as JSON text (``summary``: what coverage.json is
  completed from when a crash came between the two writes);
* ``coverage/coverage.json``: the summary (:meth:`coordinator.coverage.Coverage.summary`), the
  mesh it was computed for, the views of the picture and when;
* ``coverage/coverage.png``: the picture (unless the operator named another file).

Also the reading of what coverage needs from a rig: the slots posed onto one mesh
(:func:`rig_projectors`) and a calibrated camera (:func:`rig_camera`).
"""
from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from imaging.calibration.threed import Pinhole
from coordinator.coverage import Coverage, Projector, projector_from_pose
from coordinator.errors import RigError
from coordinator.rig import Mesh, ProjectionPose, Rig
from protos.store import atomic_file, atomic_write_json

__all__ = ["coverage_dir", "save_coverage", "load_coverage", "rig_projectors", "rig_camera", "summary_behind"]


def coverage_dir(rig_dir: str | Path) -> Path:
    return Path(rig_dir) / "coverage"


def save_coverage(rig_dir: str | Path, cov: Coverage, doc: dict) -> tuple[Path, Path]:
    """Write ``coverage.npz`` and ``coverage.json`` (``doc``) under the rig's ``coverage/``."""
    d = coverage_dir(rig_dir)
    npz, js = d / "coverage.npz", d / "coverage.json"
    with atomic_file(npz) as f:     # the summary rides along: a crash before coverage.json is completed from it
        np.savez_compressed(f, slots=np.array(cov.slots), mask=cov.mask, area=cov.area, count=cov.count,
                            reach=np.packbits(cov.reach, axis=0), irradiance=cov.irradiance.astype(np.float16),
                            points=cov.points, normals=cov.normals, summary=np.asarray(json.dumps(doc, sort_keys=True)))
    atomic_write_json(js, doc)
    return npz, js


def summary_behind(rig_dir: str | Path) -> dict | None:
    """The summary ``coverage.npz`` carries when ``coverage.json`` is missing or another one (a crash
    came between the two writes of :func:`save_coverage`); None when they agree or cannot be told."""
    d = coverage_dir(rig_dir)
    try:
        with np.load(d / "coverage.npz", allow_pickle=False) as z:
            if "summary" not in z.files:
                return None
            text = str(z["summary"])
        doc = json.loads(text)
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None         # none, or unreadable: load_coverage says so when it is asked for
    try:
        if json.dumps(json.loads((d / "coverage.json").read_text()), sort_keys=True) == text:
            return None
    except (FileNotFoundError, ValueError):
        pass
    return doc


def load_coverage(path: str | Path) -> Coverage:
    """A :class:`Coverage` read back from ``coverage.npz`` (irradiance at float16 precision)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            slots = tuple(str(s) for s in z["slots"])
            reach = np.unpackbits(z["reach"], axis=0, count=len(slots)).astype(bool)
            return Coverage(slots, z["mask"].astype(bool), z["area"], z["points"], z["normals"], reach,
                            z["irradiance"].astype(np.float32))
    except (OSError, KeyError, ValueError, EOFError) as exc:
        raise RigError(" ".join(f"{path}: cannot read the coverage ({exc})".split())) from None


def rig_projectors(rig: Rig, slots: list[str] | None = None, *, planned: bool = False) -> tuple[Mesh, list[Projector]]:
    """The rig's mesh and its projectors posed onto it (each slot's 3x4 pose, output size and gain).

    ``planned``: the slots' planned poses (``rig init --layout``) instead of their calibrated ones.
    Raises RigError (one line) when no slot has a 3D pose, when the slots render different meshes
    or when a named slot is unknown or has no 3D pose.
    """
    names = list(rig.slots) if slots is None else list(slots)
    for s in names:
        rig.slot(s)        # unknown slot: one line naming the rig's slots
    pose_of = (lambda st: st.planned) if planned else (lambda st: st.pose)
    what = "planned pose" if planned else "3D pose (a projection onto a mesh)"
    posed = {s: pose_of(rig.slots[s]) for s in names if isinstance(pose_of(rig.slots[s]), ProjectionPose)}
    if slots is not None and len(posed) < len(names):
        missing = [s for s in names if s not in posed]
        raise RigError(f"slot(s) {', '.join(missing)} have no {what}")
    if not posed:
        if planned:
            raise RigError("no slot of the rig has a planned pose: they come from `shadowless rig init DIR --layout FILE`, "
                           "and a calibration replaces them")
        planar = any(st.pose is not None for st in rig.slots.values())
        plan = any(st.planned is not None for st in rig.slots.values())
        raise RigError(f"no slot of the rig has a {what}"
                       + ("; its poses are planar: coverage is for rigs that project onto an object" if planar else
                          "; its poses are only planned (rig init --layout): pass --planned for the plan's coverage"
                          if plan else "; calibrate the rig on its mesh first (shadowless calibrate --mesh ...)"))
    meshes = {pose.mesh.mesh_id for pose in posed.values()}
    if len(meshes) > 1:
        raise RigError(f"the slots render different meshes ({', '.join(sorted(meshes))}); give --slots that share one")
    mesh = next(iter(posed.values())).mesh
    return mesh, [projector_from_pose(s, pose.matrix, (rig.slots[s].width, rig.slots[s].height), gain=rig.slots[s].gain)
                  for s, pose in posed.items()]


def rig_camera(rig_dir: str | Path, index: int) -> Pinhole:
    """Camera ``index`` as 3D calibration posed it (``calibration/cameras.json``)."""
    f = Path(rig_dir) / "calibration" / "cameras.json"
    try:
        doc = json.loads(f.read_text())
    except FileNotFoundError:
        raise RigError(f"no calibrated camera in this rig ({f} is missing): use --view AZ,EL") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise RigError(f"{f}: cannot read it ({exc})") from None
    for c in doc.get("cameras", []) if isinstance(doc, dict) else []:
        if isinstance(c, dict) and c.get("camera") == index:
            if "pinhole" not in c:
                break
            try:
                return Pinhole.from_dict(c["pinhole"])
            except (KeyError, TypeError, ValueError) as exc:
                raise RigError(f"{f}: camera {index}'s pose is unreadable ({exc})") from None
    raise RigError(f"camera {index} was not posed in 3D ({f}); calibrate the mesh with it, or use --view AZ,EL")
