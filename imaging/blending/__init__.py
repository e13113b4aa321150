"""Per-pixel blending: each projector's measured contribution, a target every point can reach,
and the alpha (gain) and beta (black offset) maps that make the rig's light even.

* :mod:`~imaging.blending.contributions`: :class:`Contributions`, each projector's light on a
  camera grid, and the grid's geometry;
* :mod:`~imaging.blending.sample_plan`: the multiplexed blob captures (the capture count barely
  grows with the number of projectors);
* :mod:`~imaging.blending.samples`: reading the blobs of a capture;
* :mod:`~imaging.blending.fit`: a smooth model of each projector's light fitted to its samples;
* :mod:`~imaging.blending.envelope`: the Lipschitz envelope of a surface (two-pass chamfer);
* :mod:`~imaging.blending.solve`: :func:`compute_blend`, the target and the maps;
* :mod:`~imaging.blending.metrics`: :func:`uniformity` and :func:`seam_step`.

Modules are imported on use, so ``import imaging.blending`` costs nothing.
"""
