"""A corpus of damaged rig files: each is refused with one line naming the file and what is wrong,
with no traceback, exit status 2 from the CLI, and nothing stored changed.

The CLI runs in the test's interpreter (``shadowless.cli.main``, output captured at the file
descriptors); the first case of each kind (:data:`REAL_PROCESS`) also runs as a real `python -m
shadowless` process, which shows the exit status and stderr an operator's shell sees.

Set ``SHADOWLESS_CORPUS_TABLE=path`` to append the corpus as markdown rows (input | message | exit status).
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cli_inprocess import run_shadowless
from coordinator.assets import AssetStore
from coordinator.errors import RigError
from coordinator.rig import Content, HomographyPose, Rig, init_rig
from protos.auth import TokenError, read_token

ROOT = Path(__file__).resolve().parents[2]
TABLE_ENV = "SHADOWLESS_CORPUS_TABLE"


# ---- a good rig, and ways to damage it ----------------------------------------------------
@pytest.fixture(scope="module")
def good_rig(tmp_path_factory) -> Path:
    path = init_rig(tmp_path_factory.mktemp("good") / "rig", name="table", slots=["r0c0", "r0c1"], width=64, height=48,
                    content_width=32, content_height=16)
    rig = Rig(path)
    rig.update_slot("r0c0", pose=HomographyPose(np.eye(3)), gain=0.5,
                    lut=np.tile(np.linspace(0, 1, 8, dtype=np.float32), (3, 1)))
    rig.set_content(Content(np.zeros((16, 32, 3), np.uint8), name="black"))
    still = path.parent / "still.npy"
    np.save(still, np.full((16, 32, 3), 0.5, np.float32))
    AssetStore(path).add(still, name="grey")
    return path


def edit_text(rel: str, old: str, new: str):
    def apply(d: Path) -> None:
        f = d / rel
        text = f.read_text()
        assert old in text, (old, text)
        f.write_text(text.replace(old, new, 1))
    return apply


def edit_json(rel: str, change):
    def apply(d: Path) -> None:
        f = d / rel
        doc = json.loads(f.read_text())
        change(doc)
        f.write_text(json.dumps(doc))
    return apply


def write(rel: str, data: bytes):
    def apply(d: Path) -> None:
        (d / rel).write_bytes(data)
    return apply


def make_dir(rel: str):
    def apply(d: Path) -> None:
        f = d / rel
        f.unlink()
        f.mkdir()
        (f / "x").write_text("x")
    return apply


def remove(rel: str):
    def apply(d: Path) -> None:
        f = d / rel
        shutil.rmtree(f) if f.is_dir() else f.unlink()
    return apply


def save_npy(rel: str, array: np.ndarray):
    def apply(d: Path) -> None:
        np.save(d / rel, array, allow_pickle=False)
    return apply


def npy_declaring(shape: tuple[int, ...], dtype: str = "<f4") -> bytes:
    """A .npy of a few bytes whose header declares ``shape`` (numpy would allocate it all)."""
    import io

    from numpy.lib import format as npy_format

    buf = io.BytesIO()
    npy_format.write_array_header_1_0(buf, {"descr": dtype, "fortran_order": False, "shape": shape})
    return buf.getvalue() + bytes(64)


def truncate(rel: str, keep: float = 0.5):
    def apply(d: Path) -> None:
        f = d / rel
        data = f.read_bytes()
        f.write_bytes(data[: int(len(data) * keep)])
    return apply


def set_key(key, value):
    def change(doc):
        doc[key] = value
    return change


def set_pose(matrix):
    def change(doc):
        doc["pose"]["matrix"] = matrix
    return change


SLOT = "slots/r0c0.json"
LUT = "luts/r0c0.r1.npy"
META = "content/current.json"
TOML = "rig.toml"

#: (case id, damage, file the message names, substrings it must contain)
RIG_CASES = [
    ("toml-misspelled-latency", edit_text(TOML, "latency_ms =", "latancy_ms ="), TOML,
     ["unknown key 'latancy_ms'", "did you mean 'latency_ms'"]),
    ("toml-misspelled-content-width", edit_text(TOML, "content_width =", "content_widht ="), TOML,
     ["unknown key 'content_widht'", "did you mean 'content_width'"]),
    ("toml-misspelled-defaults-key", edit_text(TOML, "width = 64", "widht = 64"), TOML,
     ["unknown key 'widht' in [defaults]", "did you mean 'width'"]),
    ("toml-misspelled-slot-key", edit_text(TOML, "r0c0 = {}", "r0c0 = { heigth = 100 }"), TOML,
     ["unknown key 'heigth' in [slots.r0c0]", "did you mean 'height'"]),
    ("toml-unknown-table", edit_text(TOML, "[defaults]", "[defualts]"), TOML, ["unknown key 'defualts'", "'defaults'"]),
    ("toml-latency-nan", edit_text(TOML, "latency_ms = 50", "latency_ms = nan"), TOML, ["latency_ms", "nan"]),
    ("toml-latency-inf", edit_text(TOML, "latency_ms = 50", "latency_ms = inf"), TOML, ["latency_ms", "inf"]),
    ("toml-latency-negative", edit_text(TOML, "latency_ms = 50", "latency_ms = -5"), TOML, ["latency_ms", "-5"]),
    ("toml-latency-string", edit_text(TOML, "latency_ms = 50", 'latency_ms = "50"'), TOML, ["latency_ms", "'50'"]),
    ("toml-content-width-negative", edit_text(TOML, "content_width = 32", "content_width = -32"), TOML,
     ["content_width must be an integer in 16..16384", "-32"]),
    ("toml-content-width-float", edit_text(TOML, "content_width = 32", "content_width = 32.5"), TOML,
     ["content_width", "32.5"]),
    ("toml-slot-height-huge", edit_text(TOML, "r0c0 = {}", "r0c0 = { height = 99999 }"), TOML,
     ["slots.r0c0: height must be an integer in 16..16384", "99999"]),
    ("toml-heartbeat-bool", edit_text(TOML, "heartbeat_ms = 1000", "heartbeat_ms = true"), TOML, ["heartbeat_ms", "True"]),
    ("toml-lost-after-too-short", edit_text(TOML, "lost_after_ms = 5000", "lost_after_ms = 1500"), TOML,
     ["lost_after_ms at least twice"]),
    ("toml-name-empty", edit_text(TOML, 'name = "table"', 'name = ""'), TOML, ["`name` must be a non-empty string"]),
    ("toml-missing-id", edit_text(TOML, 'id = "', 'idx = "'), TOML, ["unknown key 'idx'", "did you mean 'id'"]),
    ("toml-bad-slot-name", edit_text(TOML, "r0c1 = {}", '"r0 c1" = {}'), TOML, ["slot name 'r0 c1'"]),
    ("toml-cameras-not-list", edit_text(TOML, "cameras = []", 'cameras = "opencv:0"'), TOML, ["cameras"]),
    ("toml-not-toml", edit_text(TOML, "[slots]", "[slots"), TOML, ["not valid TOML"]),
    ("toml-binary", write(TOML, b"\x89PNG\r\n\x1a\n\x00\x00\xff\xfe"), TOML, ["not a text file"]),
    ("toml-is-directory", make_dir(TOML), TOML, ["is a directory"]),
    ("toml-missing", remove(TOML), "", ["not a rig directory (no rig.toml)"]),
    ("slot-misspelled-gain", edit_json(SLOT, lambda d: d.update(gian=d.pop("gain"))), SLOT,
     ["unknown key 'gian'", "did you mean 'gain'"]),
    ("slot-misspelled-pose-key", edit_json(SLOT, lambda d: d["pose"].update(matirx=d["pose"].pop("matrix"))), SLOT,
     ["unknown key 'matirx' in [pose.homography]", "did you mean 'matrix'"]),
    ("slot-gain-nan", edit_json(SLOT, set_key("gain", float("nan"))), SLOT, ["gain must be a number in 0..16", "nan"]),
    ("slot-gain-negative", edit_json(SLOT, set_key("gain", -0.5)), SLOT, ["gain must be a number in 0..16", "-0.5"]),
    ("slot-gain-inf", edit_json(SLOT, set_key("gain", float("inf"))), SLOT, ["gain must be a number in 0..16", "inf"]),
    ("slot-revision-negative", edit_json(SLOT, set_key("revision", -1)), SLOT, ["revision must be an integer >= 0"]),
    ("slot-width-string", edit_json(SLOT, set_key("width", "64")), SLOT, ["width must be an integer in 16..16384"]),
    ("slot-homography-shape", edit_json(SLOT, set_pose([[1, 0], [0, 1]])), SLOT, ["homography must be a (3, 3)"]),
    ("slot-homography-nan", edit_json(SLOT, set_pose([[1, 0, 0], [0, float("nan"), 0], [0, 0, 1]])), SLOT,
     ["homography must be finite"]),
    ("slot-homography-singular", edit_json(SLOT, set_pose([[1, 2, 3], [2, 4, 6], [0, 0, 1]])), SLOT,
     ["singular"]),
    ("slot-pose-kind", edit_json(SLOT, lambda d: d["pose"].update(kind="affine")), SLOT, ["`kind` must be"]),
    ("slot-lut-outside-rig", edit_json(SLOT, set_key("lut", "../../etc/passwd")), SLOT, ["lut must be a path inside"]),
    ("slot-truncated-json", truncate(SLOT), SLOT, ["not valid JSON", "line"]),
    ("slot-empty", write(SLOT, b""), SLOT, ["empty"]),
    ("slot-binary", write(SLOT, b"\xff\xfe\x00garbage"), SLOT, ["not a text file"]),
    ("slot-is-directory", make_dir(SLOT), SLOT, ["is a directory"]),
    ("slot-json-array", write(SLOT, b"[1, 2]"), SLOT, ["must hold a JSON object"]),
    ("lut-float64", save_npy(LUT, np.tile(np.linspace(0, 1, 8), (3, 1))), LUT, ["LUT", "must be float32, got float64"]),
    ("lut-wrong-shape", save_npy(LUT, np.full((2, 8), 0.5, np.float32)), LUT, ["(C, E)", "(2, 8)"]),
    ("lut-out-of-range", save_npy(LUT, np.full((3, 8), 1.5, np.float32)), LUT, ["within [0, 1]"]),
    ("lut-truncated", truncate(LUT, 0.6), LUT, ["not a readable .npy"]),
    ("lut-missing", remove(LUT), LUT, ["missing"]),
    ("lut-declares-112-gib", write(LUT, npy_declaring((3, 10**10))), LUT,
     ["its header declares an array of shape (3, 10000000000) float32", "the file holds 64"]),
    ("luts-folder-missing", remove("luts"), LUT, ["missing"]),
    ("content-meta-truncated", truncate(META), META, ["not valid JSON"]),
    ("content-meta-misspelled", edit_json(META, lambda d: d.update(flie=d.pop("file"))), META,
     ["unknown key 'flie'", "did you mean 'file'"]),
    ("content-meta-bad-file", edit_json(META, set_key("file", "../rig.toml")), META, ["file must be a plain file name"]),
    ("content-meta-nan-time", edit_json(META, set_key("updated_at", float("nan"))), META, ["updated_at", "nan"]),
    ("content-image-float64", lambda d: np.save(d / "content" / json.loads((d / META).read_text())["file"],
                                                np.zeros((16, 32, 3))), "content/", ["must be uint8 or uint16 or float32, got float64"]),
    ("content-image-declares-112-gib", lambda d: (d / "content" / json.loads((d / META).read_text())["file"]).write_bytes(
        npy_declaring((100000, 100000, 3))), "content/", ["its header declares an array of shape (100000, 100000, 3)"]),
    ("content-folder-missing", remove("content"), "", None),   # no content: a valid rig (shows nothing)
]


def checksums(root: Path) -> dict[str, str]:
    """Every entry under ``root``: sha256 for files, "dir" for folders."""
    out = {}
    for p in sorted(root.rglob("*")):
        out[str(p.relative_to(root))] = "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
    return out


#: cases whose CLI check also runs as a real process (one per kind of file: rig, manifest, token)
REAL_PROCESS = {"toml-misspelled-latency", "manifest-truncated", "token-world-readable", "nope"}


def run_cli(capfd, case: str, *args: str) -> subprocess.CompletedProcess:
    """`shadowless ARGS...` in this interpreter; for the cases of :data:`REAL_PROCESS`, also in a real
    process, whose result must be the in-process one (the real process's is returned)."""
    code, out, err = run_shadowless(list(args), capfd)
    here = subprocess.CompletedProcess(["shadowless", *args], code, out, err)
    if case not in REAL_PROCESS:
        return here
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, "-m", "shadowless", *args], capture_output=True, text=True, timeout=60,
                          cwd=ROOT, env=env)
    stamp = re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3} ", re.M)   # a log line's time
    assert (proc.returncode, proc.stdout, stamp.sub("", proc.stderr)) == (code, out, stamp.sub("", err)), (proc, here)
    return proc


