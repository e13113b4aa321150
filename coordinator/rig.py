"""The rig: its configuration (``rig.toml``) and state (poses, LUTs, gains,
content), persisted in a rig directory with atomic writes.

Layout of a rig directory::

    rig.toml              human-editable: name, id, slots, resolutions, content size
    token                 the rig's secret (mode 0600), created by `shadowless rig init`
    slots/<slot>.json     per-slot state: revision, pose, gain, output size, LUT file
    luts/<slot>.npy       (C, E) float32 inverse-response LUT
    meshes/<id>.npz       meshes that projection poses render
    content/current.*     what the rig shows (image + metadata)
    calibration/          calibration runs, camera mappings, per-slot results
    compensation/         responses, the light transport, compensated results
    assets/               content assets by SHA-256 (see coordinator/assets.py)

A coordinator restarted on the same directory serves the same rig.
"""
from __future__ import annotations

import hashlib
import io
import json
import logging
import re
import time
import uuid
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from coordinator.errors import RigError
from coordinator.schema import (MAX_GAIN, MAX_SIDE, MIN_SIDE, SLOT_RE, ContentMeta, RigToml, SizeDoc, SlotFile, check_homography,
                                parse_toml, read_bytes, read_json, read_npy, read_text, valid_gain, validate, validate_lut)
from protos.store import (atomic_save_npy, atomic_save_npz, atomic_write_files, atomic_write_json, atomic_write_text,
                          remove_stale_temps)
from protos.auth import new_token
from protos.blend import BlendMaps
from protos.spaces import scale_intrinsics

__all__ = ["MAX_GAIN", "MAX_SIDE", "MIN_SIDE", "SLOT_RE", "Content", "HomographyPose", "Mesh", "ProjectionPose", "Rig",
           "RigConfig", "SlotState", "grid_slots", "init_rig", "parse_config", "valid_gain", "validate_lut"]
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class HomographyPose:
    """Planar pose: ``matrix`` (3, 3) float64 maps content px to projector px."""

    matrix: np.ndarray

    kind = "homography"

    def __post_init__(self):
        object.__setattr__(self, "matrix", check_homography(self.matrix))


@dataclass(frozen=True)
class Mesh:
    """A textured mesh: vertices (V, 3) float32 mm, uvs (V, 2) float32 in [0, 1], faces (F, 3) uint32."""

    mesh_id: str
    vertices: np.ndarray
    uvs: np.ndarray
    faces: np.ndarray

    def __post_init__(self):
        v = np.asarray(self.vertices, np.float32)
        uv = np.asarray(self.uvs, np.float32)
        f = np.asarray(self.faces, np.uint32)
        if v.ndim != 2 or v.shape[1] != 3 or uv.shape != (v.shape[0], 2) or f.ndim != 2 or f.shape[1] != 3:
            raise ValueError(f"mesh shapes must be (V,3), (V,2), (F,3); got {v.shape}, {uv.shape}, {f.shape}")
        if f.size and int(f.max()) >= v.shape[0]:
            raise ValueError("mesh faces index past the last vertex")
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "uvs", uv)
        object.__setattr__(self, "faces", f)


@dataclass(frozen=True)
class ProjectionPose:
    """3D pose: ``matrix`` (3, 4) float64 maps world mm to projector px; renders ``mesh``."""

    matrix: np.ndarray
    mesh: Mesh
    near_mm: float = 100.0
    far_mm: float = 10_000.0

    kind = "projection"

    def __post_init__(self):
        m = np.asarray(self.matrix, dtype=np.float64)
        if m.shape != (3, 4) or not np.all(np.isfinite(m)):
            raise ValueError(f"a projection pose must be a finite (3, 4) matrix, got shape {m.shape}")
        if not np.any(m[2, :3]):   # what the nodes' renderer needs (node.render.renderer.set_projection)
            raise ValueError("a projection pose needs a depth axis: its third row must not start with three zeros "
                             "(an affine matrix is not a projector's pose)")
        if not 0 < self.near_mm < self.far_mm:
            raise ValueError("projection pose needs 0 < near_mm < far_mm")
        object.__setattr__(self, "matrix", m)


