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
import json
import re
import time
import tomllib
import uuid
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from coordinator.errors import RigError
from coordinator.store import atomic_save_npy, atomic_save_npz, atomic_write_json, atomic_write_text, remove_stale_temps
from protos.auth import new_token

SLOT_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,31}$")
MIN_SIDE, MAX_SIDE = 16, 16384


@dataclass(frozen=True)
class HomographyPose:
    """Planar pose: ``matrix`` (3, 3) float64 maps content px to projector px."""

    matrix: np.ndarray

    kind = "homography"

    def __post_init__(self):
        m = np.asarray(self.matrix, dtype=np.float64)
        if m.shape != (3, 3) or not np.all(np.isfinite(m)) or abs(np.linalg.det(m)) < 1e-12:
            raise ValueError(f"a homography must be a finite, invertible (3, 3) matrix, got shape {m.shape}")
        object.__setattr__(self, "matrix", m)


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
        if not 0 < self.near_mm < self.far_mm:
            raise ValueError("projection pose needs 0 < near_mm < far_mm")
        object.__setattr__(self, "matrix", m)


Pose = HomographyPose | ProjectionPose


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


#: rigs with more projectors than this default to a heartbeat every 2 s instead of every second
LARGE_RIG_SLOTS = 64


def default_heartbeat_ms(n_slots: int) -> int:
    """A node's heartbeat interval when rig.toml does not set one: 1 s, 2 s for rigs of more than
    LARGE_RIG_SLOTS projectors (each heartbeat costs the coordinator about a quarter of a
    millisecond of CPU, `bench swarm`; a node counts as lost after five missed)."""
    return 1000 if n_slots <= LARGE_RIG_SLOTS else 2000


#: a slot's linear gain lies in 0..MAX_GAIN (0: its light off)
MAX_GAIN = 16.0


def valid_gain(gain: object) -> bool:
    """Whether ``gain`` is a number (not a bool) in 0..MAX_GAIN."""
    return (not isinstance(gain, bool) and isinstance(gain, (int, float, np.floating)) and bool(np.isfinite(gain))
            and 0.0 <= gain <= MAX_GAIN)


def _check_size(what: str, w: object, h: object) -> tuple[int, int]:
    if not (isinstance(w, int) and isinstance(h, int) and MIN_SIDE <= w <= MAX_SIDE and MIN_SIDE <= h <= MAX_SIDE):
        raise RigError(f"{what}: size must be integers in {MIN_SIDE}..{MAX_SIDE}, got {w}x{h}")
    return w, h


def parse_config(text: str, *, source: str = "rig.toml") -> RigConfig:
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RigError(f"{source}: not valid TOML: {exc}") from exc
    for key in ("name", "id"):
        if not isinstance(doc.get(key), str) or not doc[key]:
            raise RigError(f"{source}: `{key}` must be a non-empty string")
    defaults = doc.get("defaults", {})
    dw, dh = defaults.get("width", 1920), defaults.get("height", 1080)
    _check_size(f"{source} [defaults]", dw, dh)
    slots_doc = doc.get("slots")
    if not isinstance(slots_doc, dict) or not slots_doc:
        raise RigError(f"{source}: needs a [slots] table with at least one slot (e.g. r0c0 = {{}})")
    slots: dict[str, tuple[int, int]] = {}
    for name, spec in slots_doc.items():
        if not SLOT_RE.match(name):
            raise RigError(f"{source}: slot name {name!r} must be 1-32 letters, digits, '_', '-' or '.'")
        if not isinstance(spec, dict):
            raise RigError(f"{source}: slot {name} must be a table, e.g. {name} = {{ width = 1920, height = 1080 }}")
        slots[name] = _check_size(f"{source} slot {name}", spec.get("width", dw), spec.get("height", dh))
    cw, ch = _check_size(f"{source} content", doc.get("content_width", 1200), doc.get("content_height", 600))
    latency = doc.get("latency_ms", 50.0)
    if not isinstance(latency, (int, float)) or not 1 <= latency <= 5000:
        raise RigError(f"{source}: latency_ms must be a number in 1..5000, got {latency!r}")
    hb = doc.get("heartbeat_ms", default_heartbeat_ms(len(slots)))
    lost = doc.get("lost_after_ms", max(5000, 5 * hb if isinstance(hb, int) else 5000))
    if not isinstance(hb, int) or not 50 <= hb <= 60_000 or not isinstance(lost, int) or lost < 2 * hb:
        raise RigError(f"{source}: heartbeat_ms must be 50..60000 and lost_after_ms at least twice it")
    cameras = doc.get("cameras", [])
    if not isinstance(cameras, list) or not all(isinstance(c, str) and c for c in cameras):
        raise RigError(f'{source}: cameras must be a list of sources, e.g. cameras = ["room://127.0.0.1:7700", "opencv:0"]')
    return RigConfig(
        name=doc["name"], rig_id=doc["id"], slots=slots, content_width=cw, content_height=ch,
        latency_ms=float(latency), heartbeat_ms=hb, lost_after_ms=lost, cameras=tuple(cameras),
    )


