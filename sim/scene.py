"""What is in the room: projectors, cameras, the table, a mesh; the reference rig; layout files.

The reference rig (:func:`reference_scene`) is the paper's: a 5 x 5 projector
array on the ceiling plane z = 1400 mm above a 1200 x 600 mm table, slot
``r{row}c{col}`` at x = (col - 2) * pitch, y = (row - 2) * pitch (rows grow
along +y, columns along +x), every projector aimed at the table centre so its
footprint covers the whole table; one ceiling camera beside the centre
projector (with ``cameras=3`` two more around the bust, :data:`RING_CAMERAS`, as the paper
measured its object with three); plus ``p1``, the single high-luminance projector at the centre
position that the paper compares against (unpowered unless selected).

Named subsets (:data:`SUBSETS`, paper section 5.2; ``#`` = powered, ``.`` = off,
row r0 printed first)::

    P1   the bright unit "p1" at the centre position, as bright as P25 together
    P9D  dense centre 3x3     P9W  centre + corners + edge midpoints
         . . . . .                 # . # . #
         . # # # .                 . . . . .
         . # # # .                 # . # . #
         . # # # .                 . . . . .
         . . . . .                 # . # . #
    P13  checkerboard (r+c even)   P17  outer ring + centre
         # . # . #                 # # # # #
         . # . # .                 # . . . #
         # . # . #                 # . # . #
         . # . # .                 # . . . #
         # . # . #                 # # # # #
    P20  outer ring + inner diagonals (no centre: the paper notes P20 lacks it)
         # # # # #
         # # . # #
         # . . . #
         # # . # #
         # # # # #
    P25  all 25

A layout file (TOML, :func:`load_layout`) describes any other room.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from protos.layout import CAMERA_NATIVE, PROJECTOR_NATIVE, TABLE_SIZE, Layout, LayoutFileError, read_layout
from sim.errors import LayoutError, UnknownSlotError
from sim.geometry import Pinhole, intrinsics, look_at, rotation_about
from sim.mesh import Mesh, bust, load_mesh
from sim.optics import Response, Sensor, irradiance_factor, random_response
from sim.photometry import PROJECTOR_KEYS, Photometry, Profile, apply_photometry, parse_photometry, projector_photometry
from sim.specular import Gloss

# PROJECTOR_NATIVE, CAMERA_NATIVE (the reference devices' native resolutions, a layout's defaults)
# and TABLE_SIZE come from protos.layout, which reads layout files for the room and the coordinator.
CEILING_MM = 1400.0

#: The cameras ``reference_scene(cameras=3)`` adds to the ceiling one: name, position (mm), each aimed at the
#: bust's middle (z = 250 mm) with the image's top up, its focal fitted to the bust and the table around it.
#: From the ceiling the bust shows its crown and shoulders (15 % of its surface at cos >= 0.25); these add
#: its face and its back (72 % with the three).
RING_CAMERAS = (("front-left", (-400.0, 1000.0, 700.0)), ("back-right", (400.0, -1000.0, 700.0)))

#: Level the powered projectors at full white reach on the camera's axis (fraction of full scale).
TARGET_LEVEL = 0.8


def _grid(pred) -> list[str]:
    return [f"r{r}c{c}" for r in range(5) for c in range(5) if pred(r, c)]


#: Named projector subsets of the 5x5 rig (see the module docstring for the pictures).
SUBSETS: dict[str, list[str]] = {
    "P1": ["p1"],
    "P9D": _grid(lambda r, c: 1 <= r <= 3 and 1 <= c <= 3),
    "P9W": _grid(lambda r, c: r % 2 == 0 and c % 2 == 0),
    "P13": _grid(lambda r, c: (r + c) % 2 == 0),
    "P17": _grid(lambda r, c: r in (0, 4) or c in (0, 4) or (r, c) == (2, 2)),
    "P20": _grid(lambda r, c: r in (0, 4) or c in (0, 4) or (r in (1, 3) and c in (1, 3))),
    "P25": _grid(lambda r, c: True),
}


@dataclass(frozen=True, eq=False)
class ProjectorSpec:
    """One projector.

    Attributes
    ----------
    slot : str
    native : Pinhole
        Optics at the native resolution.
    pinhole : Pinhole
        The same optics at the room's (possibly scaled-down) resolution; what
        nodes render for.
    response : Response
    peak : float
        Relative output: irradiance 1.0 per unit luminance is an on-axis,
        fronto-parallel surface 1 m away (see :func:`sim.optics.irradiance_factor`).
    aperture : float
        Lens aperture diameter, mm (defocus blur).
    focus : float
        Focus distance, mm along the ray.
    falloff : float
        Lens fall-off exponent (``cos(off-axis angle) ** falloff``).
    powered : bool
        Part of the rig by default (``p1`` is not).
    white : (3,) float64 or None
        Per-channel gains of the emitted light, the unit's white point (None: 1, 1, 1).
    profile : Profile or None
        The light across the image, a hot spot and vignetting (None: even;
        :mod:`sim.photometry`).
    """

    slot: str
    native: Pinhole
    pinhole: Pinhole
    response: Response
    peak: float = 1.0
    aperture: float = 10.0
    focus: float = 1500.0
    falloff: float = 1.0
    powered: bool = True
    white: np.ndarray | None = None
    profile: Profile | None = None

    @property
    def size(self) -> tuple[int, int]:
        return self.pinhole.size

    @property
    def white_gains(self) -> np.ndarray:
        """(3,) float64: the per-channel gains (ones when the unit has none)."""
        return np.ones(3) if self.white is None else np.asarray(self.white, np.float64)

    def profile_at(self, u: np.ndarray, v: np.ndarray) -> np.ndarray | None:
        """The profile at projector coordinates (u, v) of :attr:`pinhole` ((...) float64), or None when even."""
        if self.profile is None or self.profile.identity:
            return None
        return self.profile.factor(u, v, self.pinhole.size)


@dataclass(frozen=True, eq=False)
class CameraSpec:
    """One camera.

    Attributes
    ----------
    native, pinhole : Pinhole
        Optics at native and at the room's resolution.
    gain : float
        Sensor signal (fraction of full scale) per unit of albedo x irradiance
        at exposure 1.0.
    exposure : float
        Relative exposure (1.0: the powered projectors at full white reach
        :data:`TARGET_LEVEL` on the camera's axis).
    sensor : Sensor
    """

    name: str
    native: Pinhole
    pinhole: Pinhole
    gain: float
    exposure: float = 1.0
    sensor: Sensor = field(default_factory=Sensor)

    @property
    def size(self) -> tuple[int, int]:
        return self.pinhole.size


@dataclass(frozen=True)
class Table:
    """The table top: a rectangle at z = 0 centred on the origin."""

    size: tuple[float, float] = TABLE_SIZE
    albedo: float = 0.85


@dataclass(frozen=True, eq=False)
class Scene:
    """Everything static in a room."""

    projectors: tuple[ProjectorSpec, ...]
    cameras: tuple[CameraSpec, ...]
    table: Table | None = field(default_factory=Table)
    mesh: Mesh | None = None
    mesh_albedo: float = 0.8
    mesh_source: str | None = None
    hand_albedo: float = 0.45
    name: str = "room"
    #: Glossy coats (:mod:`sim.specular`); none by default, and then the room renders as it always did.
    gloss: tuple[Gloss, ...] = ()

    def __post_init__(self) -> None:
        slots = [p.slot for p in self.projectors]
        if len(set(slots)) != len(slots):
            raise LayoutError(f"duplicate projector slots in {slots}")
        if not self.projectors or not self.cameras:
            raise LayoutError("a room needs at least one projector and one camera")
        if self.table is None and self.mesh is None:
            raise LayoutError("a room needs a surface: a table, a mesh, or both")
        for g in self.gloss:
            if not isinstance(g, Gloss) or getattr(self, g.surface) is None:
                raise LayoutError(f"gloss {g} is not a Gloss on a surface this room has (table: {self.table is not None}, mesh: {self.mesh is not None})")

    @property
    def slots(self) -> list[str]:
        """The powered-by-default projectors (the rig's slots)."""
        return [p.slot for p in self.projectors if p.powered]

    @property
    def all_slots(self) -> list[str]:
        return [p.slot for p in self.projectors]

    def projector(self, slot: str) -> ProjectorSpec:
        for p in self.projectors:
            if p.slot == slot:
                return p
        raise UnknownSlotError(f"no projector {slot!r} in this room; slots are {_slot_summary(self.all_slots)}")

    def camera(self, index: int) -> CameraSpec:
        if not 0 <= index < len(self.cameras):
            raise UnknownSlotError(f"no camera {index}; this room has {len(self.cameras)} camera(s), numbered from 0")
        return self.cameras[index]


def _slot_summary(slots: list[str]) -> str:
    if len(slots) > 8:
        return f"{', '.join(slots[:3])}, ..., {', '.join(slots[-2:])} ({len(slots)} in all)"
    return ", ".join(slots)


def _scaled_size(native: tuple[int, int], scale: float) -> tuple[int, int]:
    if not 0 < scale <= 1:
        raise ValueError(f"scale must be in (0, 1], got {scale}")
    return max(8, round(native[0] * scale)), max(8, round(native[1] * scale))


def _device(position, target, up, native_size, focal, principal, roll_deg: float = 0.0) -> Pinhole:
    R, _ = look_at(position, target, up=up)
    if roll_deg:
        R = rotation_about((0, 0, 1), math.radians(roll_deg)) @ R
    t = -R @ np.asarray(position, np.float64)
    return Pinhole(intrinsics(native_size, focal=focal, principal=principal), R, t, native_size)


def fit_focal(positions, target, up, size, points, *, margin: float) -> float:
    """Largest focal length (px) for which ``points`` fall inside the image from every position."""
    best = np.inf
    w, h = size
    for pos in positions:
        R, t = look_at(pos, target, up=up)
        Xc = points @ R.T + t
        xn = np.abs(Xc[:, 0] / Xc[:, 2])
        yn = np.abs(Xc[:, 1] / Xc[:, 2])
        best = min(best, float(np.min((w / 2 * (1 - margin)) / np.maximum(xn, 1e-9))), float(np.min((h / 2 * (1 - margin)) / np.maximum(yn, 1e-9))))
    return best


def _table_corners(size, grow: float) -> np.ndarray:
    w, h = size[0] / 2 + grow, size[1] / 2 + grow
    return np.array([[sx * w, sy * h, 0.0] for sx in (-1, 1) for sy in (-1, 1)])


def auto_gain(projectors, camera: Pinhole, *, albedo: float, level: float = TARGET_LEVEL) -> float:
    """Camera gain for which the powered projectors at full white reach ``level`` on the camera's axis.

    The reference point is where the axis meets the table plane z = 0 (a
    horizontal surface); for a camera that does not look down, a surface
    facing the camera 1 m along its axis.
    """
    c = camera.center
    a = camera.axis
    if a[2] < -1e-9 and c[2] > 0:
        point, normal = c + (-c[2] / a[2]) * a, np.array([0.0, 0.0, 1.0])
    else:
        point, normal = c + 1000.0 * a, -a
    total = 0.0
    for p in projectors:
        if p.powered:
            e = p.peak * float(irradiance_factor(p.native.center, p.native.axis, point, normal, falloff=p.falloff))
            # uneven light (sim.photometry), only when a unit has it: the level holds with it too
            if p.white is not None:
                e *= float(np.mean(p.white))
            if p.profile is not None and not p.profile.identity and e > 0:
                pix, _ = p.native.project(point[None, :])
                e *= float(p.profile.factor(pix[0, 0], pix[0, 1], p.native.size))
            total += e
    if total <= 0:
        raise LayoutError(
            f"no powered projector lights the point on the camera's axis ({point.round(1).tolist()} mm); "
            "aim a projector there or give the camera an explicit gain"
        )
    return level / (albedo * total)


def reference_scene(
    projector_scale: float = 0.25,
    camera_scale: float = 0.25,
    surface: str | Mesh = "table",
    seed: int = 0,
    *,
    pitch: float | tuple[float, float] = 250.0,
    ceiling: float = CEILING_MM,
    jitter: bool = True,
    aperture: float = 10.0,
    cameras: int = 1,
    photometry: Photometry | None = None,
) -> Scene:
    """The paper's rig: 5 x 5 projectors 1.4 m above a 1200 x 600 mm table, one ceiling camera (or three).

    Parameters
    ----------
    projector_scale, camera_scale : float
        Resolution relative to native (1280 x 800 projectors, 2592 x 1944
        camera); 0.25 by default so the room runs fast, 1.0 for full resolution.
    surface : "table", "bust", a Mesh, or a path to an OBJ/PLY file (mm)
        "bust": the procedural bust standing at the table centre, facing +y.
    seed : int
        Unit-to-unit variation: responses (gamma 2.2 +- 10 %, black level
        0.002-0.01), peak output (+- 5 %) and, with ``jitter``, mounting
        (position +- 3 mm, aim +- 10 mm on the table, roll +- 0.3 deg, focal
        +- 1 %, principal point +- 2 px).
    pitch : float or (float, float)
        Spacing of the array along x and y, mm.
    aperture : float
        Lens aperture diameter (mm) of every projector (defocus blur).
    cameras : 1 or 3
        The ceiling camera alone, or with the two of :data:`RING_CAMERAS` (cameras 1 and 2).
    photometry : Photometry, optional
        Uneven light (:mod:`sim.photometry`: brightness and white-point spread, a hot spot,
        vignetting), drawn from ``seed``; none by default. The cameras' gains follow, so the
        powered projectors still reach :data:`TARGET_LEVEL` on the camera's axis.
    """
    if cameras not in (1, 3):
        raise ValueError(f"the reference rig has 1 or 3 cameras, not {cameras}")
    rng = np.random.default_rng(seed)
    px, py = (pitch, pitch) if np.isscalar(pitch) else pitch
    up = (0.0, 1.0, 0.0)
    target = np.zeros(3)
    grid = [(r, c, np.array([(c - 2) * px, (r - 2) * py, ceiling])) for r in range(5) for c in range(5)]
    corners = _table_corners(TABLE_SIZE, 40.0)
    focal = fit_focal([g[2] for g in grid], target, up, PROJECTOR_NATIVE, corners, margin=0.04)
    proj_size = _scaled_size(PROJECTOR_NATIVE, projector_scale)
    projectors: list[ProjectorSpec] = []

    def make(slot, position, *, powered, peak_scale=1.0):
        j = jitter
        pos = position + (rng.uniform(-3, 3, 3) if j else 0.0)
        aim = target + (np.append(rng.uniform(-10, 10, 2), 0.0) if j else 0.0)
        f = focal * (1.0 + (rng.uniform(-0.01, 0.01) if j else 0.0))
        cxy = np.array([(PROJECTOR_NATIVE[0] - 1) / 2, (PROJECTOR_NATIVE[1] - 1) / 2]) + (rng.uniform(-2, 2, 2) if j else 0.0)
        roll = rng.uniform(-0.3, 0.3) if j else 0.0
        native = _device(pos, aim, up, PROJECTOR_NATIVE, f, tuple(cxy), roll)
        response = random_response(rng)
        peak = peak_scale * (1.0 + rng.uniform(-0.05, 0.05))
        focus = float(np.linalg.norm(native.center - aim))
        return ProjectorSpec(slot, native, native.scaled(proj_size), response, peak, aperture, focus, 1.0, powered)

    for r, c, pos in grid:
        projectors.append(make(f"r{r}c{c}", pos, powered=True))
    bright = make("p1", np.array([0.0, 0.0, ceiling]), powered=False)
    # The paper's high-luminance unit: as bright at the table centre as the 25 together.
    centre, up_n = np.zeros(3), np.array([0.0, 0.0, 1.0])
    total = sum(p.peak * float(irradiance_factor(p.native.center, p.native.axis, centre, up_n, falloff=p.falloff)) for p in projectors)
    own = float(irradiance_factor(bright.native.center, bright.native.axis, centre, up_n, falloff=bright.falloff))
    projectors.append(replace(bright, peak=total / own))
    if photometry is not None and not photometry.none:
        projectors = list(apply_photometry(projectors, photometry, seed=seed))

    cam_pos = np.array([0.0, -py / 2, ceiling])
    cam_focal = fit_focal([cam_pos], target, up, CAMERA_NATIVE, _table_corners(TABLE_SIZE, 30.0), margin=0.05)
    cam_native = _device(cam_pos, target, up, CAMERA_NATIVE, cam_focal, None)
    table = Table()
    gain = auto_gain(projectors, cam_native, albedo=table.albedo)
    cam_size = _scaled_size(CAMERA_NATIVE, camera_scale)
    devices = [CameraSpec("ceiling", cam_native, cam_native.scaled(cam_size), gain)]
    middle = np.array([0.0, 0.0, 250.0])
    seen = np.array([[x, y, z] for x in (-160, 160) for y in (-140, 140) for z in (0, 600)]
                    + [[x, y, 0.0] for x in (-450, 450) for y in (-250, 250)])
    for name, pos in RING_CAMERAS[:cameras - 1]:
        f = fit_focal([np.asarray(pos)], middle, (0.0, 0.0, 1.0), CAMERA_NATIVE, seen, margin=0.05)
        native = _device(np.asarray(pos), middle, (0.0, 0.0, 1.0), CAMERA_NATIVE, f, None)
        devices.append(CameraSpec(name, native, native.scaled(cam_size), auto_gain(projectors, native, albedo=table.albedo)))

    mesh, source = _surface_mesh(surface)
    return Scene(tuple(projectors), tuple(devices), table, mesh, mesh_source=source, name=f"reference-5x5-{surface if isinstance(surface, str) else 'mesh'}")


def _surface_mesh(surface, base: Path | None = None) -> tuple[Mesh | None, str | None]:
    if isinstance(surface, Mesh):
        return surface, None
    if surface == "table":
        return None, None
    if surface == "bust":
        return bust(), "builtin:bust"
    path = Path(surface)
    if base is not None and not path.is_absolute():
        path = base / path
    return load_mesh(path), str(path)


# ---------------------------------------------------------------- layout files


def load_layout(path: str | Path, *, projector_scale: float = 0.25, camera_scale: float = 0.25, seed: int = 0,
                photometry: Photometry | dict | None = None) -> Scene:
    """Read a room from a TOML layout file (any number of projectors, anywhere, aimed anywhere).

    Schema (millimetres; every key but ``position`` has a default)::

        name = "my room"
        [table]                     # omit the section for no table
        size = [1200, 600]
        albedo = 0.85
        [mesh]                      # optional: an object on the table
        builtin = "bust"            # or: path = "statue.obj" (relative to this file)
        albedo = 0.8
        [[projector]]
        slot = "left"               # default p0, p1, ...
        position = [-500, 0, 1400]
        target = [0, 0, 0]          # aim point
        up = [0, 1, 0]              # world direction towards the image top
        resolution = [1280, 800]    # native
        focal_px = 1250             # native px; or throw_ratio = 0.98 (focal / width)
        principal = [639.5, 399.5]  # native px, default the centre
        gamma = 2.2                 # or [r, g, b]; default: random unit from the seed
        black = 0.005
        peak = 1.0
        aperture_mm = 10
        focus_mm = 1450             # default: distance to the target
        falloff = 1.0
        powered = true
        white = [1.0, 0.95, 1.05]   # optional: per-channel gains, the unit's white point
        hotspot = 0.2               # optional: this unit's own profile (replaces [photometry]'s, key by key)
        hotspot_width = 0.35
        hotspot_center = [0, 0]     # normalised image coordinates, -1..1
        vignetting = 0.3
        [[camera]]
        position = [0, -125, 1400]
        target = [0, 0, 0]
        resolution = [2592, 1944]
        focal_px = 2645
        exposure = 1.0              # relative to the automatic exposure
        gain = 0.088                # optional: absolute signal per albedo x irradiance (replaces the automatic one)
        full_well = 10000
        read_noise = 2.5
        bits = 12
        [photometry]                # optional: uneven light for every projector (sim.photometry)
        brightness_spread = 0.15    # each unit's peak times 1 +- 0.15 (uniform, drawn from the seed)
        white_spread = 0.15         # each unit's channel gains 1 +- 0.15
        hotspot = 0.2               # 20 % more light at the image centre, a Gaussian ...
        hotspot_width = 0.35        # ... of this sigma, in half-diagonals of the image
        vignetting = 0.3            # 30 % less light in the image corners (quadratic in the radius)

    Photometry: a projector's ``peak`` or ``white`` stated in the file is that unit's truth, and
    the spreads leave it alone; its profile keys replace the ``[photometry]`` ones. ``photometry``
    replaces the file's ``[photometry]`` section (a :class:`~sim.photometry.Photometry`) or some of
    its keys (a dict, e.g. what ``shadowless room --hotspot`` gives). Every key defaults to 0: the
    light of a layout without them is even, as it always was.

    Raises
    ------
    LayoutError
        Naming the file and the entry that is wrong.
    """
    try:
        layout = read_layout(path)
        return scene_from_layout(layout, projector_scale=projector_scale, camera_scale=camera_scale, seed=seed,
                                  photometry=photometry)
    except LayoutFileError as exc:
        raise LayoutError(str(exc)) from None
    except LayoutError as exc:
        raise LayoutError(f"layout {path}: {exc}") from None
    except (TypeError, ValueError, KeyError) as exc:
        raise LayoutError(f"layout {path}: {exc}") from exc


def scene_from_layout(layout: Layout, *, projector_scale: float = 0.25, camera_scale: float = 0.25, seed: int = 0,
                      photometry: Photometry | dict | None = None) -> Scene:
    """The room of a parsed layout (:mod:`protos.layout`): its devices, plus the photometry only the
    room models (responses, peaks, apertures, sensors, uneven light). Arguments as :func:`load_layout`;
    raises ValueError (or LayoutError) naming the entry."""
    if isinstance(photometry, Photometry):
        rig_light = photometry
    else:
        rig_light = parse_photometry(layout.photometry or None)
        if photometry:
            rig_light = rig_light.merged(**photometry)
    rng = np.random.default_rng(seed)
    table = None if layout.table is None else Table(layout.table.size, layout.table.albedo)
    mesh, source, mesh_albedo = None, None, 0.8
    if layout.mesh is not None:
        spec = layout.mesh
        mesh, source = (bust(), "builtin:bust") if spec.builtin == "bust" else _surface_mesh(spec.path)
        if spec.placed:
            mesh = Mesh(spec.place(mesh.vertices), mesh.faces, mesh.uvs)
        mesh_albedo = spec.albedo
    projectors = []
    own: dict = {}
    explicit_peak = set()
    for i, d in enumerate(layout.projectors):
        e = d.entry
        if any(k in e for k in PROJECTOR_KEYS):
            own[d.name] = projector_photometry(e, rig_light, where=f"[[projector]] #{i + 1} ({d.name})")
        if "peak" in e:
            explicit_peak.add(d.name)
        native = Pinhole(d.K, d.R, d.t, d.size)
        unit = random_response(rng)
        gamma = e.get("gamma", unit.gamma)
        black = e.get("black", unit.black)
        peak = float(e.get("peak", 1.0 + rng.uniform(-0.05, 0.05)))
        response = Response(gamma, black)
        focus = float(e.get("focus_mm", np.linalg.norm(native.center - d.target)))
        size = _scaled_size(d.size, projector_scale)
        projectors.append(
            ProjectorSpec(d.name, native, native.scaled(size), response, peak, float(e.get("aperture_mm", 10.0)), focus, float(e.get("falloff", 1.0)), bool(e.get("powered", True)))
        )
    if own or not rig_light.none:
        projectors = list(apply_photometry(projectors, rig_light, seed=seed, own=own, explicit_peak=frozenset(explicit_peak)))
    cameras = []
    for d in layout.cameras:
        e = d.entry
        native = Pinhole(d.K, d.R, d.t, d.size)
        albedo = table.albedo if table is not None else mesh_albedo
        gain = float(e["gain"]) if "gain" in e else auto_gain(projectors, native, albedo=albedo)
        sensor = Sensor(float(e.get("full_well", 10000.0)), float(e.get("read_noise", 2.5)), int(e.get("bits", 12)), float(e.get("gamma", 1.0)))
        cameras.append(CameraSpec(d.name, native, native.scaled(_scaled_size(d.size, camera_scale)), gain, float(e.get("exposure", 1.0)), sensor))
    return Scene(tuple(projectors), tuple(cameras), table, mesh, mesh_albedo, source, name=layout.name)


def write_layout(scene: Scene, path: str | Path) -> None:
    """Write ``scene`` as a layout file that :func:`load_layout` reads back (native resolutions)."""

    def fmt(v) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, (list, tuple, np.ndarray)):
            return "[" + ", ".join(fmt(x) for x in np.asarray(v).tolist()) + "]"
        if isinstance(v, (int, np.integer)):
            return str(int(v))
        return repr(float(v))

    lines = [f"name = {fmt(scene.name)}", ""]
    if scene.table is not None:
        lines += ["[table]", f"size = {fmt(list(scene.table.size))}", f"albedo = {fmt(scene.table.albedo)}", ""]
    if scene.mesh is not None:
        if scene.mesh_source is None:
            raise LayoutError("this scene's mesh was built in memory; save it with sim.mesh.save_mesh and reference its path")
        key = ("builtin", "bust") if scene.mesh_source == "builtin:bust" else ("path", scene.mesh_source)
        lines += ["[mesh]", f"{key[0]} = {fmt(key[1])}", f"albedo = {fmt(scene.mesh_albedo)}", ""]
    for p in scene.projectors:
        n = p.native
        up = -n.R[1]
        target = n.center + n.axis * p.focus
        lines += [
            "[[projector]]",
            f"slot = {fmt(p.slot)}",
            f"position = {fmt(n.center)}",
            f"target = {fmt(target)}",
            f"up = {fmt(up)}",
            f"resolution = {fmt(list(n.size))}",
            f"focal_px = {fmt(n.K[0, 0])}",
            f"principal = {fmt(n.K[:2, 2])}",
            f"gamma = {fmt(p.response.gamma)}",
            f"black = {fmt(p.response.black)}",
            f"peak = {fmt(p.peak)}",
            f"aperture_mm = {fmt(p.aperture)}",
            f"focus_mm = {fmt(p.focus)}",
            f"falloff = {fmt(p.falloff)}",
            f"powered = {fmt(p.powered)}",
        ]
        if p.white is not None:
            lines.append(f"white = {fmt(p.white)}")
        if p.profile is not None and not p.profile.identity:
            pr = p.profile
            lines += [f"hotspot = {fmt(pr.hotspot)}", f"hotspot_width = {fmt(pr.hotspot_width)}",
                      f"hotspot_center = {fmt(list(pr.hotspot_center))}", f"vignetting = {fmt(pr.vignetting)}"]
        lines.append("")
    for c in scene.cameras:
        n = c.native
        up = -n.R[1]
        # Aim at the table plane when looking down, else one metre ahead.
        dist = -n.center[2] / n.axis[2] if n.axis[2] < -1e-9 else 1000.0
        lines += [
            "[[camera]]",
            f"name = {fmt(c.name)}",
            f"position = {fmt(n.center)}",
            f"target = {fmt(n.center + dist * n.axis)}",
            f"up = {fmt(up)}",
            f"resolution = {fmt(list(n.size))}",
            f"focal_px = {fmt(n.K[0, 0])}",
            f"principal = {fmt(n.K[:2, 2])}",
            f"exposure = {fmt(c.exposure)}",
            f"gain = {fmt(c.gain)}",
            f"full_well = {fmt(c.sensor.full_well)}",
            f"read_noise = {fmt(c.sensor.read_noise)}",
            f"bits = {fmt(c.sensor.bits)}",
            "",
        ]
    Path(path).write_text("\n".join(lines))
