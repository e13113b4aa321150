"""Start-up recovery: whatever a crash (``kill -9``, a power cut after the last fsync) left in a rig
directory is completed, rolled back or quarantined before the coordinator serves it.

Every write of the rig goes through a temp file, fsync and rename (:mod:`protos.store`), and
the multi-file writes order their steps so that each crash point leaves the old state or the new
one plus files nothing names. This pass removes those files and settles the rest:

* **temp files** of atomic writes (``.NAME.XXXXXXXX.tmp``) anywhere in the rig, unless a process
  on this host still holds one open (a ``content add --rig-dir`` or ``coverage`` running beside);
* **uploads** (``assets/uploads/<id>/``): a folder without a readable announcement
  (``spec.json`` missing, truncated, or not hashing to its id) is rolled back, and the operator's
  ``content add`` announces it again; files nobody announced, larger than announced or not plain
  files are removed; a missing ``files/`` is made again. What was received stays: it resumes;
* **assets**: files staged by an add that died (``assets/tmp``) are removed when no add is running
  (adds hold ``assets/.staging.lock`` shared); blobs no manifest names (an add killed between
  moving its blobs and writing its manifest) are removed, or quarantined when a manifest could
  not be read (they may be its); a manifest that does not parse, does not hash to its name or
  names a missing or resized blob is quarantined;
* **rig state**: LUT files (``luts/<slot>.r<N>.npy``) the slot's file does not name and content
  images ``content/current.json`` does not name, left when a crash came between the steps of a
  write, are removed; a calibration run left ``running`` is marked ``interrupted`` (the next
  run with its settings resumes it); a ``show.json`` that is not JSON is quarantined; black
  captures ``compensation/transport.*`` does not name are removed;
* **pairs written one after the other**: ``compensation/transport.json`` and
  ``coverage/coverage.json`` are completed from the metadata ``transport.npz`` and
  ``coverage.npz`` carry when a crash came between the two writes;
* **generations committed by a pointer** (``blend/`` and ``blend/contributions/``,
  :mod:`coordinator.blend_store`): folders the pointer does not name (a save cut before its commit,
  or the older set's clean-up) are removed; a pointer that is damaged or names a missing folder, and
  a live set a file of which is missing or fails its checksum, are quarantined: the rig starts
  without a stored blend and the operator blends again.

Quarantined files move to ``quarantine/<UTC time>/<their path>`` inside the rig, never deleted.
Each thing done is one log line (WARNING for quarantine, INFO otherwise). Nothing here raises: a
step that fails is one ERROR line and the next step runs. Call it with the rig directory's lock
held (:mod:`coordinator.rig_lock`): only temp files (held open?) and staged files (the staging
lock) are checked against processes beside the coordinator.
"""
from __future__ import annotations

import fcntl
import json
import logging
import os
import re
import shutil
import stat
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable


from coordinator.assets import STAGING_LOCK
from coordinator.blend_store import (CONTRIBUTIONS_DIR, POINTER, BlendStoreError, blend_dir, generation_names,
                                     load_blend, load_contributions, read_pointer)
from coordinator.calibration.runs import mark_interrupted
from coordinator.rig import parse_config
from coordinator.show import SHOW_FILE
from protos.store import atomic_write_json, flocked, is_temp_name
from coordinator.uploads import UploadFile, check_spec, upload_id
from protos.asset_manifest import Manifest, ManifestError, is_sha256

log = logging.getLogger(__name__)

__all__ = ["QUARANTINE", "Action", "Recovery", "open_files", "recover"]

#: where damaged files go, inside the rig directory
QUARANTINE = "quarantine"
_LUT = re.compile(r"^(?P<slot>.+)\.r(?P<rev>\d+)\.npy$")


@dataclass(frozen=True)
class Action:
    """One thing the pass did: ``verb`` (removed, rolled back, completed, quarantined), the path
    relative to the rig, and why."""

    verb: str
    path: str
    why: str

    def line(self) -> str:
        return f"start-up recovery: {self.verb} {self.path}: {self.why}"


