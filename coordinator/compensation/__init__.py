"""The compensation jobs: what the coordinator runs to measure and compensate a rig's light.

The numerics they call (luminance response, light transport, the bounded least-squares solve,
texture space) live in :mod:`imaging.compensation`; this package holds what needs the rig.

Jobs (each ``OPTIONS`` + ``async run(ctx, opts) -> Result``, a typed result; see
:mod:`coordinator.jobs`): :mod:`.response_job`, :mod:`.transport_job`, :mod:`.compensate_job`,
:mod:`.sequence_job` (frames played live) and :mod:`.video_job` (a video asset into a compensated
16-bit asset), the last two over :mod:`.frames` (warm-started frame by frame). ``transport`` and
``compensate`` have one body each over a :class:`~.surface.Surface` (:mod:`.surfaces` picks it):
a table's (:mod:`.planar_surface`, measuring through :mod:`.planar_transport`) or a mesh's
(:mod:`.mesh_surface`, over :mod:`.mesh_transport` and :mod:`.mesh_compensate`, in texture space);
the evaluation they share in :mod:`.evaluation`; their options in
:mod:`.options`, what they store in :mod:`.store`, images as job parameters in
:mod:`.image_param`, video assets decoded and FFV1 written in :mod:`.video_io`, a video split
over a Dask cluster in :mod:`.cluster`.
"""
