"""`shadowless rig export` and `shadowless rig import`: a rig directory's calibration to and from
an MPCDI archive (see :mod:`rigctl.mpcdi.archive`).

``export`` only reads the rig directory (it works while a coordinator serves it) and writes the
archive through a temp file and a rename. ``import`` writes poses (and, from archives that carry
the ``shadowless`` extension, gains and LUTs) into the slots through :meth:`Rig.update_slot`, so
revisions bump and every write is atomic; it holds the rig directory's lock
(:mod:`coordinator.rig_lock`) throughout, and so is refused while a coordinator serves the rig.
Blend maps travel too: ``export`` writes the rig's stored blend (:mod:`coordinator.blend_store`)
as each region's alphaMap and betaMap, and ``import`` stores an archive's maps as the rig's
blend, for the slots it imports (the other slots keep the maps they had).
Errors raise RigError/ValueError/OSError, which `shadowless rig` prints as one line (exit 2).
"""
from __future__ import annotations

import argparse
import hashlib
import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from coordinator.blend_store import BlendStoreError, StoredBlend, load_blend, save_blend
from coordinator.errors import RigError
from rigctl.mpcdi.archive import ImportedRig, export_mpcdi, import_mpcdi
from coordinator.rig import HomographyPose, Mesh, Pose, ProjectionPose, Rig, SlotState, valid_gain, validate_lut
from coordinator.rig_lock import RigLock, holder
from protos.store import fsync_dir
from protos import cli_types

__all__ = ["configure_export", "configure_import", "run_export", "run_import"]

FORMATS = ("mpcdi",)
PREFIX = "shadowless rig"


def configure_export(p: argparse.ArgumentParser) -> None:
    p.description = ("Write a rig directory's calibration (poses; gains, LUTs and meshes in the shadowless "
                     "extension) and its stored blend (each projector's alphaMap and betaMap, 16-bit PNGs) to an "
                     "MPCDI archive that other projection tools read. Reads the rig directory only, so it works "
                     "while a coordinator serves it.")
    p.add_argument("dir", metavar="DIR", help="the rig directory")
    p.add_argument("out", metavar="OUT.mpcdi", help="the archive to write")
    p.add_argument("--format", choices=FORMATS, default="mpcdi", help="archive format (default mpcdi)")
    p.add_argument("--force", action="store_true", help="replace OUT if it exists")


def configure_import(p: argparse.ArgumentParser) -> None:
    p.description = ("Write the poses of an MPCDI archive (and its gains and LUTs, when it carries the shadowless "
                     "extension) into the slots of a rig directory, and its alpha and beta maps into the rig's "
                     "blend store (the other slots keep theirs). Only slots in the rig's rig.toml are "
                     "imported; each changed slot's revision bumps. Refused while a coordinator serves the rig.")
    p.add_argument("archive", metavar="IN.mpcdi", type=cli_types.existing_file, help="the archive to read")
    p.add_argument("dir", metavar="DIR", help="the rig directory to write into")
    p.add_argument("--format", choices=FORMATS, default="mpcdi", help="archive format (default mpcdi)")
    p.add_argument("--slots", type=cli_types.names, metavar="A,B,...", help="import only these slots")
    p.add_argument("--dry-run", action="store_true", help="print what would change; write nothing")


# ---------------------------------------------------------------------------- export
def _kib(n: int) -> str:
    return f"{n / 1024:.1f} KiB" if n < 1 << 20 else f"{n / (1 << 20):.1f} MiB"


def _publish(tmp: Path, out: Path, *, force: bool) -> None:
    """Move the finished ``tmp`` to ``out`` (same folder): replace it with ``force``, else refuse
    an existing ``out`` without a window in which another writer's file could be lost."""
    if force:
        os.replace(tmp, out)
        return
    try:
        os.link(tmp, out)             # fails if out exists, atomically
    except FileExistsError:
        raise RigError(f"{out} exists; pass --force to replace it") from None
    except OSError:                   # a filesystem without hard links
        if out.exists():
            raise RigError(f"{out} exists; pass --force to replace it") from None
        os.replace(tmp, out)
    else:
        tmp.unlink()


