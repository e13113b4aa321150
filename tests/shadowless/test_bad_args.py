"""Every CLI mistake costs one line naming what is wrong, exit status 2, and no traceback; a rig
directory named in the mistake is left exactly as it was (checksums before and after).

Each case runs `shadowless` in this process (``shadowless.cli.main``), its output captured at the
file descriptors, so a line a C library writes to stderr (OpenCV's log) counts as much as Python's;
none of them reaches a coordinator: each mistake is caught before anything is sent (the token, the
files and the arguments are checked first). A few cases (:data:`REAL_PROCESS`: the parser's refusal,
a command's own refusal, a decoder's) also run as real `python -m shadowless` processes, which proves
what an operator's shell sees: the exit status, and stderr as the interpreter leaves it. Each row
goes to the closing note's table (SHADOWLESS_CORPUS_TABLE).
"""
from __future__ import annotations

import hashlib
import io
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from numpy.lib import format as npy_format

import bench.image_headers as HEADERS
from cli_inprocess import run_shadowless
from coordinator.rig import init_rig
from protos import auth

NOWHERE = "127.0.0.1:1"          # a port nothing listens on: a case that got this far would fail differently
REMOTE = ["--coordinator", NOWHERE, "--token-file", "{ok}"]

# (name, argv with {rig} {dir} {ok} {loose} {pickle} {f64img} placeholders, what the one line must say)
CASES = [
    ("unknown command", ["projectt"], "invalid choice: 'projectt'"),
    ("unknown option", ["status", "--bogus"], "shadowless status: unrecognized arguments: --bogus"),
    ("local: no nodes", ["local", "--nodes", "0"], "--nodes: '0' is not a whole number 1..256"),
    ("local: size without height", ["local", "--size", "160"], "--size: '160' is not a size WxH"),
    ("local: zero frame rate", ["local", "--fps", "0"], "--fps: '0' is not a number above 0"),
    ("rig init: grid typo", ["rig", "init", "{dir}/new", "--grid", "5y5"], "'5y5' is not a grid COLSxROWS"),
    ("rig init: zero height", ["rig", "init", "{dir}/new", "--resolution", "1920x0"], "each side must be 1..16384"),
    ("rig init: negative latency", ["rig", "init", "{dir}/new", "--latency-ms", "-5"], "--latency-ms: '-5' is not a number"),
    ("rig init: empty slot list", ["rig", "init", "{dir}/new", "--slots", " , "], "a list of names"),
    ("rig init: onto a rig", ["rig", "init", "{rig}"], "already holds a rig"),
    ("rig init: onto a file", ["rig", "init", "{ok}"], "is a file; give a folder"),
    ("rig show: missing", ["rig", "show", "{dir}/none"], "is not a rig directory"),
    ("node: no slot", ["node"], "the following arguments are required: --slot"),
    ("node: zero cache", ["node", "--slot", "r0c0", "--cache-max", "0"], "--cache-max: '0' is not a size"),
    ("node: rate in words", ["node", "--slot", "r0c0", "--fetch-rate", "fast"], "--fetch-rate: 'fast' is not a size"),
    ("node: missing token file", ["node", "--slot", "r0c0", "--token-file", "{dir}/missing"], "does not exist"),
    ("node: unknown output", ["node", "--slot", "r0c0", "--output", "hdmi", "--token-file", "{ok}"], "unknown output 'hdmi'; accepted"),
    ("play: negative fps", ["play", "--pattern", "counter", "--fps", "-1"], "--fps: '-1' is not a number above 0"),
    ("play: no frames", ["play", "--pattern", "counter", "--frames", "0"], "--frames: '0' is not a whole number"),
    ("play: negative loops", ["play", "--pattern", "counter", "--loops", "-1"], "--loops: '-1' is not a whole number"),
    ("play: missing folder", ["play", "{dir}/nothing-here", "--coordinator", NOWHERE, "--token-file", "{ok}"],
     "no such folder"),
    ("play: a pickle among the frames", ["play", "{dir}/frames", "--coordinator", NOWHERE, "--token-file", "{ok}"],
     "pickle"),
    ("show: unknown fit", ["show", "x.png", "--fit", "squash"], "--fit: invalid choice: 'squash'"),
    ("show: missing image", ["show", "{dir}/missing.png", "--coordinator", NOWHERE, "--token-file", "{ok}"],
     "no such file"),
    ("show: a pickled .npy", ["show", "{pickle}", "--coordinator", NOWHERE, "--token-file", "{ok}"], "pickle"),
    ("show: seek without frame", ["show", "seek", "--coordinator", NOWHERE, "--token-file", "{ok}"], "seek needs the frame"),
    ("configure: NaN gain", ["configure", "--slot", "r0c0", "--gain", "nan"], "--gain: 'nan' is not a number from 0 to 16"),
    ("configure: negative gain", ["configure", "--slot", "r0c0", "--gain", "-1"], "--gain: '-1' is not a number from 0 to 16"),
    ("configure: 3x4 pose without a mesh", ["configure", "--slot", "r0c0", "--projection", ",".join(["1"] * 12),
                                            "--coordinator", NOWHERE, "--token-file", "{ok}"], "needs its mesh"),
    ("configure: both poses", ["configure", "--slot", "r0c0", "--homography", "1", "--projection", "1"],
     "not allowed with argument"),
    ("configure: resolution with *", ["configure", "--slot", "r0c0", "--resolution", "1920*1080"],
     "'1920*1080' is not a size WxH"),
    ("configure: missing LUT", ["configure", "--slot", "r0c0", "--lut", "{dir}/missing.npy"], "no such file"),
    ("configure: 3 numbers for a homography", ["configure", "--slot", "r0c0", "--homography", "1,2,3",
                                               "--coordinator", NOWHERE, "--token-file", "{ok}"], "needs 9 numbers"),
    ("configure: a pickled homography", ["configure", "--slot", "r0c0", "--homography", "{pickle}",
                                         "--coordinator", NOWHERE, "--token-file", "{ok}"], "not a readable .npy homography"),
    ("status: readable token", ["status", "--coordinator", NOWHERE, "--token-file", "{loose}"], "chmod 600"),
    ("status: missing rig dir", ["status", "--rig-dir", "{dir}/none", "--coordinator", NOWHERE], "no such directory"),
    ("status: two rigs named", ["status", "--rig-dir", "{rig}", "--rig", "another"], "is not the rig in"),
    ("room: three numbers for a point", ["room", "--hand", "1,2,3"], "'1,2,3' is not a point X,Y"),
    ("room: a path of one point", ["room", "--hand-path", "1,2"], "two or more points"),
    ("room: scale above 1", ["room", "--projector-scale", "2"], "--projector-scale: '2' is not a number"),
    ("room: port out of range", ["room", "--port", "70000"], "--port: '70000' is not a whole number 0..65535"),
    ("demo: size without height", ["demo", "--content-size", "600"], "--content-size: '600' is not a size"),
    ("bench sync: a word in a list", ["bench", "sync", "--nodes", "1,x"], "'1,x' is not a list of whole numbers"),
    ("swarm: no nodes", ["swarm", "--nodes", "0"], "--nodes: '0' is not a whole number"),
    ("calibrate: unknown mode", ["calibrate", "--mode", "wrong"], "--mode: invalid choice: 'wrong'"),
    ("calibrate: NaN contrast", ["calibrate", "--min-contrast", "nan"], "--min-contrast: 'nan' is not a number"),
    ("transport: negative dot radius", ["transport", "--radius", "-1"], "--radius: '-1' is not a whole number 1..16"),
    ("compensate: nothing to compensate", ["compensate", "--coordinator", NOWHERE, "--token-file", "{ok}"],
     "give an image or video file"),
    ("content add: not a rig", ["content", "add", "{ok}", "--rig-dir", "{dir}"], "is not a rig directory"),
    ("study: missing ratings", ["study", "scheffe", "{dir}/missing.csv"], "missing.csv"),
    # images: each declares 10000x10000 pixels in a file of a few kB; refused from its header, never decoded
    *[(f"show: a {fmt} declaring 100 megapixels", ["show", f"{{dir}}/bomb{HEADERS.SUFFIX[fmt]}", *REMOTE],
       "header declares 10000x10000 pixels (100.0 megapixels), nothing was decoded") for fmt in HEADERS.FORMATS],
    ("show: a PAM (OpenCV reads it, no header reader does)", ["show", "{dir}/x.pam", *REMOTE],
     "x.pam is not an image the coordinator reads: give PNG"),
    ("show: a PNG cut inside its header", ["show", "{dir}/cut.png", *REMOTE], "its PNG header cannot be read"),
    ("show: a TIFF cut inside its header", ["show", "{dir}/cut.tif", *REMOTE],
     "cut.tif: its TIFF header cannot be read"),
    ("show: an OpenEXR whose display window is 100 megapixels", ["show", "{dir}/wide.exr", *REMOTE],
     "its OpenEXR header declares 10000x10000 pixels"),
    *[(f"show: a {fmt} cut inside its pixels (OpenCV's own log stays quiet)",
       ["show", f"{{dir}}/half{HEADERS.SUFFIX[fmt]}", *REMOTE], f"half{HEADERS.SUFFIX[fmt]}: its {name} pixels cannot be "
       "decoded") for fmt, name in (("PNG", "PNG"), ("HDR", "Radiance HDR"), ("BMP", "BMP"))],
    ("show: an empty image file", ["show", "{dir}/empty.png", *REMOTE], "empty.png is empty"),
    ("show: float .npy outside 0..1", ["show", "{dir}/hot.npy", *REMOTE],
     "hot.npy holds values from -0.5 to 3, but float content must lie in 0..1"),
    ("show: an HDR photograph brighter than white", ["show", "{dir}/bright.hdr", *REMOTE], "pass --clip to clip it"),
    ("play: a float frame outside 0..1", ["play", "{dir}/hot-frames", *REMOTE], "0001.npy holds values from"),
    ("content add: a TIFF declaring 100 megapixels", ["content", "add", "{dir}/bomb.tif", "--rig-dir", "{rig}"],
     "its TIFF header declares 10000x10000 pixels"),
    ("content add: float .npy outside 0..1", ["content", "add", "{dir}/hot.npy", "--rig-dir", "{rig}"],
     "hot.npy holds values from -0.5 to 3"),
    ("demo: an image declaring 100 megapixels", ["demo", "--image", "{dir}/bomb.bmp", "--out", "{dir}/demo"],
     "bomb.bmp: its BMP header declares 10000x10000"),
    ("configure: a LUT of E rows and 3 columns", ["configure", "--slot", "r0c0", "--lut", "{dir}/lut-e3.npy", *REMOTE],
     "a LUT must be (3, E) (a curve per channel) or (E,) (one curve for all), got shape (256, 3); transpose it"),
    ("configure: a 3-D LUT", ["configure", "--slot", "r0c0", "--lut", "{dir}/lut-3d.npy", *REMOTE],
     "got shape (3, 16, 16)"),
    ("configure: LUT values above 1", ["configure", "--slot", "r0c0", "--lut", "{dir}/lut-hot.npy", *REMOTE],
     "LUT values must be finite and within [0, 1] (found 0 to 2)"),
    ("configure: a LUT of one entry", ["configure", "--slot", "r0c0", "--lut", "{dir}/lut-one.npy", *REMOTE],
     "2 <= E <= 65536"),
    ("configure: an integer LUT", ["configure", "--slot", "r0c0", "--lut", "{dir}/lut-int.npy", *REMOTE],
     "LUT must be float32 or float64, got int64"),
    ("show: a 200-byte .npy declaring 112 GiB", ["show", "{dir}/vast.npy", *REMOTE],
     "its header declares an array of shape (100000, 100000, 3) float32 (120,000,000,000 bytes)"),
    ("configure: a LUT .npy declaring 112 GiB", ["configure", "--slot", "r0c0", "--lut", "{dir}/vast.npy", *REMOTE],
     "not a readable .npy LUT (its header declares"),
    ("local: an --image outside 0..1", ["local", "--image", "{dir}/hot.npy"],
     "hot.npy holds values from -0.5 to 3, but float content must lie in 0..1 (0 black, 1 the projector's white): "
     "rescale it, or clip it to 0..1 first"),
    ("local: an --image declaring 100 megapixels", ["local", "--image", "{dir}/bomb.webp"],
     "its WebP header declares 10000x10000 pixels"),
    ("configure: an empty 1-D LUT", ["configure", "--slot", "r0c0", "--lut", "{dir}/lut-empty.npy", *REMOTE],
     "got (1, 0)"),
]