def record(case: str, message: str, status: object) -> None:
    table = os.environ.get(TABLE_ENV)
    if table:
        with open(table, "a") as f:
            if f.tell() == 0:
                f.write("| input | message | exit status |\n|---|---|---|\n")
            f.write(f"| {case} | {message.replace('|', '/')} | {status} |\n")


def assert_one_line(message: str, names: str, says: list[str]) -> None:
    assert "\n" not in message.strip() and "Traceback" not in message, message
    assert names in message, (names, message)
    for s in says:
        assert s in message, (s, message)


@pytest.mark.parametrize("case,damage,names,says", RIG_CASES, ids=[c[0] for c in RIG_CASES])
def test_damaged_rig_file_is_refused_in_one_line(tmp_path, good_rig, capfd, case, damage, names, says):
    rig_dir = tmp_path / "rig"
    shutil.copytree(good_rig, rig_dir)
    damage(rig_dir)
    before = checksums(rig_dir)
    if says is None:                       # the control: still loads
        Rig(rig_dir)
        assert run_cli(capfd, case, "rig", "show", str(rig_dir)).returncode == 0
        return
    with pytest.raises(RigError) as exc:
        Rig(rig_dir)
    assert_one_line(str(exc.value), names, says)
    assert checksums(rig_dir) == before
    # the public CLI in a real process: exit 2, one line on stderr, no traceback, nothing changed
    proc = run_cli(capfd, case, "rig", "show", str(rig_dir))
    assert proc.returncode == 2, proc
    assert proc.stdout == ""
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert_one_line(proc.stderr, names, says)
    assert checksums(rig_dir) == before
    record(f"{case} (`rig show`)", proc.stderr.strip().replace(str(rig_dir), "RIG"), proc.returncode)


