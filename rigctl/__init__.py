"""The operator's command line: ``shadowless status/show/play/content/calibrate/...`` and ``shadowless rig``.

It talks to a running coordinator through :mod:`rigctl.link` (gRPC, dataclasses out), and works
on rig directories and asset stores on this machine. It builds each job's flags from the job's
options dataclass, so a job's command line and its validation come from one place. MPCDI export
is :mod:`rigctl.mpcdi`. The coordinator never imports this package.
"""
