"""The virtual room: projectors, camera, table, meshes and hands simulated in millimetres.

Nothing outside ``sim/`` imports this package except tests, benchmarks and the
demo wiring; the coordinator only sees the room through its gRPC camera
(``room://HOST:PORT``) and nodes through ``--output room://HOST:PORT``.

Modules
-------
geometry   pinhole devices (K, R, t, look-at, projection, rays, GL projection)
optics     projector response, pixel footprint + defocus kernels, irradiance, camera sensor
mesh       OBJ/PLY reading and writing, the procedural bust
occluders  analytic solids with exact ray tests, the queries over many of them
hand       the hand with forearm built from those solids, hand paths
scene      projectors, cameras, table, mesh; the paper's 5x5 rig; subsets P1 ... P25; layout files
photometry uneven light: brightness and white-point spread, hot spot, vignetting, the lamp's checks
specular   a glossy coat (energy-normalised Blinn-Phong) on the table or the mesh; off by default
observer   an eye at any point, added to a scene as its last camera
rigs       rigs that partly overlap (the 3x1 wall, projectors on the walls around the bust), shipped
           layouts (sim/layouts/), one call for any room in process or as `shadowless room` arguments
raster     moderngl (EGL) rasterisation: camera G-buffers and projector depth maps of meshes
precompute views and plans per camera and projector, mesh maps (the static precomputation)
occlusion  occluder visibility and sampling in a precomputed view
room       the Room: facade, light fields, fast linear captures
truth      ground truth: poses, homographies, correspondences, light transport, light drop
wire       the Room and RoomTruth gRPC services and their messages; link: a synchronous client
cli        ``shadowless room``

Entry points::

    from sim.scene import reference_scene, load_layout, SUBSETS
    from sim.rigs import scene, room_argv, wall_scene, BENCH_LIGHT
    from sim.photometry import Photometry
    from sim.room import Room
    from sim.hand import Hand, HandPath
    from sim.occluders import Box
"""