# ---- asset manifests (content metadata in assets/manifests/<id>.json) ------------------------
def manifest(d: Path) -> Path:
    return next((d / "assets" / "manifests").glob("*.json"))


MANIFEST_CASES = [
    ("manifest-truncated", lambda d: truncate(str(manifest(d).relative_to(d)))(d), ["its manifest is damaged"]),
    ("manifest-edited", lambda d: edit_text(str(manifest(d).relative_to(d)), '"grey"', '"gray"')(d),
     ["its manifest is damaged", "do not hash"]),
    ("manifest-binary", lambda d: manifest(d).write_bytes(b"\x00\xff" * 10), ["its manifest is damaged"]),
    ("manifest-directory", lambda d: make_dir(str(manifest(d).relative_to(d)))(d), ["cannot read", "Is a directory"]),
]


@pytest.mark.parametrize("case,damage,says", MANIFEST_CASES, ids=[c[0] for c in MANIFEST_CASES])
def test_damaged_asset_manifest_is_refused_in_one_line(tmp_path, good_rig, capfd, case, damage, says):
    rig_dir = tmp_path / "rig"
    shutil.copytree(good_rig, rig_dir)
    name = manifest(rig_dir).name
    damage(rig_dir)
    before = checksums(rig_dir)
    # `content list` skips a damaged manifest with one warning line and lists the rest (exit 0, by design)
    proc = run_cli(capfd, case, "content", "list", "--rig-dir", str(rig_dir))
    assert proc.returncode == 0 and "grey" not in proc.stdout, proc
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert_one_line(proc.stderr, name, says)
    assert checksums(rig_dir) == before
    record(f"{case} (`content list`)", proc.stderr.strip().replace(str(rig_dir), "RIG"), proc.returncode)


