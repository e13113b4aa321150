"""The ``calibrate`` job: every projector's pose, from the camera(s).

Stages (each reports progress per stage and projector; :mod:`coordinator.calibration.stages`):

1. **exposure**: every projector black, then white, per camera: fails early and clearly
   when a camera is under-exposed.
2. **cameras**: the table -> camera mapping of every camera (known points from the rig
   file or a points file, a ChArUco board lying on the table, or the mapping an earlier run
   saved) and, for a mesh, each camera's pose in the world and the mesh's registration.
   Saved in ``calibration/cameras.json``.
3. **projectors**: *multiplexed* (planar default; captures independent of the projector
   count): every projector at once, coded dots then an interleaved lattice, on the table or,
   lifted onto the surface by the camera's rays, on a mesh (3D). *sequential* (the paper's
   method, the reference; mesh default): per projector, white and black references and the
   Gray-code patterns, on the table or cast onto the mesh (3D).

Each projector's pose is stored and pushed to its node as soon as it is computed, with its
figures in ``calibration/<slot>.json``. A run that stops half-way (Ctrl-C, a failed
projector, a crash) resumes: the next run with the same settings skips the projectors this
run already calibrated (``force`` starts afresh; :mod:`coordinator.calibration.runs`). A run
with ``record`` saves every capture (``record/camera<i>/000001.png``, ...) so that
``cameras = ["folder:record/camera0"]`` replays it offline.

The options, and rig.toml's ``[calibration]`` table that sets their defaults for a rig, are
:class:`coordinator.calibration.options.CalibrateOptions`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from coordinator.calibration import runs
from coordinator.calibration.options import CalibrateOptions, Inputs, decide, resolve, rig_defaults
from coordinator.calibration.stages.cameras import map_cameras
from coordinator.calibration.stages.dots import multiplexed
from coordinator.calibration.stages.dots3d import multiplexed_3d
from coordinator.calibration.stages.exposure import exposure
from coordinator.calibration.stages.gray import sequential
from coordinator.calibration.stages.mesh import sequential_3d
from coordinator.calibration.stages.state import State
from coordinator.jobs import JobContext, JobError
from coordinator.jobs.results import Figures, JobResult
from coordinator.rig import Rig
from protos.wording import count

OPTIONS = CalibrateOptions


@dataclass(frozen=True, kw_only=True)
class CalibrateResult(JobResult):
    """The ``calibrate`` job's result: the run (its id, mode, surface, whether it resumed), its captures and
    cameras, per projector its figures (:func:`~coordinator.calibration.runs.slot_doc`; ``resumed`` for those
    an earlier part of the run calibrated), those that failed and why, and each camera's set-up."""

    run: str
    mode: str
    surface: str
    resumed: bool
    captures: int
    cameras: int
    wall_s: float
    slots: dict[str, Figures]
    failed: dict[str, str]
    camera_setup: list[Figures]


def _saved_table(opts: CalibrateOptions, inputs: Inputs, rig_dir: Path) -> dict[int, dict]:
    """Without known points or a board given, the table mappings an earlier run saved: each camera
    uses its own unless it sees a board on the table (the cameras stage looks for one), and none
    when this run is to map the table afresh (``table_only``)."""
    if inputs.table_points or inputs.charuco is not None or opts.table_only:
        return {}
    return runs.saved_table(rig_dir)


def option_defaults(rig: Rig) -> tuple[dict, str]:
    """rig.toml's ``[calibration]`` table fills in what a request leaves out."""
    return rig_defaults(rig.path)


async def run(ctx: JobContext, opts: CalibrateOptions) -> CalibrateResult:
    """Calibrate the rig's projectors (see the module docstring); returns per-slot figures."""
    t0 = time.monotonic()
    rig = ctx.rig
    rig_dir = Path(rig.path)
    opts = decide(opts)
    inputs = resolve(opts, rig_dir)
    saved = _saved_table(opts, inputs, rig_dir)
    if ctx.camera_count == 0:
        raise JobError("no camera: set `cameras = [\"room://HOST:PORT\"]` in rig.toml, start the coordinator "
                       "with --camera, or pass --camera to `shadowless calibrate`")
    specs = [ctx.camera_spec(i) for i in range(ctx.camera_count)]
    slots = ctx.select_slots(opts.slots)
    content_size = (rig.config.content_width, rig.config.content_height)
    current = runs.start_run(rig_dir, opts, fingerprint=runs.fingerprint(opts, inputs, saved), content_size=content_size,
                          camera_specs=specs)
    done = current.done & set(slots)
    todo = [s for s in slots if s not in done]
    ctx.log(f"calibration run {current.run_id} ({'resumed' if current.resumed else 'new'}): {opts.mode} mode, "
            f"{opts.surface} surface, {count(len(specs), 'camera')}, {len(todo)} of {count(len(slots), 'projector')} to do"
            + (f" ({', '.join(sorted(done))} already done in this run)" if done else ""))
    if opts.record:
        ctx.record_captures(opts.record)
    st = State(ctx, opts, inputs, current, slots, todo, {s: ctx.projector_size(s) for s in slots},
               list(range(len(specs))), content_size, saved_table=saved)
    status = "interrupted"      # resumable, like "incomplete"; only "complete" makes the next run start afresh
    try:
        await exposure(st)
        await map_cameras(st)
        if opts.table_only:
            st.todo = []
            ctx.log("table mapped (calibration/cameras.json); remove the board and run `shadowless calibrate` again")
        if st.todo:
            if opts.surface == "table" and opts.mode == "multiplexed":
                await multiplexed(st)
            elif opts.surface == "table":
                await sequential(st)
            elif opts.mode == "multiplexed":
                await multiplexed_3d(st)
            else:
                await sequential_3d(st)
        status = "complete" if not st.failed else "incomplete"
    finally:
        runs.finish_run(rig_dir, current, status)
    results = {**runs.resumed_results(rig_dir, [s for s in slots if s in done and s not in st.results]), **st.results}
    summary = CalibrateResult(
        run=current.run_id, mode=opts.mode, surface=opts.surface, resumed=current.resumed,
        captures=st.shots, cameras=len(st.cameras), wall_s=round(time.monotonic() - t0, 3),
        slots={s: results[s] for s in slots if s in results}, failed=st.failed,
        camera_setup=st.setup.summary(),
    )
    if st.failed:
        raise JobError(f"calibrated {len(summary.slots)} of {count(len(slots), 'projector')} (saved; run again to retry "
                       "the others); " + "; ".join(st.failed.values()))
    return summary
