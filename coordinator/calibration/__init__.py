"""Geometric calibration: from a freshly mounted rig to the poses nodes render with.

Modules (numerics first, then the jobs, the command line last):

``graycode``       Gray-code patterns and the vectorised decoder (dense camera <-> projector pixels).
``planar``         table <-> camera mapping (known points, ChArUco), robust homographies, pose composition.
``multiplex``      the constant-capture mode: every projector at once (coded dots, then an interleaved lattice).
``threed``         meshes, camera posing, mesh registration, ray casting, projector intrinsics and pose.
``points``         the known-points / landmark file format.
``alignment``      the residual-misalignment check's numerics and its heat map.
``options``        the options of both jobs (validation, command-line flags, rig.toml defaults).
``runs``           what a calibration run keeps in the rig directory (run.json, cameras.json, per slot).
``stages``         the calibrate job's stages: exposure, cameras, sequential, multiplexed, 3D.
``calibrate_job``  the ``calibrate`` job.
``alignment_job``  the ``alignment`` job.
``cli``            ``shadowless calibrate`` and ``shadowless alignment``.
"""