#: the cases that also run as real processes: the parser's refusal, a command's refusal of a value,
#: and a decoder's (whose library would write its own lines to the process's stderr)
REAL_PROCESS = ("unknown command", "configure: NaN gain",
                "show: a PNG cut inside its pixels (OpenCV's own log stays quiet)")


def digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    d = tmp_path_factory.mktemp("bad-args")
    rig = d / "rig"
    init_rig(rig, name="bad-args", slots=["r0c0"], width=32, height=18, content_width=32, content_height=18)
    ok, loose = d / "ok.token", d / "loose.token"
    for path, mode in ((ok, 0o600), (loose, 0o644)):
        path.write_text(auth.new_token() + "\n")
        path.chmod(mode)
    pickle = d / "pickled.npy"
    np.save(pickle, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    (d / "frames").mkdir()
    np.save(d / "frames" / "0001.npy", np.zeros((18, 32, 3), np.float32))
    np.save(d / "frames" / "0002.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    for fmt in HEADERS.FORMATS:
        (d / f"bomb{HEADERS.SUFFIX[fmt]}").write_bytes(HEADERS.huge(fmt))
    (d / "bright.hdr").write_bytes(HEADERS.valid("HDR"))         # values 0..4
    (d / "cut.png").write_bytes(HEADERS.valid("PNG")[:20])
    (d / "cut.tif").write_bytes(HEADERS.valid("TIFF")[:12])
    for fmt in ("PNG", "HDR", "BMP"):
        whole = HEADERS.valid(fmt)
        (d / f"half{HEADERS.SUFFIX[fmt]}").write_bytes(whole[:len(whole) * 6 // 10])
    exr = HEADERS.valid("EXR")
    i = exr.index(b"displayWindow\0box2i\0") + len(b"displayWindow\0box2i\0") + 4
    (d / "wide.exr").write_bytes(exr[:i] + np.array([0, 0, 9999, 9999], "<i4").tobytes() + exr[i + 16:])
    (d / "empty.png").write_bytes(b"")
    (d / "x.pam").write_bytes(b"P7\nWIDTH 4\nHEIGHT 4\nDEPTH 1\nMAXVAL 255\nTUPLTYPE GRAYSCALE\nENDHDR\n" + bytes(16))
    hot = np.full((18, 32, 3), 0.5, np.float32)
    hot[0, 0], hot[1, 1] = -0.5, 3.0
    np.save(d / "hot.npy", hot)
    (d / "hot-frames").mkdir()
    np.save(d / "hot-frames" / "0001.npy", hot)
    np.save(d / "lut-e3.npy", np.zeros((256, 3), np.float32))
    np.save(d / "lut-3d.npy", np.zeros((3, 16, 16), np.float32))
    np.save(d / "lut-hot.npy", np.linspace(0, 2, 3 * 16, dtype=np.float32).reshape(3, 16))
    np.save(d / "lut-one.npy", np.zeros((3, 1), np.float32))
    np.save(d / "lut-int.npy", np.arange(256).reshape(1, 256))
    np.save(d / "lut-empty.npy", np.zeros((0,), np.float32))
    vast = io.BytesIO()
    npy_format.write_array_header_1_0(vast, {"descr": "<f4", "fortran_order": False, "shape": (100000, 100000, 3)})
    (d / "vast.npy").write_bytes(vast.getvalue() + bytes(64))
    values = {"rig": str(rig), "dir": str(d), "ok": str(ok), "loose": str(loose), "pickle": str(pickle)}
    env = {k: v for k, v in os.environ.items() if k != "SHADOWLESS_TOKEN_FILE"}

    def one(case):
        argv = [a.format(**values) for a in case[1]]
        r = subprocess.run([sys.executable, "-m", "shadowless", *argv], capture_output=True, text=True,
                           timeout=120, env=env, cwd=d)
        return case[0], r

    before = digest(rig)
    with ThreadPoolExecutor(len(REAL_PROCESS)) as pool:
        processes = dict(pool.map(one, [c for c in CASES if c[0] in REAL_PROCESS]))
    return d, rig, values, processes, before, digest(rig)


@pytest.mark.parametrize("name, argv, expected", CASES, ids=[c[0] for c in CASES])
def test_a_mistake_is_one_line_and_status_2(results, corpus_table, capfd, monkeypatch, name, argv, expected):
    d, rig, values, _, _, _ = results
    args = [a.format(**values) for a in argv]
    monkeypatch.chdir(d)
    monkeypatch.delenv("SHADOWLESS_TOKEN_FILE", raising=False)
    before = digest(rig)
    code, _, stderr = run_shadowless(args, capfd)
    err = stderr.strip()
    corpus_table("CLI", "shadowless " + " ".join(Path(a).name if "/" in a else a for a in args), err, code)
    assert "Traceback" not in stderr, stderr
    assert code == 2, (code, stderr)
    assert len(err.splitlines()) == 1, err
    assert expected in err, err
    assert digest(rig) == before, "a refused command changed the rig directory"


@pytest.mark.parametrize("name", REAL_PROCESS)
def test_a_real_process_refuses_in_one_line_with_status_2(results, name):
    expected = next(c[2] for c in CASES if c[0] == name)
    r = results[3][name]
    err = r.stderr.strip()
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert len(err.splitlines()) == 1, err
    assert expected in err and err.startswith("shadowless"), err
    assert r.stdout == "", r.stdout


def test_the_corpus_is_large_enough_and_nothing_stored_changed(results):
    _, _, _, processes, before, after = results
    assert len(CASES) >= 50 + 33 and len(processes) == len(REAL_PROCESS)
    assert before == after, "a refused command changed the rig directory"
