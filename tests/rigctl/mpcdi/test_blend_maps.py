"""rigctl/mpcdi/blend_maps.py through archive.py: a rig's blend maps in MPCDI's alphaMap and betaMap
(16-bit PNGs, read back here with OpenCV on its own) and the extension's float32 maps. Exact from
shadowless to shadowless, exact on 16-bit levels through the standard data alone, and every
malformed map refused in one line naming its file."""
from __future__ import annotations

import io
import math
import zipfile
from xml.etree import ElementTree as ET

import cv2
import numpy as np
import pytest

from coordinator.blend_store import StoredBlend
from coordinator.rig import HomographyPose, Mesh, ProjectionPose, SlotState
from protos.blend import BlendMaps
from rigctl.mpcdi.archive import export_mpcdi, import_mpcdi
from rigctl.mpcdi.pfm import encode_pfm

CONTENT = (240, 160)
FRAME = (160, 100)


def planar_slots() -> list[SlotState]:
    def h(dx: float, dy: float) -> np.ndarray:
        return np.array([[0.9, 0.05, dx], [-0.03, 0.95, dy], [1e-5, 2e-5, 1.0]])
    return [SlotState("p1", *FRAME, pose=HomographyPose(h(-10, 5))),
            SlotState("p2", *FRAME, pose=HomographyPose(h(-90, -40))),
            SlotState("spare", *FRAME)]


def mesh_slots() -> list[SlotState]:
    from sim.mesh import bust

    b = bust(segments=12, rings=20)
    mesh = Mesh("bust", b.vertices, b.uvs, b.faces)
    out = []
    for i, a in enumerate((0.0, 2.0)):
        c = np.array([1500 * math.cos(a), 1500 * math.sin(a), 1200.0])
        fwd = (np.array([0, 0, 300.0]) - c) / np.linalg.norm(np.array([0, 0, 300.0]) - c)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        r = np.stack([right, np.cross(fwd, right), fwd])
        k = np.array([[200.0, 0, FRAME[0] / 2], [0, 200.0, FRAME[1] / 2], [0, 0, 1]])
        out.append(SlotState(f"o{i}", *FRAME, pose=ProjectionPose(k @ np.concatenate([r, (-r @ c)[:, None]], 1),
                                                                  mesh, 200.0, 5000.0)))
    return out


def random_maps(names, *, seed=3, size=(40, 25), levels=False) -> dict[str, BlendMaps]:
    """Maps of arbitrary float32 values (``levels``: on 16-bit levels), 0 and 1 included."""
    rng = np.random.default_rng(seed)
    maps = {}
    for n in names:
        a = rng.random((size[1], size[0], 3))
        b = rng.random((size[1], size[0])) * 0.1
        a[0, 0], a[-1, -1], b[0, 0] = 0.0, 1.0, 0.0
        if levels:
            a, b = np.rint(a * 65535) / 65535, np.rint(b * 65535) / 65535
        maps[n] = BlendMaps(a.astype(np.float32), b.astype(np.float32))
    return maps


def same_maps(a: dict[str, BlendMaps], b: dict[str, BlendMaps]) -> bool:
    return set(a) == set(b) and all(np.array_equal(a[k].alpha, b[k].alpha) and np.array_equal(a[k].beta, b[k].beta)
                                    for k in a)


def archive_parts(path) -> tuple[ET.Element, dict[str, bytes]]:
    with zipfile.ZipFile(path) as z:
        return ET.fromstring(z.read("mpcdi.xml")), {n: z.read(n) for n in z.namelist() if n != "mpcdi.xml"}


def write_archive(path, root: ET.Element, files: dict[str, bytes]) -> None:
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("mpcdi.xml", ET.tostring(root))
        for n, data in files.items():
            z.writestr(n, data)


def strip_extension(src, dst) -> None:
    """The archive as another tool writes it: no shadowless extension, none of its files."""
    root, files = archive_parts(src)
    root.remove(root.find("extensionSet"))
    write_archive(dst, root, {n: d for n, d in files.items() if not (n.endswith(".alpha.pfm") or n.endswith(".beta.pfm")
                                                                      or ".lut." in n)})


def png_levels(data: bytes) -> np.ndarray:
    """OpenCV's own reading of a PNG, channels R, G, B."""
    a = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    return a[..., ::-1] if a.ndim == 3 else a