Pose = HomographyPose | ProjectionPose


def mesh_with_id(vertices: np.ndarray, uvs: np.ndarray, faces: np.ndarray) -> Mesh:
    """A :class:`Mesh` whose id is a digest of its arrays (the same mesh, the same id)."""
    v, uv, f = (np.ascontiguousarray(vertices, np.float32), np.ascontiguousarray(uvs, np.float32),
                np.ascontiguousarray(faces, np.uint32))
    h = hashlib.blake2b(digest_size=8)
    for a in (v, uv, f):
        h.update(a.tobytes())
    return Mesh(h.hexdigest(), v, uv, f)


@dataclass(frozen=True)
class SlotState:
    """Everything one node needs to render: its assignment."""

    name: str
    width: int
    height: int
    revision: int = 0
    gain: float = 1.0
    pose: Pose | None = None
    lut: np.ndarray | None = None   # (C, E) float32
    source: str = "none"
    updated_at: float = 0.0
    #: the 3x4 pose a layout planned for this projector (``rig init --layout``), onto the layout's
    #: surface; not part of the node's assignment, and no job reads it: only ``coverage --planned``.
    #: Setting a pose (calibration, ``configure``) drops it.
    planned: ProjectionPose | None = None
    #: per-pixel blend maps (alpha gain, beta black offset) this projector applies before its LUT;
    #: None: none. Stored by the blend store, not in rig.toml.
    blend: BlendMaps | None = None
    #: rig-clock ns from which the nodes show ``blend`` (0: as soon as they have it), so that every
    #: node of a failover switches at one common swap instant
    blend_at_ns: int = 0


def hash_slot_state(h, st: SlotState) -> None:
    """Feed ``h`` (a hashlib object) what light measured through a slot depends on: its size, gain,
    pose and LUT. The transport's fingerprint and a blend's per-slot digests both use it, so they
    go stale on the same changes."""
    h.update(f"{st.width}x{st.height}:{st.gain!r}".encode())
    h.update(st.pose.matrix.tobytes() if st.pose is not None else b"-")
    h.update(np.ascontiguousarray(st.lut, np.float32).tobytes() if st.lut is not None else b"identity")


@dataclass(frozen=True)
class Content:
    """An image the rig shows: ``image`` (H, W, C) uint8/uint16/float32, with a stable id."""

    image: np.ndarray
    name: str = ""
    content_id: str = ""

    def __post_init__(self):
        img = np.asarray(self.image)
        if img.ndim == 2:
            img = img[:, :, None]
        if img.ndim != 3 or not 1 <= img.shape[2] <= 4:
            raise ValueError(f"content must be (H, W) or (H, W, C<=4), got {img.shape}")
        if img.dtype not in (np.uint8, np.uint16, np.float32):
            raise ValueError(f"content dtype must be uint8, uint16 or float32, got {img.dtype}")
        object.__setattr__(self, "image", img)
        if not self.content_id:
            object.__setattr__(self, "content_id", content_id_of(img))


def content_id_of(image: np.ndarray) -> str:
    """A stable id for an image: the same pixels give the same id across restarts."""
    h = hashlib.blake2b(digest_size=12)
    h.update(f"{image.shape}{image.dtype.str}".encode())
    h.update(np.ascontiguousarray(image).tobytes())
    return h.hexdigest()


@dataclass(frozen=True)
class BlendConfig:
    """rig.toml's ``[blend]``: ``headroom`` None ("auto": enough that losing any one projector is
    covered where others reach) or a fraction 0..0.9 of each point's light held in reserve; whether
    the photometric watchdog runs during a show, and every how many seconds."""

    headroom: float | None = None
    watchdog: bool = True
    watchdog_interval_s: float = 1.0
    #: how far ahead of now a failover's new maps take effect on every node at once (ms); None: "auto"
    #: (:func:`coordinator.blending.state.auto_lead_ns`, from the bytes the switch pushes)
    switch_lead_ms: float | None = None


