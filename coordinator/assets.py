"""The asset store: content (stills, image sequences, videos) kept in the rig directory.

Layout under the rig directory::

    assets/blobs/<first 2 hex>/<sha256>    a file's bytes, named by their SHA-256 (read-only)
    assets/manifests/<asset_id>.json       a manifest's canonical bytes: the file hashes to its name
    assets/tmp/                            files being added (a killed add may leave one; swept later)
    assets/.lock                           taken while an add commits and while a remove deletes
    assets/.staging.lock                   held shared by every add, start-up recovery's exclusively

An asset is described by a :class:`protos.asset_manifest.Manifest`. Adding streams every source
file in chunks into ``assets/tmp`` while hashing it (a multi-GB video never sits in memory), then,
under the lock, renames the blobs into place and writes the manifest last, each step atomic
(:func:`protos.store.atomic_file`). So a manifest only ever names blobs that are there, the
same content added twice is the same asset and stores nothing new, and an add that fails (or is
killed) leaves no manifest behind.
"""
from __future__ import annotations

import dataclasses
import fcntl
import hashlib
import logging
import math
import os
import re
import time
import uuid
from contextlib import contextmanager
from fractions import Fraction
from pathlib import Path
from typing import BinaryIO, Callable, Iterator


from coordinator.asset_probe import (DEFAULT_SEQUENCE_FPS, LONG_GOP_S, STILL_SUFFIXES, VIDEO_SUFFIXES, Note, Probe,
                                     keyframe_gap_s, probe_sequence, probe_still, probe_video, sequence_files)
from coordinator.errors import AssetError
from protos.store import atomic_file, atomic_write_bytes, flocked, fsync_dir
from protos.asset_manifest import Blob, Manifest, ManifestError, is_sha256

log = logging.getLogger(__name__)

CHUNK_BYTES = 1 << 20          # streaming unit for hashing, copying and verifying
MAX_READ_BYTES = 64 << 20      # read_blob's largest chunk
MIN_PREFIX = 4                 # shortest id prefix `get` accepts
STALE_TMP_S = 3600.0           # files in assets/tmp untouched this long are leftovers of killed adds
#: an add holds this (under assets/) shared while it stages and commits; start-up recovery empties
#: assets/tmp only when it can take it exclusively (:mod:`coordinator.recovery`)
STAGING_LOCK = ".staging.lock"
_NAME_MAX = 200

Progress = Callable[[int, int], None]


# ---------------------------------------------------------------- hashing
def copy_hashing(src: BinaryIO, dst: BinaryIO | None, *, on_chunk: Callable[[int], None] | None = None) -> tuple[str, int]:
    """Stream ``src`` into ``dst`` (or nowhere) in ``CHUNK_BYTES`` chunks; its SHA-256 and size."""
    h, n = hashlib.sha256(), 0
    while chunk := src.read(CHUNK_BYTES):
        h.update(chunk)
        if dst is not None:
            dst.write(chunk)
        n += len(chunk)
        if on_chunk:
            on_chunk(len(chunk))
    return h.hexdigest(), n


def _exact_rate(src: Path, probe: Probe, rate: Fraction) -> Probe:
    """``probe`` with the exact ``rate`` (its fps and ``extra.rate``) when the container's rate agrees."""
    if rate <= 0 or not math.isclose(float(rate), probe.fps, rel_tol=1e-4):
        raise AssetError(f"{src}: the video runs at {probe.fps:g} fps, not {float(rate):g}")
    return dataclasses.replace(probe, fps=float(rate), extra={**probe.extra, "rate": f"{rate.numerator}/{rate.denominator}"})