def run_export(args: argparse.Namespace) -> int:
    """Export rig directory ``args.dir`` to ``args.out``; print one line."""
    rig = Rig(args.dir, read_only=True)
    out = Path(args.out)
    if out.is_dir():
        raise RigError(f"{out} is a folder; give the archive's file name, e.g. {out / (rig.config.name + '.mpcdi')}")
    if out.exists() and not args.force:
        raise RigError(f"{out} exists; pass --force to replace it")
    if not out.parent.is_dir():
        raise RigError(f"{out.parent}: no such folder for the archive")
    slots = list(rig.slots.values())
    try:
        blend = load_blend(rig.path)
    except BlendStoreError as exc:
        print(f"{PREFIX}: warning: the archive gets no blend maps: {exc}", file=sys.stderr)
        blend = None
    fd, name = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        profile = export_mpcdi(tmp, rig_name=rig.config.name, content_size=(rig.config.content_width,
                               rig.config.content_height), slots=slots, blend=blend)
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        size = tmp.stat().st_size
        _publish(tmp, out, force=args.force)
        fsync_dir(out.parent)
    finally:
        tmp.unlink(missing_ok=True)
        tmp.with_name(tmp.name + ".partial").unlink(missing_ok=True)
    unposed = [s.name for s in slots if s.pose is None]
    missing = f"{len(unposed)} without a pose ({', '.join(unposed)})" if unposed else "all with a pose"
    blended = len([s for s in slots if blend is not None and s.name in blend.maps])
    maps = f", blend maps for {blended}" if blended else ""
    print(f"wrote {out}: MPCDI profile {profile}, {len(slots)} slots, {missing}{maps}; {_kib(size)}")
    return 0


# ---------------------------------------------------------------------------- import
@dataclass
class _Plan:
    """What importing one slot does: ``changes`` are :meth:`Rig.update_slot`'s keywords."""

    name: str
    kind: str                                   # the pose it ends with: "homography", "projection" or "no pose"
    changes: dict = field(default_factory=dict)
    refused: str = ""
    note: str = ""


def _same_mesh(a: Mesh, b: Mesh) -> bool:
    return (a.mesh_id == b.mesh_id and np.array_equal(a.vertices, b.vertices) and np.array_equal(a.uvs, b.uvs)
            and np.array_equal(a.faces, b.faces))


def _same_pose(a: Pose | None, b: Pose | None) -> bool:
    if a is None or b is None:
        return a is b
    if a.kind != b.kind or not np.array_equal(a.matrix, b.matrix):
        return False
    return not isinstance(a, ProjectionPose) or ((a.near_mm, a.far_mm) == (b.near_mm, b.far_mm)
                                                 and _same_mesh(a.mesh, b.mesh))


def _same_lut(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    return (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))


def _mesh_on_disk(rig: Rig, mesh_id: str) -> Mesh | None:
    """The mesh ``meshes/<mesh_id>.npz`` of ``rig`` (None if there is none or it does not load)."""
    if mesh_id in rig.meshes:
        return rig.meshes[mesh_id]
    f = rig.path / "meshes" / f"{mesh_id}.npz"
    if not f.is_file():
        return None
    try:
        with np.load(f) as z:
            return Mesh(mesh_id, z["vertices"], z["uvs"], z["faces"])
    except (OSError, KeyError, ValueError, EOFError):
        return None


def _place_mesh(rig: Rig, pose: ProjectionPose) -> ProjectionPose:
    """``pose`` with a mesh id that names its mesh in ``rig``: the archive's id, unless the rig holds
    another mesh under it (then the id gets the mesh's digest appended). RigError for an id that is
    no plain file name."""
    mesh = pose.mesh
    mid = mesh.mesh_id
    if not mid or mid.startswith(".") or any(c in mid for c in "/\\\x00") or len(mid) > 180:
        raise RigError(f"the archive names a mesh {mid!r}, which is no plain file name")
    on_disk = _mesh_on_disk(rig, mid)
    if on_disk is None or _same_mesh(on_disk, mesh):
        return pose
    digest = hashlib.blake2b(digest_size=6)
    for a in (mesh.vertices, mesh.uvs, mesh.faces):
        digest.update(np.ascontiguousarray(a).tobytes())
    renamed = Mesh(f"{mid}-{digest.hexdigest()}", mesh.vertices, mesh.uvs, mesh.faces)
    other = _mesh_on_disk(rig, renamed.mesh_id)
    if other is not None and not _same_mesh(other, renamed):
        raise RigError(f"the rig holds other meshes named {mid} and {renamed.mesh_id}; the archive's mesh would replace them")
    return ProjectionPose(pose.matrix, renamed, pose.near_mm, pose.far_mm)