@dataclass(frozen=True)
class RigConfig:
    name: str
    rig_id: str
    slots: dict[str, tuple[int, int]]
    content_width: int = 1200
    content_height: int = 600
    latency_ms: float = 50.0
    heartbeat_ms: int = 1000
    lost_after_ms: int = 5000
    cameras: tuple[str, ...] = ()
    blend: BlendConfig = BlendConfig()


#: rigs with more projectors than this default to a heartbeat every 2 s instead of every second
LARGE_RIG_SLOTS = 64


def default_heartbeat_ms(n_slots: int) -> int:
    """A node's heartbeat interval when rig.toml does not set one: 1 s, 2 s for rigs of more than
    LARGE_RIG_SLOTS projectors (each heartbeat costs the coordinator about a quarter of a
    millisecond of CPU, `bench swarm`; a node counts as lost after five missed)."""
    return 1000 if n_slots <= LARGE_RIG_SLOTS else 2000


def _check_size(what: str, w: object, h: object) -> tuple[int, int]:
    """(w, h) as a slot/content resolution (ints in MIN_SIDE..MAX_SIDE), checked by the schema."""
    validate(SizeDoc, {"width": w, "height": h}, what)
    return w, h


def parse_config(text: str, *, source: str = "rig.toml") -> RigConfig:
    """``rig.toml``'s text as a RigConfig, checked by :class:`coordinator.schema.RigToml`; refusals
    are one-line RigErrors naming ``source``."""
    doc = validate(RigToml, parse_toml(text, source), source)
    dw, dh = doc.defaults.width or 1920, doc.defaults.height or 1080
    slots = {name: (spec.width or dw, spec.height or dh) for name, spec in doc.slots.items()}
    hb = doc.heartbeat_ms or default_heartbeat_ms(len(slots))
    lost = doc.lost_after_ms or max(5000, 5 * hb)
    if lost < 2 * hb:
        raise RigError(f"{source}: heartbeat_ms must be 50..60000 and lost_after_ms at least twice it")
    return RigConfig(
        name=doc.name, rig_id=doc.id, slots=slots, content_width=doc.content_width, content_height=doc.content_height,
        latency_ms=doc.latency_ms, heartbeat_ms=hb, lost_after_ms=lost, cameras=tuple(doc.cameras),
        blend=BlendConfig(headroom=None if doc.blend.headroom == "auto" else float(doc.blend.headroom),
                          watchdog=doc.blend.watchdog, watchdog_interval_s=doc.blend.watchdog_interval_s,
                          switch_lead_ms=(None if doc.blend.switch_lead_ms == "auto"
                                          else float(doc.blend.switch_lead_ms))),
    )


def grid_slots(rows: int, cols: int) -> list[str]:
    return [f"r{r}c{c}" for r in range(rows) for c in range(cols)]


def render_config(name: str, rig_id: str, slots: list[str], *, width: int, height: int,
                  content_width: int, content_height: int, latency_ms: float, cameras: list[str] = (),
                  sizes: dict[str, tuple[int, int]] | None = None, calibration_mesh: str | None = None) -> str:
    """rig.toml's text; ``sizes`` gives slots whose output is not ``width`` x ``height`` their own;
    ``calibration_mesh`` (a mesh file, relative to the rig directory) is the object `shadowless
    calibrate` poses the projectors onto unless told otherwise."""
    hb_ms = default_heartbeat_ms(len(slots))
    lines = [
        "# A shadowless rig. Edit by hand; the coordinator reads this file when it starts.",
        "# Calibration results, LUTs and content live beside it (slots/, luts/, content/).",
        f'name = "{name}"',
        f'id = "{rig_id}"',
        "# the shared image's size in content pixels (for a table: a rectified grid on it)",
        f"content_width = {content_width}",
        f"content_height = {content_height}",
        "# how far ahead of now frames are scheduled; covers network + render time",
        f"latency_ms = {latency_ms:g}",
        "# a node's heartbeat (a show's swap reports travel with it), and its silence that marks it lost",
        f"heartbeat_ms = {hb_ms}",
        f"lost_after_ms = {5 * hb_ms}",
        "# cameras for calibration: room://HOST:PORT (virtual room), opencv:INDEX or a device path, folder:DIR",
        f"cameras = [{', '.join(json.dumps(c) for c in cameras)}]",
        "",
        "[defaults]",
        "# each projector's output resolution unless its slot says otherwise",
        f"width = {width}",
        f"height = {height}",
        "",
        "[slots]",
        "# one entry per projector; e.g. r0c1 = { width = 1280, height = 800 }",
    ]
    for s in slots:
        w, h = (sizes or {}).get(s, (width, height))
        lines.append(f"{s} = {{}}" if (w, h) == (width, height) else f"{s} = {{ width = {w}, height = {h} }}")
    if calibration_mesh is not None:
        lines += ["", "[calibration]", "# the object the projectors light: `shadowless calibrate` poses them onto it",
                  f"mesh = {json.dumps(calibration_mesh)}"]
    return "\n".join(lines) + "\n"


