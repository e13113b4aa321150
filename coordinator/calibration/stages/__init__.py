"""The stages of the ``calibrate`` job, in the order it runs them.

Each stage is ``async def stage(st: State) -> ...`` on the job's :class:`~.state.State`:

* :mod:`.exposure`: every projector black, then white, per camera; fails early when a
  camera is under-exposed.
* :mod:`.cameras`: the table -> camera mapping of every camera (known points, a ChArUco
  board, or the mapping an earlier run saved) and, on a mesh, every camera's pose and the
  mesh's registration.
* :mod:`.gray`: sequential Gray codes on the table, one projector after another.
* :mod:`.dots`: the multiplexed mode on the table, every projector at once.
* :mod:`.mesh`: sequential Gray codes cast onto the mesh (3D poses).
* :mod:`.dots3d`: the multiplexed mode on the mesh, every projector at once (3D poses).

The table's and the mesh's modes share their loops (:mod:`.loops`): one projector after another
in the sequential modes; the coded-dot rounds, coarse fits and failures of the multiplexed ones.
"""