@pytest.mark.parametrize("profile, slots", [("2d", planar_slots), ("sl", mesh_slots)])
def test_blend_maps_round_trip_bit_for_bit_and_follow_the_standard(tmp_path, profile, slots):
    slots = slots()
    names = [s.name for s in slots]
    maps = random_maps(names)
    info = {"headroom": 0.25, "brightness_cost": 0.2, "uniformity_after": 0.012, "created_at": 1.5e9}
    out = tmp_path / "rig.mpcdi"
    assert export_mpcdi(out, rig_name="r", content_size=CONTENT, slots=slots,
                        blend=StoredBlend(maps, info, {"before": np.ones((2, 2), np.float32)})) == profile
    back = import_mpcdi(out)
    assert back.blend_exact and back.blend_info == info
    assert same_maps(back.blend, maps)                      # float32, bit for bit, unposed slots too

    root, files = archive_parts(out)
    posed = [s.name for s in slots if s.pose is not None]
    for n in posed:
        fs = root.find(f"files/fileset[@region='{n}']")
        am, bm = fs.find("alphaMap"), fs.find("betaMap")
        assert [(c.tag, c.text) for c in am] == [("path", f"alpha-{n}.png"), ("componentDepth", "3"), ("bitDepth", "16"),
                                                  ("gammaEmbedded", "1.0")]
        assert [(c.tag, c.text) for c in bm] == [("path", f"beta-{n}.png"), ("componentDepth", "1"), ("bitDepth", "16")]
        a, b = png_levels(files[f"alpha-{n}.png"]), png_levels(files[f"beta-{n}.png"])
        assert a.dtype == np.uint16 and a.shape == (25, 40, 3) and b.shape == (25, 40)
        np.testing.assert_array_equal(a, np.rint(maps[n].alpha.astype(np.float64) * 65535))
        np.testing.assert_array_equal(b, np.rint(maps[n].beta.astype(np.float64) * 65535))
        if profile == "2d":                                 # the geometry warp comes first, as the standard orders it
            assert [c.tag for c in fs] == ["geometryWarpFile", "alphaMap", "betaMap"]
    assert not [f for f in root.iter("fileset") if f.get("region") not in posed]


def test_through_the_standard_data_alone_16_bit_levels_survive_and_reimport_is_the_identity(tmp_path):
    slots = planar_slots()[:2]
    on_levels = random_maps(["p1", "p2"], levels=True)
    export_mpcdi(tmp_path / "a.mpcdi", rig_name="r", content_size=CONTENT, slots=slots, blend=StoredBlend(on_levels))
    strip_extension(tmp_path / "a.mpcdi", tmp_path / "plain.mpcdi")
    first = import_mpcdi(tmp_path / "plain.mpcdi")
    assert not first.blend_exact and not first.exact
    assert same_maps(first.blend, on_levels)                # on 16-bit levels: bit for bit

    # any maps: the standard data gives their levels, and import -> export -> import changes nothing
    export_mpcdi(tmp_path / "b.mpcdi", rig_name="r", content_size=CONTENT, slots=slots,
                 blend=StoredBlend(random_maps(["p1", "p2"], seed=9)))
    strip_extension(tmp_path / "b.mpcdi", tmp_path / "b-plain.mpcdi")
    once = import_mpcdi(tmp_path / "b-plain.mpcdi").blend
    export_mpcdi(tmp_path / "c.mpcdi", rig_name="r", content_size=CONTENT, slots=slots, blend=StoredBlend(once))
    assert same_maps(import_mpcdi(tmp_path / "c.mpcdi").blend, once)
    strip_extension(tmp_path / "c.mpcdi", tmp_path / "c-plain.mpcdi")
    assert same_maps(import_mpcdi(tmp_path / "c-plain.mpcdi").blend, once)


