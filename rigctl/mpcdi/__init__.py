"""The rig in VESA's MPCDI (Multiple Projection Common Data Interchange) format: an archive other
projection tools read. See :mod:`rigctl.mpcdi.archive`."""
