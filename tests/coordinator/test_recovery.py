"""Start-up recovery (coordinator/recovery.py): generated partial states of every write path, the
pass never raises, leaves a rig that loads, keeps what was acknowledged, and leaves nothing behind."""
from __future__ import annotations

import fcntl
import hashlib
import json
import logging
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.configuration import set_hypothesis_home_dir

from coordinator.assets import STAGING_LOCK, AssetStore
from coordinator.compensation.store import save_measured_transport, stored_transport_meta
from coordinator.coverage import Coverage
from coordinator.coverage_store import save_coverage, summary_behind
from coordinator.distribution import Distribution
from coordinator.recovery import QUARANTINE, recover
from protos.store import is_temp_name
from coordinator.rig import Content, HomographyPose, Rig, init_rig
from coordinator.uploads import UploadFile, Uploads, upload_id

SLOTS = ["r0c0", "r0c1"]

# Hypothesis keeps its caches in the session's temporary folder (made at collection), not in the checkout
_HOME = Path(tempfile.gettempdir()) / "hypothesis"
_HOME.mkdir(exist_ok=True)
set_hypothesis_home_dir(_HOME)


def _lut(level: float) -> np.ndarray:
    return np.tile(np.linspace(0, level, 8, dtype=np.float32), (3, 1))


@pytest.fixture(scope="module")
def base_rig(tmp_path_factory) -> Path:
    """A rig with poses, LUTs, content, two assets, a finished calibration run and a show file."""
    path = init_rig(tmp_path_factory.mktemp("base") / "rig", name="table", slots=SLOTS, width=64, height=48,
                    content_width=32, content_height=16)
    rig = Rig(path)
    for s in SLOTS:
        rig.update_slot(s, pose=HomographyPose(np.eye(3)), lut=_lut(1.0))
    rig.set_content(Content(np.zeros((16, 32, 3), np.uint8), name="black"))
    store = AssetStore(path)
    for i, name in enumerate(("grey", "white")):
        still = path.parent / f"{name}.npy"
        np.save(still, np.full((16, 32, 3), 0.5 + 0.5 * i, np.float32))
        store.add(still, name=name)
    (path / "calibration").mkdir()
    (path / "calibration" / "run.json").write_text(json.dumps({"run": "x", "status": "complete"}))
    (path / "show.json").write_text(json.dumps({"version": 1, "revision": 0, "timeline": None}))
    # the pairs written one after the other: the light transport (npz, json, black) and the coverage
    L = sp.csr_matrix(np.eye(4, 6, dtype=np.float32))
    save_measured_transport(rig, L, {"black_file": "black-aaaa.npy", "fingerprint": "aaaa", "radius": 3},
                            np.zeros((2, 2, 3), np.float32))
    h, w = 4, 5
    cov = Coverage(("r0c0", "r0c1"), np.ones((h, w), bool), np.ones((h, w), np.float32),
                   np.zeros((h, w, 3), np.float32), np.zeros((h, w, 3), np.float32), np.ones((2, h, w), bool),
                   np.ones((2, h, w), np.float32))
    save_coverage(path, cov, {"texels": h * w, "mean": 1.5, "mesh": "m"})
    return path


def _spec(files: list[UploadFile]) -> bytes:
    return json.dumps({"files": [{"name": f.name, "size": f.size, "sha256": f.sha256} for f in files]}).encode()


def _upload(rig: Path, data: bytes, name: str = "clip.mp4") -> tuple[Path, list[UploadFile]]:
    files = [UploadFile(name, len(data), hashlib.sha256(data).hexdigest())]
    d = rig / "assets" / "uploads" / upload_id(files)
    (d / "files").mkdir(parents=True, exist_ok=True)
    (d / "spec.json").write_bytes(_spec(files))
    return d, files


# ---- the partial states a crash (or a damaged disk) can leave, one function each ----------------
def empty_upload(rig: Path, draw) -> None:           # begin_upload, then no byte (issue 35)
    _upload(rig, draw(st.binary(min_size=1, max_size=64)))


def partial_upload(rig: Path, draw) -> None:          # cut mid-file: resumable, kept
    data = draw(st.binary(min_size=2, max_size=64))
    d, files = _upload(rig, data)
    (d / "files" / files[0].name).write_bytes(data[:draw(st.integers(1, len(data) - 1))])


