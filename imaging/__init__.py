"""The numerics of shadowless: structured light, geometric calibration, light transport and blur compensation.

Pure functions and small value types over NumPy arrays (SciPy, OpenCV and scikit-image where they
do the work), with no rig directory, no jobs, no network and no event loop. The coordinator's jobs
(:mod:`coordinator.calibration`, :mod:`coordinator.compensation`) call them; benchmarks and the
studies call them directly. Every module states the shapes and dtypes it takes and returns.

* :mod:`imaging.calibration` — Gray codes, planar homographies, multiplexed dots, 3D posing,
  the known-points format, the alignment check;
* :mod:`imaging.compensation` — luminance response, light transport, the bounded least-squares
  solvers, texture space, quality measures, a synthetic rig;
* :mod:`imaging.channel_mean` and :mod:`imaging.errors`, shared by both.
"""
