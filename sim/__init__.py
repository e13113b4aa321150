"""The virtual room: projectors, camera, table, meshes and hands simulated in millimetres.

Nothing outside ``sim/`` imports this package except tests, benchmarks and the
demo wiring; the coordinator only sees the room through its gRPC camera
(``room://HOST:PORT``). Entry points::

    from sim.scene import reference_scene, load_layout, SUBSETS
    from sim.room import Room
"""