def grid_slots(rows: int, cols: int) -> list[str]:
    return [f"r{r}c{c}" for r in range(rows) for c in range(cols)]


def render_config(name: str, rig_id: str, slots: list[str], *, width: int, height: int,
                  content_width: int, content_height: int, latency_ms: float, cameras: list[str] = ()) -> str:
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
    lines += [f"{s} = {{}}" for s in slots]
    return "\n".join(lines) + "\n"


def init_rig(path: str | Path, *, name: str, slots: list[str], width: int = 1920, height: int = 1080,
             content_width: int = 1200, content_height: int = 600, latency_ms: float = 50.0,
             cameras: list[str] = (), force: bool = False) -> Path:
    """Create a rig directory with ``rig.toml`` and a fresh token; refuse to overwrite one."""
    path = Path(path)
    if (path / "rig.toml").exists() and not force:
        raise RigError(f"{path} already holds a rig (rig.toml); pass --force to replace its configuration")
    for s in slots:
        if not SLOT_RE.match(s):
            raise RigError(f"slot name {s!r} must be 1-32 letters, digits, '_', '-' or '.'")
    if len(set(slots)) != len(slots) or not slots:
        raise RigError("slot names must be unique and at least one is needed")
    _check_size("output", width, height)
    _check_size("content", content_width, content_height)
    text = render_config(name, uuid.uuid4().hex[:12], slots, width=width, height=height,
                         content_width=content_width, content_height=content_height, latency_ms=latency_ms,
                         cameras=list(cameras))
    parse_config(text)  # what we write must read back
    path.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path / "rig.toml", text)
    if not (path / "token").exists():
        atomic_write_text(path / "token", new_token() + "\n", mode=0o600)
    return path