def upload_without_spec(rig: Path, draw) -> None:     # killed between mkdir and the spec's rename
    (rig / "assets" / "uploads" / hashlib.sha256(draw(st.binary(max_size=8))).hexdigest() / "files").mkdir(parents=True, exist_ok=True)


def truncated_spec(rig: Path, draw) -> None:
    d, _ = _upload(rig, draw(st.binary(min_size=1, max_size=64)))
    text = (d / "spec.json").read_bytes()
    (d / "spec.json").write_bytes(text[:draw(st.integers(0, len(text) - 1))])


def spec_of_another_id(rig: Path, draw) -> None:
    d, _ = _upload(rig, draw(st.binary(min_size=1, max_size=64)))
    (d / "spec.json").write_bytes(_spec([UploadFile("other.png", 3, "0" * 64)]))


def file_bigger_than_announced(rig: Path, draw) -> None:
    data = draw(st.binary(min_size=1, max_size=64))
    d, files = _upload(rig, data)
    (d / "files" / files[0].name).write_bytes(data + draw(st.binary(min_size=1, max_size=16)))


def unannounced_file(rig: Path, draw) -> None:
    d, _ = _upload(rig, draw(st.binary(min_size=1, max_size=64)))
    (d / "files" / draw(st.sampled_from(["x.png", "notes.txt", "clip.mp4.part"]))).write_bytes(b"?")


def files_is_a_file(rig: Path, draw) -> None:
    d, _ = _upload(rig, draw(st.binary(min_size=1, max_size=64)))
    (d / "files").rmdir()
    (d / "files").write_bytes(b"not a folder")


def stray_upload_entry(rig: Path, draw) -> None:
    up = rig / "assets" / "uploads"
    up.mkdir(parents=True, exist_ok=True)
    (up / draw(st.sampled_from(["notes.txt", "partial", "ABC"]))).write_bytes(b"?")


def temp_file(rig: Path, draw) -> None:               # an atomic write killed before its rename
    folder = draw(st.sampled_from(["", "slots", "luts", "content", "calibration", "assets/manifests",
                                   "assets/blobs", "compensation", "coverage"]))
    target = draw(st.sampled_from(["r0c0.json", "current.json", "show.json", "run.json", "x.npy"]))
    suffix = draw(st.text("abcdefghijklmnopqrstuvwxyz0123456789_", min_size=8, max_size=8))
    (rig / folder).mkdir(parents=True, exist_ok=True)
    (rig / folder / f".{target}.{suffix}.tmp").write_bytes(draw(st.binary(max_size=64)))


def temp_in_upload(rig: Path, draw) -> None:          # the spec's own temp file
    d, _ = _upload(rig, draw(st.binary(min_size=1, max_size=64)))
    (d / ".spec.json.abcd1234.tmp").write_bytes(b'{"fil')


def staged_add(rig: Path, draw) -> None:              # an add killed while staging
    tmp = rig / "assets" / "tmp"
    tmp.mkdir(parents=True, exist_ok=True)
    uid = hashlib.md5(draw(st.binary(max_size=8))).hexdigest()
    name = draw(st.sampled_from([f"{uid}.blob", f".{uid}.blob.k2j3h4g5.tmp"]))
    (tmp / name).write_bytes(draw(st.binary(max_size=64)))


def orphan_blob(rig: Path, draw) -> None:             # an add killed between its blobs and its manifest
    data = draw(st.binary(min_size=1, max_size=64))
    sha = hashlib.sha256(data).hexdigest()
    p = rig / "assets" / "blobs" / sha[:2] / sha
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_bytes(data)


def damaged_manifest(rig: Path, draw) -> None:        # a half-made asset (a disk, not a crash, does this)
    manifests = sorted((rig / "assets" / "manifests").glob("*.json"))
    if not manifests:
        return
    m = draw(st.sampled_from(manifests))
    text = m.read_bytes()
    os.chmod(m, 0o644)
    m.write_bytes(text[:draw(st.integers(0, max(0, len(text) - 1)))])


def missing_blob(rig: Path, draw) -> None:
    blobs = sorted(p for p in (rig / "assets" / "blobs").rglob("*") if p.is_file())
    if blobs:
        draw(st.sampled_from(blobs)).unlink()


def old_lut(rig: Path, draw) -> None:                 # a LUT write cut before the older one was removed
    s = draw(st.sampled_from(SLOTS))
    np.save(rig / "luts" / f"{s}.r{draw(st.integers(0, 0))}.npy", _lut(0.5))