@dataclass
class Recovery:
    """What :func:`recover` did (``actions``) and the steps it could not finish (``errors``)."""

    rig_dir: Path
    actions: list[Action] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    _stamp: str = ""

    def rel(self, p: Path) -> str:
        try:
            return str(p.relative_to(self.rig_dir))
        except ValueError:
            return str(p)

    def did(self, verb: str, p: Path, why: str) -> None:
        a = Action(verb, self.rel(p), why)
        self.actions.append(a)
        (log.warning if verb == "quarantined" else log.info)("%s", a.line())

    def remove(self, p: Path, why: str, verb: str = "removed") -> None:
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        else:
            p.unlink(missing_ok=True)
        self.did(verb, p, why)

    def quarantine(self, p: Path, why: str) -> None:
        if not self._stamp:
            self._stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
        dest = self.rig_dir / QUARANTINE / self._stamp / self.rel(p)
        dest.parent.mkdir(parents=True, exist_ok=True)
        while dest.exists() or dest.is_symlink():
            dest = dest.with_name(dest.name + "~")
        os.replace(p, dest)
        self.did("quarantined", p, f"{why}; moved to {self.rel(dest)}")

    def step(self, name: str, fn: Callable[[], None]) -> None:
        try:
            fn()
        except Exception as exc:       # noqa: BLE001 - recovery never stops the start
            msg = f"start-up recovery could not finish {name}: {type(exc).__name__}: {exc}"
            self.errors.append(msg)
            log.error("%s", " ".join(msg.split()))


# ---------------------------------------------------------------- temp files
def open_files() -> set[tuple[int, int]]:
    """(device, inode) of every file a process on this host holds open, as far as /proc shows."""
    held: set[tuple[int, int]] = set()
    try:
        pids = [p for p in os.listdir("/proc") if p.isdigit()]
    except OSError:
        return held
    for pid in pids:
        fd_dir = f"/proc/{pid}/fd"
        try:
            fds = os.listdir(fd_dir)
        except OSError:
            continue
        for fd in fds:
            try:
                st = os.stat(f"{fd_dir}/{fd}")
            except OSError:
                continue
            if stat.S_ISREG(st.st_mode):
                held.add((st.st_dev, st.st_ino))
    return held


def _temps(r: Recovery) -> None:
    found: list[tuple[Path, os.stat_result]] = []
    for dirpath, dirnames, filenames in os.walk(r.rig_dir):
        here = Path(dirpath)
        if here == r.rig_dir:
            dirnames[:] = [d for d in dirnames if d != QUARANTINE]
        elif here == r.rig_dir / "assets":
            dirnames[:] = [d for d in dirnames if d != "tmp"]     # the staging step's own
        for name in filenames:
            if is_temp_name(name):
                p = here / name
                st = p.lstat()
                if stat.S_ISREG(st.st_mode):
                    found.append((p, st))
    if not found:
        return
    held = open_files()
    for p, st in found:
        if (st.st_dev, st.st_ino) in held:
            log.info("start-up recovery: left %s: a running process is writing it", r.rel(p))
            continue
        r.remove(p, f"temp file of an interrupted write ({st.st_size} bytes)")


# ---------------------------------------------------------------- uploads
def _spec_files(spec: Path, uid: str) -> dict[str, int] | str:
    """The announced ``{name: size}`` of upload ``uid``, or why its spec cannot be used."""
    try:
        doc = json.loads(spec.read_bytes())
        files = [UploadFile(str(d["name"]), int(d["size"]), str(d["sha256"])) for d in doc["files"]]
        check_spec(files)
    except FileNotFoundError:
        return "announced, but its file list (spec.json) was never written"
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return f"its file list (spec.json) is damaged ({type(exc).__name__}: {exc})"
    if upload_id(files) != uid:
        return "its file list (spec.json) does not hash to its id"
    return {f.name: f.size for f in files}


def _uploads(r: Recovery) -> None:
    root = r.rig_dir / "assets" / "uploads"
    if root.is_symlink() or (root.exists() and not root.is_dir()):
        r.quarantine(root, "not a folder of uploads")
        return
    if not root.is_dir():
        return
    for d in sorted(root.iterdir()):
        if d.is_symlink() or not d.is_dir():
            r.quarantine(d, "not an upload folder")
            continue
        if not is_sha256(d.name):
            r.quarantine(d, "not named by an upload id")
            continue
        files = _spec_files(d / "spec.json", d.name)
        if isinstance(files, str):
            r.remove(d, files + "; the operator's `content add` sends it again", verb="rolled back")
            continue
        for p in sorted(d.iterdir()):
            if p.name not in ("spec.json", "files"):
                r.remove(p, "not part of an upload")
        folder = d / "files"
        if folder.is_symlink() or (folder.exists() and not folder.is_dir()):
            r.remove(folder, "not a folder")
        if not folder.exists():
            folder.mkdir()
            r.did("completed", folder, "made again (the upload resumes from zero bytes)")
            continue
        for p in sorted(folder.iterdir()):
            st = p.lstat()
            if p.name not in files:
                r.remove(p, "a file the upload did not announce")
            elif not stat.S_ISREG(st.st_mode):
                r.remove(p, "not a plain file")
            elif st.st_size > files[p.name]:
                r.remove(p, f"{st.st_size} bytes, more than the announced {files[p.name]}; it is sent again")