def test_a_map_another_tool_rewrote_wins_over_the_extension(tmp_path):
    slots = planar_slots()[:1]
    maps = random_maps(["p1"])
    export_mpcdi(tmp_path / "a.mpcdi", rig_name="r", content_size=CONTENT, slots=slots, blend=StoredBlend(maps))
    root, files = archive_parts(tmp_path / "a.mpcdi")
    edited = np.full((25, 40, 3), 30000, np.uint16)
    files["alpha-p1.png"] = cv2.imencode(".png", edited)[1].tobytes()
    write_archive(tmp_path / "b.mpcdi", root, files)
    back = import_mpcdi(tmp_path / "b.mpcdi")
    assert not back.blend_exact
    np.testing.assert_array_equal(back.blend["p1"].alpha, np.float32(30000 / 65535))
    np.testing.assert_array_equal(back.blend["p1"].beta, np.rint(maps["p1"].beta * 65535.0) / np.float32(65535))


def third_party(tmp_path, alpha_png: bytes | None, beta_png: bytes | None, *, alpha_tags=(), beta_tags=(),
                frame=FRAME, name="third.mpcdi"):
    """A 2d archive written the way another tool might: one region, its warp and the maps given."""
    root = ET.Element("MPCDI", profile="2d", geometry="1", version="2.0")
    buf = ET.SubElement(ET.SubElement(root, "display"), "buffer", id="b", Xresolution=str(CONTENT[0]),
                        Yresolution=str(CONTENT[1]))
    ET.SubElement(buf, "region", id="p1", Xresolution=str(frame[0]), Yresolution=str(frame[1]), x="0", y="0",
                  xsize="1", ysize="1")
    fs = ET.SubElement(ET.SubElement(root, "files"), "fileset", region="p1")
    gw = ET.SubElement(fs, "geometryWarpFile")
    ET.SubElement(gw, "path").text = "warp.pfm"
    u, v = np.meshgrid((np.arange(8) + 0.5) / 8, (np.arange(5) + 0.5) / 5)
    files = {"warp.pfm": encode_pfm(np.stack([u, v, np.zeros_like(u)], -1))}
    for tag, data, extra in (("alphaMap", alpha_png, alpha_tags), ("betaMap", beta_png, beta_tags)):
        if data is None:
            continue
        e = ET.SubElement(fs, tag)
        ET.SubElement(e, "path").text = f"{tag}.png"
        for k, val in extra:
            ET.SubElement(e, k).text = val
        files[f"{tag}.png"] = data
    write_archive(tmp_path / name, root, files)
    return tmp_path / name


