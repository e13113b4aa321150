"""Geometric calibration jobs: from a freshly mounted rig to the poses nodes render with.

The numerics (Gray codes, homographies, multiplexed dots, 3D posing) are in
:mod:`imaging.calibration`; this package captures through the job seam and stores results.

``options``        the options of both jobs (validation, command-line flags, rig.toml defaults).
``runs``           what a calibration run keeps in the rig directory (run.json, cameras.json, per slot).
``stages``         the calibrate job's stages: exposure, cameras, sequential, multiplexed, 3D.
``calibrate_job``  the ``calibrate`` job.
``alignment_job``  the ``alignment`` job.

The command line (``shadowless calibrate``, ``shadowless alignment``) is :mod:`rigctl.calibration_cli`.
"""