# ---- token files --------------------------------------------------------------------------
TOKEN_CASES = [
    ("token-world-readable", "A" * 43 + "\n", 0o644, ["can be read by", "chmod 600"]),
    ("token-group-readable", "A" * 43 + "\n", 0o640, ["its group", "chmod 600"]),
    ("token-empty", "", 0o600, ["is empty"]),
    ("token-whitespace-only", "  \n\n", 0o600, ["is empty"]),
    ("token-binary", b"\xff\xd8\xff\xe0\x00\x10JFIF", 0o600, ["is not text"]),
    ("token-nul-bytes", b"A" * 20 + b"\x00" * 20, 0o600, ["is not a token"]),
    ("token-short", "abc123\n", 0o600, ["shorter than 16 bytes"]),
    ("token-directory", None, 0o700, ["is a directory"]),
    ("token-missing", "missing", 0o600, ["does not exist"]),
]


def make_token(path: Path, content, mode: int) -> None:
    if content == "missing":
        return
    if content is None:
        path.mkdir()
    else:
        path.write_bytes(content.encode() if isinstance(content, str) else content)
    path.chmod(mode)


@pytest.mark.parametrize("case,content,mode,says", TOKEN_CASES, ids=[c[0] for c in TOKEN_CASES])
def test_bad_token_file_is_refused_in_one_line(tmp_path, good_rig, capfd, case, content, mode, says):
    rig_dir = tmp_path / "rig"
    shutil.copytree(good_rig, rig_dir)
    token = rig_dir / "token"
    token.unlink()
    make_token(token, content, mode)
    with pytest.raises(TokenError) as exc:
        read_token(token)
    assert_one_line(str(exc.value), str(token), says)
    before = checksums(rig_dir)
    proc = run_cli(capfd, case, "coordinator", "--rig", str(rig_dir), "--no-mdns", "--listen", "127.0.0.1:0",
                   "--port-file", str(tmp_path / "port"))
    assert proc.returncode == 2, proc
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert_one_line(lines[0], str(token), says)
    assert checksums(rig_dir) == before and not (tmp_path / "port").exists()
    record(f"{case} (`coordinator`)", lines[0].split(" coordinator: ", 1)[-1].replace(str(rig_dir), "RIG"),
           proc.returncode)


