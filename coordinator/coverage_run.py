"""Computing, storing and picturing a rig's coverage: one function for `shadowless coverage`
(offline, on a rig directory) and the coordinator's ``coverage`` job (the console's Jobs form,
while the coordinator serves the rig).

It reads the slots' 3x4 poses onto the mesh (calibrated, or with ``planned`` the poses a layout
gave them: :func:`coordinator.coverage_store.rig_projectors`), counts per texel the projectors that
reach it and their shares (:mod:`coordinator.coverage`), draws the heat map from the requested
viewpoints (:mod:`coordinator.coverage_figure`) and writes everything under ``coverage/``
(:mod:`coordinator.coverage_store`; the picture elsewhere when the operator names a file).
"""
from __future__ import annotations

import argparse
import re
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from coordinator.coverage import DEFAULT_SHADOW_SCALE, DEFAULT_TEXTURE, CoverageModel
from coordinator.coverage_figure import coverage_picture, orbit_camera
from coordinator.coverage_store import coverage_dir, rig_camera, rig_projectors, save_coverage
from coordinator.rig import Rig
from protos.store import atomic_write_bytes
from protos import cli_types
from protos.wording import count

__all__ = ["View", "view", "default_views", "compute_coverage"]

#: ("orbit", (azimuth, elevation) degrees) or ("camera", calibrated camera index)
View = tuple[str, object]

_VIEW = re.compile(r"^camera(?::(\d+))?$")


def view(text: str) -> View:
    """``"30,20"`` -> ("orbit", (30.0, 20.0)); ``"camera"`` / ``"camera:1"`` -> ("camera", index).
    argparse.ArgumentTypeError naming what a view is otherwise."""
    m = _VIEW.match(text.strip())
    if m:
        return "camera", int(m.group(1) or 0)
    try:
        az, el = cli_types.pair(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a view: AZ,EL in degrees (e.g. 30,20) or camera[:N]") from None
    if not -90.0 <= el <= 90.0:
        raise argparse.ArgumentTypeError(f"{text!r}: the elevation must be -90..90 degrees")
    return "orbit", (az, el)


def default_views(vertices: np.ndarray) -> list[View]:
    """A flat surface (a table) from above; an object from the front and from behind, 20 degrees up."""
    if float(np.ptp(np.asarray(vertices)[:, 2])) < 1e-6:
        return [("orbit", (0.0, 90.0))]
    return [("orbit", (0.0, 20.0)), ("orbit", (180.0, 20.0))]


def compute_coverage(rig: Rig, *, slots: Sequence[str] | None = None, planned: bool = False,
                     views: Sequence[View] | None = None, texture: tuple[int, int] = DEFAULT_TEXTURE,
                     shadow_scale: int = DEFAULT_SHADOW_SCALE, falloff: float = 1.0,
                     panel: tuple[int, int] = (480, 480), out: str | Path | None = None,
                     progress: Callable[[str], None] = lambda text: None) -> dict:
    """Compute the coverage of ``rig``, store it, draw it; the summary (JSON-able) with what was written.

    Blocking (GL and numpy): call it from a worker thread in a server. Raises RigError or
    CalibrationError (one line) for a rig without 3D poses, an unknown slot, or a camera view
    without a calibrated camera.

    Returns
    -------
    dict: :meth:`coordinator.coverage.Coverage.summary` plus ``rig``, ``mesh``, ``poses``
    ("calibrated" or "planned"), ``computed_at``, ``seconds``, ``picture``, ``views``, ``layout``
    (the picture's panels and colour bar) and ``files``.
    """
    t0 = time.monotonic()
    mesh, projectors = rig_projectors(rig, list(slots) if slots else None, planned=planned)
    chosen = []
    for kind, value in views or default_views(mesh.vertices):
        if kind == "camera":
            chosen.append((f"camera {value}", rig_camera(rig.path, value)))
        else:
            az, el = value
            chosen.append((f"az {az:g} el {el:g}", orbit_camera(mesh.vertices, az, el, size=panel)))
    progress(f"{count(len(projectors), 'projector')}{' as planned' if planned else ''} onto mesh {mesh.mesh_id} "
             f"({len(mesh.vertices)} vertices, {len(mesh.faces)} triangles): shadow maps")
    with CoverageModel(mesh.vertices, mesh.faces, mesh.uvs, projectors, shadow_scale=shadow_scale,
                       falloff=falloff) as model:
        progress(f"sampling {texture[0]}x{texture[1]} texels")
        cov = model.texture(texture)
        progress("drawing the picture")
        png, layout = coverage_picture(cov, model.raster, chosen)
    picture = Path(out) if out else coverage_dir(rig.path) / "coverage.png"
    atomic_write_bytes(picture, png)
    doc = {**cov.summary(), "rig": rig.config.name, "mesh": mesh.mesh_id, "poses": "planned" if planned else "calibrated",
           "computed_at": time.time(), "seconds": round(time.monotonic() - t0, 2), "picture": str(picture),
           "views": [label for label, _ in chosen], "layout": layout}
    npz, js = save_coverage(rig.path, cov, doc)
    doc["files"] = [str(npz), str(js), str(picture)]
    return doc