def init_rig(path: str | Path, *, name: str, slots: list[str], width: int = 1920, height: int = 1080,
             content_width: int = 1200, content_height: int = 600, latency_ms: float = 50.0,
             cameras: list[str] = (), force: bool = False, sizes: dict[str, tuple[int, int]] | None = None,
             calibration_mesh: str | None = None) -> Path:
    """Create a rig directory with ``rig.toml`` and a fresh token; refuse to overwrite one.
    ``sizes`` (slot -> (w, h)) overrides ``width`` x ``height`` for some slots; ``calibration_mesh``
    see :func:`render_config`."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise RigError(f"{path} is a file; give a folder for the rig (it is created if missing)")
    if (path / "rig.toml").exists() and not force:
        raise RigError(f"{path} already holds a rig (rig.toml); pass --force to replace its configuration")
    for s in slots:
        if not SLOT_RE.match(s):
            raise RigError(f"slot name {s!r} must be 1-32 letters, digits, '_', '-' or '.'")
    if len(set(slots)) != len(slots) or not slots:
        raise RigError("slot names must be unique and at least one is needed")
    _check_size("output", width, height)
    for s, (w, h) in (sizes or {}).items():
        _check_size(f"slot {s}'s output", w, h)
    _check_size("content", content_width, content_height)
    text = render_config(name, uuid.uuid4().hex[:12], slots, width=width, height=height,
                         content_width=content_width, content_height=content_height, latency_ms=latency_ms,
                         cameras=list(cameras), sizes=sizes, calibration_mesh=calibration_mesh)
    parse_config(text)  # what we write must read back
    path.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path / "rig.toml", text)
    if not (path / "token").exists():
        atomic_write_text(path / "token", new_token() + "\n", mode=0o600)
    return path


class Rig:
    """A rig directory loaded in memory. Every mutation is persisted before it returns."""

    def __init__(self, path: str | Path, *, read_only: bool = False):
        """Load and check every file of the rig at ``path``; any refusal is a one-line RigError naming
        the file and changes nothing on disk. Afterwards temp files of interrupted writes are removed,
        unless ``read_only``: a rig opened to be looked at (``rig show``, ``rig export``, a dry run)
        writes nothing, and refuses every change."""
        self.path = Path(path)
        self.read_only = read_only
        cfg_file = self.path / "rig.toml"
        if not self.path.is_dir():
            what = "no such directory" if not self.path.exists() else "a file, not a directory"
            raise RigError(f"{self.path} is not a rig directory ({what}); create one with `shadowless rig init {self.path}`")
        if not cfg_file.exists() and not cfg_file.is_symlink():
            raise RigError(f"{self.path} is not a rig directory (no rig.toml); create one with `shadowless rig init {self.path}`")
        self.config = parse_config(read_text(cfg_file), source=str(cfg_file))
        self.slots: dict[str, SlotState] = {}
        self.meshes: dict[str, Mesh] = {}
        for name, (w, h) in self.config.slots.items():
            self.slots[name] = self._load_slot(name, w, h)
        self.content: Content | None = self._load_content()
        if not read_only:
            remove_stale_temps(self.path)

    def _writable(self) -> None:
        if self.read_only:
            raise RigError(f"rig {self.path} was opened read-only: nothing may change it here")

    # ---- loading -------------------------------------------------------
    def mesh(self, mesh_id: str) -> Mesh:
        """A mesh the rig holds (``meshes/<id>.npz``); RigError if there is none of that id."""
        if not re.fullmatch(r"[A-Za-z0-9_.-]{1,64}", mesh_id or "") or mesh_id.startswith("."):
            raise RigError(f"mesh id {mesh_id!r} is not a mesh of this rig (ids are letters, digits, '_', '-', '.')")
        if mesh_id not in self.meshes and not (self.path / "meshes" / f"{mesh_id}.npz").exists():
            have = sorted(p.stem for p in (self.path / "meshes").glob("*.npz")) if (self.path / "meshes").is_dir() else []
            raise RigError(f"the rig holds no mesh {mesh_id!r} (it has: {', '.join(have) or 'none'})")
        return self._load_mesh(mesh_id)

    def _load_mesh(self, mesh_id: str) -> Mesh:
        if mesh_id not in self.meshes:
            f = self.path / "meshes" / f"{mesh_id}.npz"
            read_bytes(f)   # missing / a directory: one line
            try:
                with np.load(f) as z:
                    self.meshes[mesh_id] = Mesh(mesh_id, z["vertices"], z["uvs"], z["faces"])
            except (OSError, KeyError, ValueError, EOFError) as exc:
                raise RigError(" ".join(f"{f}: cannot load mesh {mesh_id!r}: {exc}".split())) from None
        return self.meshes[mesh_id]

    def _load_slot(self, name: str, width: int, height: int) -> SlotState:
        """``slots/<name>.json`` (checked by :class:`coordinator.schema.SlotFile`) with its pose, mesh
        and LUT ((C, E) float32 .npy; other dtypes are refused)."""
        f = self.path / "slots" / f"{name}.json"
        if not f.exists() and not f.is_symlink():
            return SlotState(name=name, width=width, height=height)
        hint = "; fix or delete the file to recalibrate this slot"
        try:
            doc: SlotFile = validate(SlotFile, read_json(f), str(f))
        except RigError as exc:
            raise RigError(f"{exc}{hint}") from None
        pose: Pose | None = None
        planned: ProjectionPose | None = None
        try:
            if doc.pose is not None and doc.pose.kind == "homography":
                pose = HomographyPose(np.array(doc.pose.matrix, dtype=np.float64))
            elif doc.pose is not None:
                pose = self._projection(doc.pose)
            if doc.planned is not None:
                planned = self._projection(doc.planned)
        except ValueError as exc:
            raise RigError(f"{f}: {exc}{hint}") from None
        lut = None
        if doc.lut:
            lut_f = self.path / doc.lut
            lut = read_npy(lut_f, ("float32",), "LUT")
            try:
                validate_lut(lut)
            except ValueError as exc:
                raise RigError(f"{lut_f}: {exc} (named by {f})") from None
        return SlotState(name=name, width=doc.width or width, height=doc.height or height, revision=doc.revision,
                         gain=doc.gain, pose=pose, lut=lut, source=doc.source, updated_at=doc.updated_at, planned=planned)

    def _projection(self, doc) -> ProjectionPose:
        """A slot file's projection document (:class:`coordinator.schema.ProjectionDoc`) with its mesh."""
        return ProjectionPose(np.array(doc.matrix, dtype=np.float64), self._load_mesh(doc.mesh), doc.near_mm, doc.far_mm)

    def _load_content(self) -> Content | None:
        """``content/current.json`` (checked by :class:`coordinator.schema.ContentMeta`) and the image
        it names: (H, W) or (H, W, C<=4) uint8/uint16/float32 .npy."""
        meta_f = self.path / "content" / "current.json"
        if not meta_f.exists() and not meta_f.is_symlink():
            return None
        meta: ContentMeta = validate(ContentMeta, read_json(meta_f), str(meta_f))
        img_f = self.path / "content" / meta.file
        img = read_npy(img_f, ("uint8", "uint16", "float32"), "content image")
        try:
            return Content(img, name=meta.name)
        except ValueError as exc:
            raise RigError(f"{img_f}: {exc}") from None

    # ---- mutation (persisted) -----------------------------------------
    def _save_slot(self, st: SlotState) -> None:
        self._save_slots([st])

    def _save_slots(self, states: list[SlotState]) -> None:
        """Write the slots' files (each slot's JSON and LUT) in one batch (:func:`atomic_write_files`:
        each file whole, old or new, whatever happens), then remove older LUT revisions."""
        luts: dict[Path, bytes] = {}       # written before the slot files that name them
        docs: dict[Path, bytes] = {}
        for st in states:
            doc: dict = {"revision": st.revision, "gain": st.gain, "width": st.width, "height": st.height,
                         "source": st.source, "updated_at": st.updated_at}
            if isinstance(st.pose, HomographyPose):
                doc["pose"] = {"kind": "homography", "matrix": st.pose.matrix.tolist()}
            elif isinstance(st.pose, ProjectionPose):
                doc["pose"] = self._projection_doc(st.pose)
            if st.planned is not None:
                doc["planned"] = self._projection_doc(st.planned)
            if st.lut is not None:
                rel = f"luts/{st.name}.r{st.revision}.npy"
                buf = io.BytesIO()
                np.save(buf, np.asarray(st.lut), allow_pickle=False)
                luts[self.path / rel] = buf.getvalue()
                doc["lut"] = rel
            docs[self.path / "slots" / f"{st.name}.json"] = (json.dumps(doc, indent=2, sort_keys=True) + "\n").encode()
        files = {**luts, **docs}
        atomic_write_files(files)
        # remove LUT files of older revisions only after the new state is durable
        for st in states:
            for old in (self.path / "luts").glob(f"{st.name}.r*.npy"):
                if old.name != f"{st.name}.r{st.revision}.npy":
                    old.unlink(missing_ok=True)

    def _projection_doc(self, pose: ProjectionPose) -> dict:
        """A projection pose as its slot-file document, its mesh saved first (once per mesh id)."""
        mesh = pose.mesh
        mf = self.path / "meshes" / f"{mesh.mesh_id}.npz"
        if not mf.exists():
            atomic_save_npz(mf, vertices=mesh.vertices, uvs=mesh.uvs, faces=mesh.faces)
        self.meshes[mesh.mesh_id] = mesh
        return {"kind": "projection", "matrix": pose.matrix.tolist(), "mesh": mesh.mesh_id,
                "near_mm": pose.near_mm, "far_mm": pose.far_mm}

    def slot(self, name: str) -> SlotState:
        try:
            return self.slots[name]
        except KeyError:
            raise RigError(f"slot {name!r} is not in rig {self.config.name!r} (slots: {', '.join(self.slots)})") from None

    _UNSET = object()

    def update_slot(self, name: str, *, pose: Pose | None | object = _UNSET, gain: float | None = None,
                    lut: np.ndarray | None | object = _UNSET, size: tuple[int, int] | None = None,
                    planned: ProjectionPose | None | object = _UNSET, blend: BlendMaps | None | object = _UNSET,
                    blend_at_ns: int | None = None, source: str = "manual") -> SlotState:
        """Change a slot's assignment; bump its revision; persist; return the new state.

        A pose replaces the slot's planned pose (calibration supersedes the plan). A new ``size``
        resamples the planned pose's optics to it (:func:`protos.spaces.scale_intrinsics`: a plan
        is optics, not a measurement; a calibrated pose at another size is stale and stays as is).
        ``blend`` (with ``blend_at_ns``, the rig-clock instant the nodes switch to it, 0 at once)
        lives in memory only: the blend store keeps blends (:mod:`coordinator.blend_store`), so a
        change of the blend alone writes nothing here (a failover costs no file write); the revision
        it bumps is written with the slot's next other change.
        """
        st, persist = self._next_state(name, pose=pose, gain=gain, lut=lut, size=size, planned=planned, blend=blend,
                                       blend_at_ns=blend_at_ns, source=source)
        if persist:
            self._save_slot(st)
        self.slots[name] = st
        return st

    def update_slots(self, names: "list[str] | tuple[str, ...]", **changes) -> list[SlotState]:
        """The same change (:meth:`update_slot`'s keywords) on several slots, their files written in
        one batch (one rename and fsync round for all, instead of a write per slot): every slot is
        checked before any file is written, so a refused change changes none."""
        states = [self._next_state(n, **changes) for n in dict.fromkeys(names)]
        self._save_slots([st for st, persist in states if persist])
        for st, _ in states:
            self.slots[st.name] = st
        return [st for st, _ in states]

    def _next_state(self, name: str, *, pose: Pose | None | object = _UNSET, gain: float | None = None,
                    lut: np.ndarray | None | object = _UNSET, size: tuple[int, int] | None = None,
                    planned: ProjectionPose | None | object = _UNSET, blend: BlendMaps | None | object = _UNSET,
                    blend_at_ns: int | None = None, source: str = "manual") -> tuple[SlotState, bool]:
        """A slot's state after ``update_slot``'s changes, and whether its file must be written."""
        self._writable()
        st = self.slot(name)
        changes: dict = {}
        if blend is not Rig._UNSET:
            if blend is not None and not isinstance(blend, BlendMaps):
                raise ValueError("a slot's blend is a BlendMaps (protos.blend)")
            changes["blend"] = blend
        if blend_at_ns is not None:
            if isinstance(blend_at_ns, bool) or not isinstance(blend_at_ns, (int, np.integer)) or blend_at_ns < 0:
                raise ValueError(f"blend_at_ns must be a rig-clock instant in ns (>= 0), got {blend_at_ns!r}")
            changes["blend_at_ns"] = int(blend_at_ns)
        blend_only = bool(changes) and (pose, lut, planned) == (Rig._UNSET,) * 3 and gain is None and size is None
        if pose is not Rig._UNSET:
            changes["pose"] = pose
            if pose is not None:
                changes["planned"] = None
        if planned is not Rig._UNSET:
            if planned is not None and not isinstance(planned, ProjectionPose):
                raise ValueError("a planned pose is a projection (3x4) onto the layout's surface")
            changes["planned"] = planned
        if gain is not None:
            if not valid_gain(gain):
                raise ValueError(f"gain must be in 0..{MAX_GAIN:g}, got {gain}")
            changes["gain"] = float(gain)
        if lut is not Rig._UNSET:
            if lut is not None:
                lut = np.ascontiguousarray(lut, dtype=np.float32)
                validate_lut(lut)
            changes["lut"] = lut
        if size is not None:
            changes["width"], changes["height"] = _check_size(f"slot {name}", *size)
            if "planned" not in changes and st.planned is not None and (st.width, st.height) != tuple(size):
                S = scale_intrinsics(np.eye(3), (st.width, st.height), tuple(size))
                changes["planned"] = replace(st.planned, matrix=S @ st.planned.matrix)
        if blend_only:      # the slot file holds nothing of the blend: only the revision moves, in memory
            return replace(st, **changes, revision=st.revision + 1), False
        return replace(st, **changes, revision=st.revision + 1, source=source, updated_at=time.time()), True

    def set_content(self, content: Content) -> None:
        self._writable()
        ext = "npy"
        fname = f"{content.content_id}.{ext}"
        atomic_save_npy(self.path / "content" / fname, content.image)
        atomic_write_json(self.path / "content" / "current.json", {"file": fname, "name": content.name,
                                                                 "content_id": content.content_id,
                                                                 "updated_at": time.time()})
        for old in (self.path / "content").glob("*.npy"):
            if old.name != fname:
                old.unlink(missing_ok=True)
        self.content = content