def _pose_name(pose: Pose | None) -> str:
    return pose.kind if pose is not None else "no pose"


def _plan(rig: Rig, imp: ImportedRig, arch: SlotState, projection: np.ndarray | None) -> _Plan:
    """How importing archive slot ``arch`` (``projection``: its (3, 4) float64 matrix when the
    archive gave one without a mesh) changes the rig's slot of that name."""
    cur = rig.slots[arch.name]
    plan = _Plan(arch.name, _pose_name(cur.pose))
    if (arch.width, arch.height) != (cur.width, cur.height):
        plan.refused = (f"the archive's {arch.name} is {arch.width}x{arch.height} px, the rig's is {cur.width}x{cur.height}: "
                        "its pose would not fit (give the slot that size in rig.toml, or leave it out with --slots)")
        return plan
    pose = arch.pose
    if projection is not None:
        if not isinstance(cur.pose, ProjectionPose):
            plan.refused = ("the archive gives it a projection but no mesh (standard MPCDI carries none), and the rig's "
                            "slot has no mesh to keep; export from shadowless (its extension carries the mesh)")
            return plan
        pose = ProjectionPose(projection, cur.pose.mesh, cur.pose.near_mm, cur.pose.far_mm)
        plan.note = "mesh kept from the rig"
    elif isinstance(pose, HomographyPose) and not imp.exact:
        cw, ch = imp.content_size          # the archive's buffer, normalised onto the rig's content
        scale = np.diag([cw / rig.config.content_width, ch / rig.config.content_height, 1.0])
        pose = HomographyPose(pose.matrix @ scale)
    if isinstance(pose, ProjectionPose):
        pose = _place_mesh(rig, pose)
    if imp.exact or pose is not None:      # the extension lists unposed slots: they end unposed
        if not _same_pose(cur.pose, pose):
            plan.changes["pose"] = pose
        plan.kind = _pose_name(pose)
    if imp.exact:
        if not valid_gain(arch.gain):
            plan.refused = f"the archive's gain {arch.gain} is out of range"
        elif arch.gain != cur.gain:
            plan.changes["gain"] = arch.gain
        if arch.lut is not None:
            try:
                validate_lut(arch.lut)
            except ValueError as exc:
                plan.refused = f"the archive's LUT: {exc}"
        if not _same_lut(cur.lut, arch.lut):
            plan.changes["lut"] = arch.lut
    if plan.refused:
        plan.changes.clear()
    return plan


def _select(rig: Rig, imp: ImportedRig, archive: Path, wanted: list[str] | None) -> list[str]:
    """The slots to import, in the rig's order; warns (one line) about archive slots the rig lacks."""
    in_archive = [s.name for s in imp.slots]
    if wanted is not None:
        for n in wanted:
            rig.slot(n)                    # the usual refusal for a slot the rig lacks, naming its slots
            if n not in in_archive:
                raise RigError(f"slot {n!r} is not in {archive} (its slots: {', '.join(in_archive) or 'none'})")
        return [n for n in rig.slots if n in wanted]
    unknown = [n for n in in_archive if n not in rig.slots]
    if unknown:
        print(f"{PREFIX}: warning: {archive} has slots that rig {rig.config.name!r} lacks, not imported: "
              f"{', '.join(unknown)}", file=sys.stderr)
    chosen = [n for n in rig.slots if n in in_archive]
    if not chosen:
        raise RigError(f"{archive} shares no slot with rig {rig.config.name!r} (archive: {', '.join(in_archive) or 'none'}; "
                       f"rig: {', '.join(rig.slots)})")
    return chosen


def _check_content(rig: Rig, imp: ImportedRig, names: list[str]) -> None:
    """Exact homographies map the archive's content pixels: refuse a rig whose content differs."""
    rig_size = (rig.config.content_width, rig.config.content_height)
    planar = any(isinstance(s.pose, HomographyPose) for s in imp.slots if s.name in names)
    if imp.exact and planar and tuple(imp.content_size) != rig_size:
        raise RigError(f"the archive's content is {imp.content_size[0]}x{imp.content_size[1]} px, rig "
                       f"{rig.config.name!r}'s is {rig_size[0]}x{rig_size[1]}: its homographies map content pixels, "
                       "so set content_width and content_height in rig.toml to match")