# ---------------------------------------------------------------- assets
def _staged(r: Recovery) -> None:
    tmp = r.rig_dir / "assets" / "tmp"
    if not tmp.is_dir() or tmp.is_symlink():
        return
    with flocked(r.rig_dir / "assets" / STAGING_LOCK, fcntl.LOCK_EX | fcntl.LOCK_NB) as free:
        if not free:
            log.info("start-up recovery: left assets/tmp: another process is adding an asset")
            return
        for p in sorted(tmp.iterdir()):
            r.remove(p, "staged by an add that did not finish")


def _assets(r: Recovery) -> None:
    root = r.rig_dir / "assets"
    manifests, blobs = root / "manifests", root / "blobs"
    if not root.is_dir():
        return
    with flocked(root / ".lock", fcntl.LOCK_EX):      # the store's own: no commit or remove meanwhile
        named: set[str] = set()
        unsure = False         # a manifest could not be read: blobs nothing names may be its
        if manifests.is_dir():
            for p in sorted(manifests.iterdir()):
                if is_temp_name(p.name):
                    continue
                aid = p.name[:-5] if p.name.endswith(".json") else ""
                if not is_sha256(aid) or p.is_symlink() or not p.is_file():
                    r.quarantine(p, "not an asset manifest")
                    continue
                try:
                    m = Manifest.from_bytes(p.read_bytes(), asset_id=aid)
                except (ManifestError, OSError, ValueError) as exc:
                    unsure = True
                    r.quarantine(p, " ".join(f"a damaged manifest ({exc})".split()))
                    continue
                bad = _missing_blobs(blobs, m)
                if bad:
                    r.quarantine(p, f"asset {m.name!r} names {bad}")
                    unsure = True
                    continue
                named.update(b.sha256 for b in m.blobs)
        if not blobs.is_dir():
            return
        for sub in sorted(blobs.iterdir()):
            if sub.is_symlink() or not sub.is_dir():
                r.quarantine(sub, "not a blob folder")
                continue
            for p in sorted(sub.iterdir()):
                if is_temp_name(p.name):
                    continue
                if not (is_sha256(p.name) and sub.name == p.name[:2]) or p.is_symlink() or not p.is_file():
                    r.quarantine(p, "not a blob")
                elif p.name not in named:
                    if unsure:
                        r.quarantine(p, "a blob no readable manifest names (kept beside the damaged manifest)")
                    else:
                        r.remove(p, "a blob no manifest names (an add stopped before its manifest)",
                                 verb="rolled back")
            try:
                sub.rmdir()          # only when empty
            except OSError:
                pass


def _missing_blobs(blobs: Path, m: Manifest) -> str:
    for b in m.blobs:
        p = blobs / b.sha256[:2] / b.sha256
        try:
            size = p.stat().st_size
        except OSError:
            return f"a missing blob {b.sha256[:12]} ({b.name})"
        if size != b.size:
            return f"blob {b.sha256[:12]} ({b.name}) of {size} bytes, not {b.size}"
    return ""


# ---------------------------------------------------------------- rig state
def _slot_luts(r: Recovery) -> None:
    luts = r.rig_dir / "luts"
    if not luts.is_dir() or luts.is_symlink():      # a folder an operator linked elsewhere is theirs
        return
    slots = parse_config((r.rig_dir / "rig.toml").read_text()).slots
    current: set[str] = set()
    for s in slots:
        try:
            doc = json.loads((r.rig_dir / "slots" / f"{s}.json").read_bytes())
        except FileNotFoundError:
            continue
        if isinstance(doc, dict) and isinstance(doc.get("lut"), str):
            current.add(doc["lut"])
    for p in sorted(luts.iterdir()):
        m = _LUT.match(p.name)
        if m and m["slot"] in slots and f"luts/{p.name}" not in current and p.is_file():
            r.remove(p, f"a LUT slot {m['slot']}'s file does not name (a write cut before the slot file, or before "
                        f"the older LUT's clean-up)")


def _content(r: Recovery) -> None:
    folder = r.rig_dir / "content"
    if not folder.is_dir() or folder.is_symlink():
        return
    meta = folder / "current.json"
    try:
        doc = json.loads(meta.read_bytes())
        keep = str(doc["file"]) if isinstance(doc, dict) else None
    except FileNotFoundError:
        keep = ""
    if keep is None:
        return                    # a damaged current.json: the rig's load says so; nothing goes
    for p in sorted(folder.glob("*.npy")):
        if p.name != keep and p.is_file():
            r.remove(p, "a content image current.json does not name (a write cut before its clean-up)")