# ---------------------------------------------------------------- the store
class AssetStore:
    """The assets of one rig directory (see the module docstring for the layout)."""

    def __init__(self, rig_dir: str | os.PathLike[str]):
        self.rig_dir = Path(rig_dir)
        if not self.rig_dir.is_dir():
            raise AssetError(f"{self.rig_dir}: no such rig directory")
        self.root = self.rig_dir / "assets"
        self.blobs_dir = self.root / "blobs"
        self.manifests_dir = self.root / "manifests"
        self.tmp_dir = self.root / "tmp"

    # ------------------------------------------------------------ paths and lock
    def blob_path(self, sha256: str) -> Path:
        if not is_sha256(sha256):
            raise AssetError(f"{sha256!r} is not a blob name (64 lowercase hex digits)")
        return self.blobs_dir / sha256[:2] / sha256

    def manifest_path(self, asset_id: str) -> Path:
        if not is_sha256(asset_id):
            raise AssetError(f"{asset_id!r} is not an asset id (64 lowercase hex digits)")
        return self.manifests_dir / f"{asset_id}.json"

    @contextmanager
    def _locked(self, name: str = ".lock", mode: int = fcntl.LOCK_EX) -> Iterator[None]:
        with flocked(self.root / name, mode):
            yield

    def _ids(self) -> list[str]:
        return [] if not self.manifests_dir.is_dir() else sorted(p.stem for p in self.manifests_dir.glob("*.json") if is_sha256(p.stem))

    def _load(self, asset_id: str) -> Manifest:
        path = self.manifest_path(asset_id)
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            raise AssetError(f"no asset {asset_id}") from None
        except OSError as exc:   # e.g. a directory where the manifest should be
            raise AssetError(f"{path}: cannot read asset {asset_id[:12]}'s manifest ({exc.strerror})") from None
        try:
            return Manifest.from_bytes(data, asset_id=asset_id)
        except ManifestError as exc:
            raise AssetError(" ".join(f"{path}: asset {asset_id[:12]}: its manifest is damaged ({exc})".split())) from exc

    def _referenced(self, *, exclude: str | None = None) -> set[str]:
        refs: set[str] = set()
        for aid in self._ids():
            if aid == exclude:
                continue
            try:
                refs.update(b.sha256 for b in self._load(aid).blobs)
            except AssetError as exc:
                raise AssetError(f"{exc}; fix or remove it before removing assets (its blobs are unknown)") from exc
        return refs

    # ------------------------------------------------------------ adding
    def add(self, path: str | os.PathLike[str], *, name: str | None = None, fps: float | None = None,
            progress: Progress | None = None, note: Note | None = None, rate: Fraction | None = None) -> Manifest:
        """Add a still or video file, or a folder of images as a sequence; return its manifest.

        Parameters
        ----------
        path
            A still (``.png``, ``.tif``/``.tiff``, ``.jpg``/``.jpeg``, ``.npy`` float32), a video
            (``.mp4``, ``.mov``, ``.mkv``, ``.avi``) or a folder of stills (frames sorted by name).
        name
            The asset's name (default: the file's stem or the folder's name).
        fps
            A sequence's frame rate (default 30, with a note); for a video, only when its
            container has none; refused for a still.
        progress
            Called with (bytes hashed, total bytes) after every chunk.
        note
            Called with notes for the operator (default: logged as warnings).
        rate
            A video's exact frame rate, for a file this program wrote (e.g. a compensated video):
            recorded as the asset's rate when the container's agrees within 1e-4 (Matroska keeps
            millisecond timestamps, so its rate may be an approximation); refused otherwise.

        Raises
        ------
        AssetError
            Unreadable or unsupported input (naming the file); nothing of it stays in the store.
        """
        note = note or log.warning
        src = Path(path)
        if fps is not None and not (math.isfinite(fps) and fps > 0):
            raise AssetError(f"fps must be a finite number > 0, got {fps}")
        if src.is_dir():
            files = sequence_files(src, note=note)
            if fps is None:
                fps = DEFAULT_SEQUENCE_FPS
                note(f"sequence {src.name!r}: no frame rate given, assuming {fps:g} fps (the rate is part of the "
                     f"asset; add it again with --fps to change it)")
            kind, probe = "sequence", probe_sequence(files, fps=fps)
        elif src.is_file():
            files = [src]
            suffix = src.suffix.lower()
            if suffix in STILL_SUFFIXES:
                if fps is not None:
                    raise AssetError(f"{src}: a still has no frame rate (--fps is for sequences and videos)")
                kind, probe = "still", probe_still(src)
            elif suffix in VIDEO_SUFFIXES:
                kind, probe = "video", probe_video(src, fps=fps)
                if rate is not None:
                    probe = _exact_rate(src, probe, Fraction(rate))
                gap = keyframe_gap_s(src, probe.fps)
                if gap is not None and gap > LONG_GOP_S:
                    note(f"{src.name}: keyframes up to {gap:.1f} s apart; a node that joins mid-show decodes up to "
                         f"that much video before it shows a frame (re-encode with a keyframe every second or two, "
                         f"e.g. ffmpeg -g {max(1, round(probe.fps))})")
            else:
                raise AssetError(f"{src}: unsupported file type {src.suffix or '(no suffix)'!r} (stills: "
                                 f"{', '.join(STILL_SUFFIXES)}; videos: {', '.join(VIDEO_SUFFIXES)}; or a folder of stills)")
        else:
            raise AssetError(f"{src}: no such file or folder")
        name = (src.stem if src.is_file() else src.resolve().name) if name is None else name.strip()
        if not name or len(name) > _NAME_MAX or any(ord(c) < 32 for c in name):
            raise AssetError(f"asset name must be 1-{_NAME_MAX} printable characters, got {name!r}")

        self._sweep_tmp()
        staged: list[tuple[str, Path]] = []
        with self._locked(STAGING_LOCK, fcntl.LOCK_SH):     # recovery leaves assets/tmp alone meanwhile
            try:
                blobs = self._stage(files, staged, progress)
                manifest = Manifest(kind=kind, name=name, blobs=tuple(blobs), width=probe.width, height=probe.height,
                                    channels=probe.channels, bit_depth=probe.bit_depth, frames=probe.frames,
                                    fps=float(probe.fps), extra=dict(probe.extra))
                self._commit(manifest, staged)
            except ManifestError as exc:
                raise AssetError(f"{src}: {exc}") from exc
            finally:
                for _, tmp in staged:
                    tmp.unlink(missing_ok=True)
        return manifest

    def _stage(self, files: list[Path], staged: list[tuple[str, Path]], progress: Progress | None) -> list[Blob]:
        """Copy ``files`` into assets/tmp, hashing on the fly; append (sha, tmp path) to ``staged``."""
        sizes = [f.stat().st_size for f in files]
        total, done = sum(sizes), 0

        def on_chunk(n: int) -> None:
            nonlocal done
            done += n
            if progress:
                progress(done, total)

        blobs = []
        for f, expected in zip(files, sizes):
            tmp = self.tmp_dir / f"{uuid.uuid4().hex}.blob"
            try:
                with open(f, "rb") as src, atomic_file(tmp, mode=0o444) as dst:
                    sha, size = copy_hashing(src, dst, on_chunk=on_chunk)
                    if size != expected:
                        raise AssetError(f"{f}: changed while being added ({expected} bytes, then {size}); try again")
            except OSError as exc:
                raise AssetError(f"{f}: cannot be copied into the asset store ({exc})") from exc
            staged.append((sha, tmp))
            blobs.append(Blob(sha256=sha, size=size, name=f.name))
        return blobs

    def _commit(self, manifest: Manifest, staged: list[tuple[str, Path]]) -> None:
        """Under the lock: move new blobs into place, then write the manifest (last)."""
        mpath = self.manifest_path(manifest.asset_id)
        with self._locked():
            created: list[Path] = []
            try:
                for sha, tmp in staged:
                    final = self.blob_path(sha)
                    if final.exists():
                        continue  # already stored: the staged copy is dropped by add()
                    final.parent.mkdir(parents=True, exist_ok=True)
                    os.replace(tmp, final)
                    created.append(final)
                    fsync_dir(final.parent)
                if not mpath.exists():
                    atomic_write_bytes(mpath, manifest.canonical(), mode=0o444)
            except BaseException:
                try:
                    refs = self._referenced()
                except AssetError:
                    refs = None  # cannot tell: keep the blobs rather than risk another asset's
                for p in created if refs is not None else ():
                    if p.name not in refs:
                        p.unlink(missing_ok=True)
                raise

    def _sweep_tmp(self) -> None:
        """Delete files in assets/tmp that no add has touched for ``STALE_TMP_S`` (killed adds), and
        only while no other add is staging (one that holds the staging lock is not dead)."""
        if not self.tmp_dir.is_dir():
            return
        with flocked(self.root / STAGING_LOCK, fcntl.LOCK_EX | fcntl.LOCK_NB) as free:
            if not free:
                return
            now = time.time()
            for p in self.tmp_dir.iterdir():
                try:
                    if p.is_file() and now - p.stat().st_mtime > STALE_TMP_S:
                        p.unlink()
                except OSError:
                    pass

    # ------------------------------------------------------------ finding
    def resolve(self, key: str) -> str:
        """The asset id for a full id, a unique id prefix (4+ hex digits) or a unique name;
        :class:`AssetError` when nothing matches or several assets do (listing them)."""
        key = key.strip()
        ids = self._ids()
        if key in ids:
            return key
        matches: dict[str, str] = {}
        low = key.lower()
        if len(low) >= MIN_PREFIX and re.fullmatch(r"[0-9a-f]+", low):
            matches.update({aid: "" for aid in ids if aid.startswith(low)})
        for aid, m in self.list():
            if m.name == key:
                matches[aid] = m.name
        if len(matches) == 1:
            return next(iter(matches))
        if not matches:
            hint = f" (an id prefix needs at least {MIN_PREFIX} hex digits)" if re.fullmatch(r"[0-9a-fA-F]{1,3}", key) else ""
            raise AssetError(f"no asset matches {key!r}{hint}; `shadowless content list` shows them")
        listed = ", ".join(f"{aid[:12]}" + (f" ({n})" if n else "") for aid, n in sorted(matches.items()))
        raise AssetError(f"{key!r} is ambiguous: it matches {len(matches)} assets: {listed}; give more of the id")

    def get(self, key: str) -> Manifest:
        """The manifest of the asset named by a full id, a unique id prefix or a unique name."""
        return self._load(self.resolve(key))

    def list(self) -> list[tuple[str, Manifest]]:
        """Every asset as (asset id, manifest), sorted by name then id; damaged manifests are logged
        and skipped (``verify`` reports them)."""
        out = []
        for aid in self._ids():
            try:
                out.append((aid, self._load(aid)))
            except AssetError as exc:
                log.warning("%s", exc)
        return sorted(out, key=lambda t: (t[1].name, t[0]))

    # ------------------------------------------------------------ removing
    def remove(self, asset_id: str) -> None:
        """Remove an asset (full id): its manifest, then the blobs no other manifest references.
        :class:`AssetError` for an unknown id or when another manifest is damaged (shared blobs
        could not be told apart)."""
        mpath = self.manifest_path(asset_id)
        with self._locked():
            if not mpath.exists():
                raise AssetError(f"no asset {asset_id}; `shadowless content list` shows them")
            try:
                mine = {b.sha256 for b in self._load(asset_id).blobs}
            except AssetError:
                mine = set()  # a damaged manifest: remove it, its blobs stay (unknown)
            others = self._referenced(exclude=asset_id)
            mpath.unlink()
            fsync_dir(mpath.parent)
            for sha in sorted(mine - others):
                p = self.blob_path(sha)
                p.unlink(missing_ok=True)
                try:
                    p.parent.rmdir()
                except OSError:
                    pass

    # ------------------------------------------------------------ reading
    def open_blob(self, sha256: str) -> BinaryIO:
        """A blob opened for binary reading (the caller closes it)."""
        path = self.blob_path(sha256)
        try:
            return open(path, "rb")
        except FileNotFoundError:
            raise AssetError(f"no blob {sha256}") from None

    def read_blob(self, sha256: str, offset: int, length: int) -> bytes:
        """Up to ``length`` bytes of a blob from ``offset`` (fewer at its end, none past it).
        ``ValueError`` for a negative offset or length or one over ``MAX_READ_BYTES``;
        :class:`AssetError` for an unknown blob."""
        if offset < 0 or length < 0 or length > MAX_READ_BYTES:
            raise ValueError(f"read_blob needs offset >= 0 and 0 <= length <= {MAX_READ_BYTES}, got {offset}, {length}")
        with self.open_blob(sha256) as f:
            parts, fd = [], f.fileno()
            while length > 0:
                chunk = os.pread(fd, length, offset)
                if not chunk:
                    break
                parts.append(chunk)
                offset += len(chunk)
                length -= len(chunk)
            return b"".join(parts)

    def verify(self, asset_id: str) -> list[str]:
        """Problems of an asset (id, prefix or name): damaged manifest, missing, resized or corrupt
        blobs (re-hashed in chunks). Empty when every byte is as the manifest says."""
        aid = self.resolve(asset_id)
        try:
            m = self._load(aid)
        except AssetError as exc:
            return [str(exc)]
        problems = []
        for i, b in enumerate(m.blobs):
            what = f"blob {i} {b.name!r} ({b.sha256[:12]})"
            path = self.blob_path(b.sha256)
            try:
                with open(path, "rb") as f:
                    sha, size = copy_hashing(f, None)
            except FileNotFoundError:
                problems.append(f"{what}: missing")
                continue
            except OSError as exc:
                problems.append(f"{what}: unreadable ({exc})")
                continue
            if size != b.size:
                problems.append(f"{what}: {size} bytes, the manifest says {b.size}")
            elif sha != b.sha256:
                problems.append(f"{what}: corrupt (its bytes hash to {sha[:12]})")
        return problems
