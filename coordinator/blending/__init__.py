"""The rig's per-pixel blend on the coordinator: the ``blend`` job that measures it
(:mod:`~coordinator.blending.blend_job`), and the state that keeps it on the nodes through a lost
node or a dimmed lamp (:mod:`~coordinator.blending.state`, :mod:`~coordinator.blending.failover`,
:mod:`~coordinator.blending.watchdog`). The numerics are :mod:`imaging.blending`'s.
"""