def _calibration(r: Recovery) -> None:
    f = mark_interrupted(r.rig_dir)
    if f is not None:
        r.did("completed", f, "a calibration run stopped by the crash is marked interrupted (the next run resumes it)")


def _show(r: Recovery) -> None:
    f = r.rig_dir / SHOW_FILE
    if f.is_symlink() or (f.exists() and not f.is_file()):
        r.quarantine(f, "not a file")
        return
    try:
        doc = json.loads(f.read_bytes())
    except FileNotFoundError:
        return
    except ValueError as exc:
        r.quarantine(f, f"not JSON ({exc}); no show is taken back")
        return
    if not isinstance(doc, dict):
        r.quarantine(f, "not a JSON object; no show is taken back")


def _compensation(r: Recovery) -> None:
    d = r.rig_dir / "compensation"
    npz, js = d / "transport.npz", d / "transport.json"
    blacks = sorted(d.glob("black-*.npy")) if d.is_dir() else []
    if not blacks and not npz.exists():
        return
    from coordinator.compensation.store import stored_transport_meta   # SciPy: only for a rig that has L
    meta = stored_transport_meta(d)
    try:
        doc = json.loads(js.read_bytes())
    except FileNotFoundError:
        doc = None
    except ValueError:
        doc = {}
    if meta is not None and json.dumps(doc, sort_keys=True) != json.dumps(meta, sort_keys=True):
        atomic_write_json(js, meta)
        r.did("completed", js, "rewritten from transport.npz's metadata (a save cut between the two files)")
        doc = meta
    keep = {str(x.get("black_file")) for x in (meta, doc) if isinstance(x, dict)}
    if meta is None and npz.exists():
        return                    # an unreadable L: which black capture is its cannot be told
    for p in blacks:
        if p.name not in keep:
            r.remove(p, "a black capture no stored light transport names (a save cut before its clean-up)")


def _coverage(r: Recovery) -> None:
    if not (r.rig_dir / "coverage" / "coverage.npz").exists():
        return
    from coordinator.coverage_store import coverage_dir, summary_behind   # OpenCV, GL: only for a rig with coverage
    doc = summary_behind(r.rig_dir)
    if doc is not None:
        js = coverage_dir(r.rig_dir) / "coverage.json"
        atomic_write_json(js, doc)
        r.did("completed", js, "rewritten from coverage.npz's summary (a save cut between the two files)")


def _blend(r: Recovery) -> None:
    root = blend_dir(r.rig_dir)
    if not root.is_dir() or root.is_symlink():
        return
    for folder, prefix, kind, load in ((root, "g", "blend", load_blend),
                                       (root / CONTRIBUTIONS_DIR, "c", "contributions", load_contributions)):
        if folder.is_dir() and not folder.is_symlink():
            with flocked(folder / ".lock", fcntl.LOCK_EX):     # the store's own: no save meanwhile
                _generations(r, folder, prefix, kind, load)


def _generations(r: Recovery, folder: Path, prefix: str, kind: str, load: Callable) -> None:
    pointer = folder / POINTER
    try:
        live = read_pointer(folder, prefix)
    except BlendStoreError as exc:
        r.quarantine(pointer, f"{exc}; the rig starts without a stored {kind}")
        for g in generation_names(folder, prefix):
            r.quarantine(folder / g, f"a {kind} the damaged pointer may have named")
        return
    if live is not None and not (folder / live).is_dir():
        r.quarantine(pointer, f"it names {live}, which is missing; the rig starts without a stored {kind}")
        live = None
    for g in generation_names(folder, prefix):
        if g != live:
            r.remove(folder / g, f"a {kind} no pointer names (a save cut before its commit, or the older "
                                 f"{kind}'s clean-up)", verb="rolled back")
    if live is None:
        return
    try:
        load(r.rig_dir)
    except BlendStoreError as exc:
        r.quarantine(folder / live, str(exc))
        r.quarantine(pointer, f"it named the damaged {kind} {live}; the rig starts without a stored {kind}")


# ---------------------------------------------------------------- the pass
def recover(rig_dir: str | os.PathLike[str]) -> Recovery:
    """Settle what a crash left in ``rig_dir`` (see the module docstring); never raises.

    Call with the rig directory's lock held and before anything serves the rig. Returns what was
    done; every action was logged as one line.
    """
    r = Recovery(Path(rig_dir))
    for name, fn in (("temp files", _temps), ("uploads", _uploads), ("staged assets", _staged),
                     ("assets", _assets), ("LUTs", _slot_luts), ("content", _content),
                     ("calibration run", _calibration), ("show.json", _show),
                     ("compensation", _compensation), ("coverage", _coverage), ("blend", _blend)):
        r.step(name, lambda fn=fn: fn(r))
    return r