def _describe(plan: _Plan, revision: int, dry_run: bool) -> str:
    if plan.refused:
        return f"  {plan.name}: refused"
    if not plan.changes:
        return f"  {plan.name}: {plan.kind}, unchanged"
    what = ", ".join("LUT" if k == "lut" else k for k in plan.changes)
    note = f"; {plan.note}" if plan.note else ""
    verb = "would change" if dry_run else "changed"
    return f"  {plan.name}: {plan.kind}, {verb} ({what}; revision {revision} -> {revision + 1}{note})"


def _blend_to_store(rig: Rig, imp: ImportedRig, archive: Path, plans: list[_Plan]) -> StoredBlend | None:
    """The blend to store after importing ``plans``: the archive's maps for the imported slots
    that were not refused, the stored maps of the other slots; None when the archive has none."""
    taken = {p.name for p in plans if not p.refused}
    new = {n: m for n, m in imp.blend.items() if n in taken}
    if not new:
        return None
    old = load_blend(rig.path)
    kept = {n: m for n, m in (old.maps.items() if old is not None else ()) if n not in taken and n in rig.slots}
    info = {**imp.blend_info, "source": "mpcdi", "archive": archive.name, "imported_at": time.time(),
            "exact": imp.blend_exact, "kept_slots": sorted(kept)}
    return StoredBlend({**kept, **new}, info)


def run_import(args: argparse.Namespace) -> int:
    """Import archive ``args.archive`` into rig directory ``args.dir``; a line per slot, exit 2 if
    a slot was refused (the others are imported)."""
    archive = Path(args.archive)
    rig = Rig(args.dir, read_only=True)    # a rig directory? (before anything else, to say so plainly)
    imp = import_mpcdi(archive)            # the whole archive is read and checked before any write
    names = _select(rig, imp, archive, args.slots)
    _check_content(rig, imp, names)
    if imp.blend:
        load_blend(rig.path)               # a damaged stored blend refuses here, before anything is touched
    lock = None
    if args.dry_run:
        who = holder(rig.path)
        if who is not None:
            print(f"{PREFIX}: warning: rig {rig.path} is in use by {who[1] or 'another process'} (pid {who[0]}); "
                  "the import itself would be refused until it stops", file=sys.stderr)
    else:
        lock = RigLock(rig.path, role="rig import").acquire()
    try:
        if lock is not None:
            rig = Rig(args.dir)            # the state as it is now that nobody else writes
        archived = {s.name: s for s in imp.slots}
        projections = dict(imp.projections)
        plans = [_plan(rig, imp, archived[n], projections.get(n)) for n in names]
        blend = _blend_to_store(rig, imp, archive, plans)
        print(f"{'dry run: ' if args.dry_run else ''}{archive} (MPCDI profile {imp.profile}) into rig "
              f"{rig.config.name!r} ({rig.path}):")
        changed = 0
        for plan in plans:
            print(_describe(plan, rig.slots[plan.name].revision, args.dry_run))
            if plan.changes:
                changed += 1
                if not args.dry_run:
                    rig.update_slot(plan.name, **plan.changes, source="mpcdi")
        if blend is not None:
            new = len(blend.maps) - len(blend.info["kept_slots"])
            how = "the extension's float32 maps" if imp.blend_exact else "the alpha and beta maps' levels"
            print(f"  blend maps: {'would store' if args.dry_run else 'stored'} for {new} slot{'s' * (new != 1)} "
                  f"(from {how})" + (f"; kept for {', '.join(blend.info['kept_slots'])}" if blend.info["kept_slots"] else ""))
            if not args.dry_run:
                save_blend(rig.path, blend)
    finally:
        if lock is not None:
            lock.release()
    refused = [p for p in plans if p.refused]
    for p in refused:
        print(f"{PREFIX}: slot {p.name} refused: {p.refused}", file=sys.stderr)
    if not imp.exact:
        print("note: the archive has no shadowless extension: poses come from its standard data; gains and LUTs "
              "were left as they are")
    ok = len(plans) - len(refused)
    if args.dry_run:
        print(f"dry run: {changed} of {ok} slot{'s' * (ok != 1)} would change; nothing written")
    else:
        print(f"imported {ok} slot{'s' * (ok != 1)}: {changed} changed, {ok - changed} unchanged"
              + (f", {len(refused)} refused" if refused else ""))
    return 2 if refused else 0