def orphan_content(rig: Path, draw) -> None:
    np.save(rig / "content" / f"{draw(st.sampled_from(['a' * 24, 'b' * 24]))}.npy", np.ones((2, 2), np.uint8))


def running_calibration(rig: Path, draw) -> None:
    (rig / "calibration" / "run.json").write_text(json.dumps({"run": "y", "status": "running", "fingerprint": "f"}))


def truncated_show(rig: Path, draw) -> None:
    f = rig / "show.json"
    text = f.read_bytes()
    f.write_bytes(text[:draw(st.integers(0, max(0, len(text) - 1)))])


def orphan_black(rig: Path, draw) -> None:
    d = rig / "compensation"
    d.mkdir(exist_ok=True)
    np.save(d / "black-0123456789abcdef.npy", np.zeros((2, 2, 3), np.float32))


def transport_json_behind(rig: Path, draw) -> None:   # a new L saved, killed before its transport.json
    d = rig / "compensation"
    np.save(d / "black-bbbb.npy", np.zeros((2, 2, 3), np.float32))
    if draw(st.booleans()):
        (d / "transport.json").write_text(json.dumps({"black_file": "black-bbbb.npy", "fingerprint": "bbbb"}))
    else:
        (d / "transport.json").unlink()


def coverage_json_behind(rig: Path, draw) -> None:    # a new coverage.npz, killed before its coverage.json
    f = rig / "coverage" / "coverage.json"
    if draw(st.booleans()):
        f.write_text(json.dumps({"texels": 1, "mean": 0.5}))
    else:
        f.unlink()


CRASH_STATES = [empty_upload, partial_upload, upload_without_spec, truncated_spec, spec_of_another_id,
                file_bigger_than_announced, unannounced_file, files_is_a_file, temp_file,
                temp_in_upload, staged_add, orphan_blob, old_lut, orphan_content, running_calibration,
                orphan_black, transport_json_behind, coverage_json_behind]
DAMAGE = [damaged_manifest, missing_blob, truncated_show, stray_upload_entry]