def test_other_tools_maps_8_bit_grey_and_gamma_are_read_as_the_standard_says(tmp_path):
    q = np.arange(200, dtype=np.uint8).reshape(10, 20)
    q[0, 0], q[-1, -1] = 0, 255
    grey8 = cv2.imencode(".png", q)[1].tobytes()
    # an 8-bit grey alpha map, no beta: the same gain on every channel, offset 0
    back = import_mpcdi(third_party(tmp_path, grey8, None, alpha_tags=[("componentDepth", "1"), ("bitDepth", "8")]))
    m = back.blend["p1"]
    np.testing.assert_array_equal(m.alpha, np.repeat((q / 255.0).astype(np.float32)[..., None], 3, axis=2))
    np.testing.assert_array_equal(m.beta, np.zeros((10, 20), np.float32))
    # exported again, the 8-bit levels q are the 16-bit levels 257 q: the same fractions, bit for bit
    slots = [SlotState("p1", *FRAME, pose=HomographyPose(np.eye(3)))]
    export_mpcdi(tmp_path / "again.mpcdi", rig_name="r", content_size=CONTENT, slots=slots, blend=StoredBlend(back.blend))
    _, files = archive_parts(tmp_path / "again.mpcdi")
    np.testing.assert_array_equal(png_levels(files["alpha-p1.png"]), np.repeat(q.astype(np.uint16)[..., None] * 257, 3, 2))
    strip_extension(tmp_path / "again.mpcdi", tmp_path / "again-plain.mpcdi")
    assert same_maps(import_mpcdi(tmp_path / "again-plain.mpcdi").blend, back.blend)

    # gammaEmbedded 2.2: linear alpha = value ** 2.2; an RGB beta map whose channels agree is one offset
    rgb16 = np.stack([np.full((10, 20), 40000, np.uint16)] * 3, -1)
    g = import_mpcdi(third_party(tmp_path, grey8, cv2.imencode(".png", rgb16)[1].tobytes(),
                                 alpha_tags=[("gammaEmbedded", "2.2")], name="gamma.mpcdi")).blend["p1"]
    np.testing.assert_allclose(g.alpha[..., 1], (q / 255.0) ** 2.2, rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(g.beta, np.float32(40000 / 65535))


def _png(a: np.ndarray) -> bytes:
    return cv2.imencode(".png", a)[1].tobytes()


GOOD = _png(np.full((10, 20), 50000, np.uint16))


@pytest.mark.parametrize("alpha, beta, kw, words", [
    (_png(np.zeros((120, 20), np.uint16)), None, {}, "alphaMap.png: the blend maps of p1 are 20x120 texels, larger than"),
    (GOOD, _png(np.zeros((11, 20), np.uint16)), {}, "alphaMap.png: the alpha map of region p1 is 20x10 texels, its beta map 20x11"),
    (GOOD, None, {"alpha_tags": [("bitDepth", "8")]}, "alphaMap.png: alpha map declares bitDepth 8, its PNG has 16-bit"),
    (GOOD, None, {"alpha_tags": [("componentDepth", "3")]}, "alphaMap.png: alpha map declares componentDepth 3, its PNG has 1"),
    (b"\x89PNG\r\n\x1a\nnot really", None, {}, "alphaMap.png: not a PNG file"),
    (GOOD[:60], None, {}, "alphaMap.png: the PNG is damaged"),
    (_png(np.zeros((10, 20, 4), np.uint8)), None, {}, "alphaMap.png: a blend map must be a grey or RGB PNG"),
    (GOOD, None, {"alpha_tags": [("gammaEmbedded", "-1")]}, "alphaMap.png: alpha map gammaEmbedded '-1' must be"),
    (GOOD, _png(np.dstack([np.zeros((10, 20), np.uint8), np.ones((10, 20), np.uint8), np.zeros((10, 20), np.uint8)])),
     {}, "betaMap.png: a beta map with a different offset per channel"),
])
def test_a_malformed_map_is_refused_in_one_line_naming_the_file(tmp_path, alpha, beta, kw, words):
    path = third_party(tmp_path, alpha, beta, **kw)
    with pytest.raises(ValueError) as e:
        import_mpcdi(path)
    msg = str(e.value)
    assert words in msg and "third.mpcdi" in msg and "\n" not in msg, msg


@pytest.mark.parametrize("bad, words", [
    (lambda a: np.where(np.arange(a.size).reshape(a.shape) == 7, np.nan, a), "p1.alpha.pfm: alpha map holds NaN"),
    (lambda a: a * 3.0, "p1.alpha.pfm: alpha map must lie in 0..1"),
])
def test_a_malformed_exact_map_is_refused_naming_the_file(tmp_path, bad, words):
    slots = [SlotState("p1", *FRAME)]                     # no pose: the extension's maps alone
    export_mpcdi(tmp_path / "a.mpcdi", rig_name="r", content_size=CONTENT, slots=slots,
                 blend=StoredBlend(random_maps(["p1"])))
    root, files = archive_parts(tmp_path / "a.mpcdi")
    from rigctl.mpcdi.pfm import decode_pfm
    files["p1.alpha.pfm"] = encode_pfm(bad(decode_pfm(files["p1.alpha.pfm"]).astype(np.float64)))
    write_archive(tmp_path / "b.mpcdi", root, files)
    with pytest.raises(ValueError, match=words):
        import_mpcdi(tmp_path / "b.mpcdi")


def test_a_rig_without_a_blend_exports_as_before(tmp_path):
    slots = planar_slots()
    export_mpcdi(tmp_path / "a.mpcdi", rig_name="r", content_size=CONTENT, slots=slots)
    export_mpcdi(tmp_path / "b.mpcdi", rig_name="r", content_size=CONTENT, slots=slots, blend=StoredBlend({}))
    for p in ("a.mpcdi", "b.mpcdi"):
        root, files = archive_parts(tmp_path / p)
        assert not [e for e in root.iter() if e.tag in ("alphaMap", "betaMap", "blend", "blendMaps")]
        assert sorted(files) == ["p1.pfm", "p2.pfm"]
        back = import_mpcdi(tmp_path / p)
        assert back.blend == {} and back.blend_info == {}
    with zipfile.ZipFile(io.BytesIO((tmp_path / "a.mpcdi").read_bytes())) as z:
        assert "alpha" not in " ".join(z.namelist())