class Rig:
    """A rig directory loaded in memory. Every mutation is persisted before it returns."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        cfg_file = self.path / "rig.toml"
        if not cfg_file.exists():
            raise RigError(f"{self.path} is not a rig directory (no rig.toml); create one with `shadowless rig init {self.path}`")
        remove_stale_temps(self.path)
        self.config = parse_config(cfg_file.read_text(), source=str(cfg_file))
        self.slots: dict[str, SlotState] = {}
        self.meshes: dict[str, Mesh] = {}
        for name, (w, h) in self.config.slots.items():
            self.slots[name] = self._load_slot(name, w, h)
        self.content: Content | None = self._load_content()

    # ---- loading -------------------------------------------------------
    def _load_mesh(self, mesh_id: str) -> Mesh:
        if mesh_id not in self.meshes:
            f = self.path / "meshes" / f"{mesh_id}.npz"
            try:
                with np.load(f) as z:
                    self.meshes[mesh_id] = Mesh(mesh_id, z["vertices"], z["uvs"], z["faces"])
            except (OSError, KeyError, ValueError) as exc:
                raise RigError(f"{f}: cannot load mesh {mesh_id!r}: {exc}") from exc
        return self.meshes[mesh_id]

    def _load_slot(self, name: str, width: int, height: int) -> SlotState:
        f = self.path / "slots" / f"{name}.json"
        if not f.exists():
            return SlotState(name=name, width=width, height=height)

        try:
            doc = json.loads(f.read_text())
            pose_doc = doc.get("pose")
            pose: Pose | None = None
            if pose_doc and pose_doc["kind"] == "homography":
                pose = HomographyPose(np.array(pose_doc["matrix"], dtype=np.float64))
            elif pose_doc and pose_doc["kind"] == "projection":
                pose = ProjectionPose(np.array(pose_doc["matrix"], dtype=np.float64), self._load_mesh(pose_doc["mesh"]),
                                      float(pose_doc.get("near_mm", 100.0)), float(pose_doc.get("far_mm", 10_000.0)))
            lut = None
            if doc.get("lut"):
                lut = np.load(self.path / doc["lut"], allow_pickle=False).astype(np.float32)
                validate_lut(lut)
            w, h = doc.get("width", width), doc.get("height", height)
            _check_size(str(f), w, h)
            gain = doc.get("gain", 1.0)
            if not valid_gain(gain):
                raise RigError(f"{f}: gain must be a number in 0..{MAX_GAIN:g}, got {gain!r}; fix or delete the file to "
                               "recalibrate this slot")
            return SlotState(name=name, width=w, height=h, revision=int(doc.get("revision", 0)),
                             gain=float(gain), pose=pose, lut=lut, source=str(doc.get("source", "")),
                             updated_at=float(doc.get("updated_at", 0.0)))
        except RigError:
            raise
        except (ValueError, KeyError, TypeError, OSError) as exc:
            raise RigError(f"{f}: invalid slot state ({exc}); fix or delete the file to recalibrate this slot") from exc

    def _load_content(self) -> Content | None:
        meta_f = self.path / "content" / "current.json"
        if not meta_f.exists():
            return None

        try:
            meta = json.loads(meta_f.read_text())
            img = np.load(self.path / "content" / meta["file"], allow_pickle=False)
            return Content(img, name=meta.get("name", ""))
        except (OSError, KeyError, ValueError) as exc:
            raise RigError(f"{meta_f}: cannot load the rig's content ({exc})") from exc

    # ---- mutation (persisted) -----------------------------------------
    def _save_slot(self, st: SlotState) -> None:
        doc: dict = {"revision": st.revision, "gain": st.gain, "width": st.width, "height": st.height,
                     "source": st.source, "updated_at": st.updated_at}
        if isinstance(st.pose, HomographyPose):
            doc["pose"] = {"kind": "homography", "matrix": st.pose.matrix.tolist()}
        elif isinstance(st.pose, ProjectionPose):
            mesh = st.pose.mesh
            mf = self.path / "meshes" / f"{mesh.mesh_id}.npz"
            if not mf.exists():
                atomic_save_npz(mf, vertices=mesh.vertices, uvs=mesh.uvs, faces=mesh.faces)
            self.meshes[mesh.mesh_id] = mesh
            doc["pose"] = {"kind": "projection", "matrix": st.pose.matrix.tolist(), "mesh": mesh.mesh_id,
                           "near_mm": st.pose.near_mm, "far_mm": st.pose.far_mm}
        if st.lut is not None:
            rel = f"luts/{st.name}.r{st.revision}.npy"
            atomic_save_npy(self.path / rel, st.lut)
            doc["lut"] = rel
        atomic_write_json(self.path / "slots" / f"{st.name}.json", doc)
        # remove LUT files of older revisions only after the new state is durable
        for old in (self.path / "luts").glob(f"{st.name}.r*.npy"):
            if old.name != f"{st.name}.r{st.revision}.npy":
                old.unlink(missing_ok=True)

    def slot(self, name: str) -> SlotState:
        try:
            return self.slots[name]
        except KeyError:
            raise RigError(f"slot {name!r} is not in rig {self.config.name!r} (slots: {', '.join(self.slots)})") from None

    _UNSET = object()

    def update_slot(self, name: str, *, pose: Pose | None | object = _UNSET, gain: float | None = None,
                    lut: np.ndarray | None | object = _UNSET, size: tuple[int, int] | None = None,
                    source: str = "manual") -> SlotState:
        """Change a slot's assignment; bump its revision; persist; return the new state."""
        st = self.slot(name)
        changes: dict = {}
        if pose is not Rig._UNSET:
            changes["pose"] = pose
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
        st = replace(st, **changes, revision=st.revision + 1, source=source, updated_at=time.time())
        self._save_slot(st)
        self.slots[name] = st
        return st

    def set_content(self, content: Content) -> None:
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


def validate_lut(lut: np.ndarray) -> None:
    """A LUT is (C, E) float32 with C in {1, 3}, 2 <= E <= 65536, values in [0, 1], finite."""
    if lut.ndim != 2 or lut.shape[0] not in (1, 3) or not 2 <= lut.shape[1] <= 65536:
        raise ValueError(f"a LUT must be (C, E) with C in {{1, 3}} and 2 <= E <= 65536, got {lut.shape}")
    if not np.all(np.isfinite(lut)) or lut.min() < 0.0 or lut.max() > 1.0:
        raise ValueError("LUT values must be finite and within [0, 1]")