def _files(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*") if p.is_file() or p.is_symlink()}


def check_settled(rig: Path) -> None:
    """What every start after recovery must find: a rig that loads, nothing left over."""
    Rig(rig)                                                   # loads (and would refuse in one line)
    store = AssetStore(rig)
    for aid, _ in store.list():
        assert store.verify(aid) == [], aid
    Distribution(store).load()
    uploads = Uploads(store)
    uploads.sweep()
    for d in (rig / "assets" / "uploads").glob("*"):
        have = uploads.have(d.name)                            # every upload left resumes
        assert all(h >= 0 for h in have)
    left = [f for f in _files(rig) if not f.startswith(QUARANTINE + "/")]
    assert not [f for f in left if is_temp_name(Path(f).name)], left
    assert not [f for f in left if f.startswith("assets/tmp/")], left
    named = {b.sha256 for _, m in store.list() for b in m.blobs}
    assert {Path(f).name for f in left if f.startswith("assets/blobs/")} <= named
    luts = {f for f in left if f.startswith("luts/")}
    assert luts == {f"luts/{s}.r{Rig(rig).slot(s).revision}.npy" for s in SLOTS}, luts
    assert len([f for f in left if f.startswith("content/") and f.endswith(".npy")]) == 1
    meta = stored_transport_meta(rig / "compensation")
    assert meta is not None and json.loads((rig / "compensation" / "transport.json").read_text()) == meta
    assert {f for f in left if f.startswith("compensation/black-")} == {f"compensation/{meta['black_file']}"}
    assert summary_behind(rig) is None
    assert json.loads((rig / "calibration" / "run.json").read_text())["status"] != "running"


@settings(max_examples=60, deadline=None, database=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_recovery_settles_every_generated_crash_state(base_rig, tmp_path, data):
    rig = tmp_path / "rig"
    shutil.rmtree(rig, ignore_errors=True)
    shutil.copytree(base_rig, rig, symlinks=True)
    try:
        kinds = data.draw(st.lists(st.sampled_from(CRASH_STATES + DAMAGE), min_size=1, max_size=6, unique=True), label="states")
        for kind in kinds:
            try:
                kind(rig, data.draw)
            except OSError:          # two generated states collided on one path: the first one stands
                pass
        before = {aid for aid, _ in AssetStore(rig).list()}
        result = recover(rig)
        assert result.errors == []
        check_settled(rig)
        # acknowledged assets stay unless their own files were damaged
        if not {damaged_manifest, missing_blob} & set(kinds):
            assert {aid for aid, _ in AssetStore(rig).list()} == before
        if set(kinds) <= set(CRASH_STATES):           # a crash alone never needs the quarantine
            assert not (rig / QUARANTINE).exists(), result.actions
        again = recover(rig)                           # settled: a second start does nothing
        assert again.actions == [] and again.errors == []
    finally:
        shutil.rmtree(rig, ignore_errors=True)


def test_every_action_is_one_log_line_and_partial_uploads_resume(base_rig, tmp_path, caplog):
    rig = tmp_path / "rig"
    shutil.copytree(base_rig, rig, symlinks=True)
    data = b"0123456789" * 10
    d, files = _upload(rig, data)
    (d / "files" / files[0].name).write_bytes(data[:40])
    empty, _ = _upload(rig, b"other bytes")
    (rig / "assets" / "uploads" / ("a" * 64) / "files").mkdir(parents=True)   # no spec
    (rig / "slots" / ".r0c0.json.x1y2z3w4.tmp").write_bytes(b"{")
    with caplog.at_level(logging.INFO, logger="coordinator.recovery"):
        result = recover(rig)
    lines = [r.getMessage() for r in caplog.records if r.name == "coordinator.recovery"]
    assert len(lines) == len(result.actions) == 2, lines
    assert all("\n" not in line for line in lines)
    assert any("rolled back assets/uploads/" + "a" * 64 in line and "spec.json" in line for line in lines), lines
    assert any("removed slots/.r0c0.json.x1y2z3w4.tmp" in line for line in lines), lines
    uploads = Uploads(AssetStore(rig))
    assert uploads.have(d.name) == [40] and uploads.have(empty.name) == [0]


def test_a_temp_file_a_running_writer_holds_open_stays(base_rig, tmp_path):
    rig = tmp_path / "rig"
    shutil.copytree(base_rig, rig, symlinks=True)
    held = rig / "coverage" / ".coverage.npz.abcdefgh.tmp"
    with open(held, "wb") as f:
        f.write(b"being written")
        recover(rig)
        assert held.exists()
    recover(rig)
    assert not held.exists()


def test_assets_being_staged_by_another_add_stay(base_rig, tmp_path):
    rig = tmp_path / "rig"
    shutil.copytree(base_rig, rig, symlinks=True)
    staged = rig / "assets" / "tmp" / "0123.blob"
    staged.parent.mkdir(exist_ok=True)
    staged.write_bytes(b"staged")
    with open(rig / "assets" / STAGING_LOCK, "a+b") as lock:
        fcntl.flock(lock.fileno(), fcntl.LOCK_SH)     # what AssetStore.add holds while it stages
        recover(rig)
        assert staged.exists()
    recover(rig)
    assert not staged.exists()


def test_the_upload_sweep_takes_an_upload_without_bytes(base_rig, tmp_path):
    rig = tmp_path / "rig"
    shutil.copytree(base_rig, rig, symlinks=True)
    d, _ = _upload(rig, b"never sent")                # the start that crashed in issue 35
    uploads = Uploads(AssetStore(rig))
    assert uploads.sweep() == []
    os.utime(d, (1.0, 1.0))
    assert uploads.sweep() == [d.name]


def test_what_cannot_be_read_is_quarantined_inside_the_rig_with_one_warning_each(base_rig, tmp_path, caplog):
    rig = tmp_path / "rig"
    shutil.copytree(base_rig, rig, symlinks=True)
    manifest = sorted((rig / "assets" / "manifests").glob("*.json"))[0]
    os.chmod(manifest, 0o644)
    manifest.write_bytes(manifest.read_bytes()[:20])          # half a manifest
    (rig / "show.json").write_text('{"version": 1, "rev')
    with caplog.at_level(logging.INFO, logger="coordinator.recovery"):
        result = recover(rig)
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert [a.verb for a in result.actions].count("quarantined") == len(warned) >= 3, warned   # + its blob
    assert any(manifest.name in w and "moved to quarantine/" in w for w in warned), warned
    assert any("show.json" in w for w in warned), warned
    kept = {p.name for p in (rig / QUARANTINE).rglob("*") if p.is_file()}
    assert {manifest.name, "show.json"} <= kept
    assert not manifest.exists() and not (rig / "show.json").exists()
    check_settled(rig)
    assert len(AssetStore(rig).list()) == 1