# ---- refusals change nothing stored -------------------------------------------------------
def test_refused_slot_updates_leave_every_file_byte_identical(tmp_path, good_rig):
    rig_dir = tmp_path / "rig"
    shutil.copytree(good_rig, rig_dir)
    rig = Rig(rig_dir)
    before = checksums(rig_dir)
    for bad in (dict(gain=float("nan")), dict(gain=-1.0), dict(gain=17.0),
                dict(lut=np.full((2, 8), 0.5, np.float32)), dict(lut=np.full((3, 8), np.inf, np.float32)),
                dict(size=(8, 8)), dict(size=(64, 10 ** 6))):
        with pytest.raises((ValueError, RigError)):
            rig.update_slot("r0c0", **bad)
    with pytest.raises(ValueError):
        HomographyPose(np.zeros((3, 3)))
    assert checksums(rig_dir) == before
    assert rig.slot("r0c0").revision == 1 and Rig(rig_dir).slot("r0c0").gain == 0.5


def test_missing_and_file_rig_dirs_are_one_line(tmp_path, capfd):
    for path, says in ((tmp_path / "nope", "no such directory"), (tmp_path / "file", "not a directory")):
        if path.name == "file":
            path.write_text("x")
        with pytest.raises(RigError, match=says):
            Rig(path)
        proc = run_cli(capfd, path.name, "rig", "show", str(path))
        assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1 and says in proc.stderr
        record(f"rig dir {path.name} (`rig show`)", proc.stderr.strip().replace(str(tmp_path), "TMP"), proc.returncode)


def test_leftover_temp_files_are_removed_when_the_rig_opens(tmp_path, good_rig, caplog):
    rig_dir = tmp_path / "rig"
    shutil.copytree(good_rig, rig_dir)
    old = 1_000_000_000
    leftovers = [rig_dir / ".rig.toml.abc123.tmp", rig_dir / "slots" / ".r0c0.json.x1y2z3.tmp",
                 rig_dir / "luts" / ".r0c0.r2.npy.q9w8e7.tmp"]
    for i, f in enumerate(leftovers):
        f.write_bytes(b"x" * (10 + i))
        os.utime(f, (old, old))
    fresh = rig_dir / "slots" / ".r0c1.json.fresh1.tmp"   # a live writer's: kept
    fresh.write_bytes(b"y")
    keep = [rig_dir / "notes.tmp", rig_dir / ".hidden"]     # not the temp pattern: kept
    for f in keep:
        f.write_bytes(b"z")
        os.utime(f, (old, old))
    outside = tmp_path / ".outside.json.aaaaaa.tmp"          # outside the rig: kept
    outside.write_bytes(b"o")
    os.utime(outside, (old, old))
    caplog.set_level("INFO", logger="protos.atomic_files")
    Rig(rig_dir)
    assert not any(f.exists() for f in leftovers)
    assert fresh.exists() and outside.exists() and all(f.exists() for f in keep)
    msgs = [r.getMessage() for r in caplog.records if "temp file" in r.getMessage()]
    assert len(msgs) == 1 and "removed 3 temp file(s) (33 bytes)" in msgs[0], msgs


def test_a_refused_rig_keeps_its_temp_files(tmp_path, good_rig):
    rig_dir = tmp_path / "rig"
    shutil.copytree(good_rig, rig_dir)
    edit_text(TOML, "latency_ms =", "latancy_ms =")(rig_dir)
    leftover = rig_dir / ".rig.toml.abc123.tmp"
    leftover.write_bytes(b"x")
    os.utime(leftover, (1_000_000_000, 1_000_000_000))
    with pytest.raises(RigError):
        Rig(rig_dir)
    assert leftover.exists()


def test_corpus_is_large_enough():
    assert len(RIG_CASES) + len(TOKEN_CASES) + len(MANIFEST_CASES) >= 30
