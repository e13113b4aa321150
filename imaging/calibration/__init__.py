"""Geometric calibration's numerics: from camera pictures of patterns to table mappings and poses.

``graycode``        Gray-code patterns and the vectorised decoder (dense camera <-> projector pixels).
``planar``          table <-> camera mapping (known points, ChArUco), robust homographies, pose composition.
``multiplex``       the constant-capture mode: every projector at once (coded dots, then an interleaved lattice).
``multiplex3d``     the same on a 3D object.
``threed``          meshes, camera posing, mesh registration, ray casting, projector intrinsics and pose.
``points``          the known-points / landmark file format.
``alignment``       the residual-misalignment check's numerics; ``heatmap_figure`` draws it.

The jobs that capture and store (``calibrate``, ``alignment``) are in :mod:`coordinator.calibration`.
"""
