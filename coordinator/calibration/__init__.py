"""Geometric calibration: from a freshly mounted rig to the poses nodes render with.

Modules (numerics first, orchestration last):

``graycode``   Gray-code patterns and the vectorised decoder (dense camera <-> projector pixels).
``planar``     table <-> camera mapping (known points, ChArUco), robust homographies, pose composition.
``multiplex``  the constant-capture mode: every projector at once (coded dots, then an interleaved lattice).
``threed``     meshes, camera posing, mesh registration, ray casting, projector intrinsics and pose.
``points``     the known-points / landmark file format.
``alignment``  the residual-misalignment check and its heat map.
``job``        the ``calibrate`` and ``alignment`` coordinator jobs.
``cli``        ``shadowless calibrate`` and ``shadowless alignment``.
"""
