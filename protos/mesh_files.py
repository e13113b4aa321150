"""Triangle mesh files, OBJ and PLY (ASCII or binary), read and written once for every package.

Arrays: ``vertices (V, 3) float64`` (world millimetres), ``faces (F, 3) int64`` (indices into the
vertices), ``uvs (V, 2) float64`` or None, with (0, 0) the top-left corner of the content (the
project's convention). OBJ and PLY store texture v growing upwards, so reading and writing flip
v (``v_ours = 1 - v_file``). Polygons are read as triangle fans; an OBJ vertex used with several
texture coordinates is split, so every vertex has one uv. Only numpy.
"""
from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np


class MeshFileError(ValueError):
    """A mesh file cannot be read; the message names the file and what is wrong."""


class MeshArrays(NamedTuple):
    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None


def read_mesh(path: str | Path) -> MeshArrays:
    """Read ``path`` (``.obj`` or ``.ply``); MeshFileError names the file and the problem."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise MeshFileError(f"cannot read mesh {path}: {exc.strerror or exc}") from None
    try:
        return parse_mesh(data, path.suffix)
    except MeshFileError as exc:
        raise MeshFileError(f"mesh {path}: {exc}") from None


def parse_mesh(data: bytes, suffix: str) -> MeshArrays:
    """Mesh file bytes of type ``suffix`` (``.obj`` or ``.ply``) -> arrays (MeshFileError)."""
    kind = suffix.lower().lstrip(".")
    if kind not in ("obj", "ply"):
        raise MeshFileError(f"unknown mesh format {suffix!r}; use .obj or .ply")
    try:
        mesh = _parse_obj(data.decode("utf-8", errors="replace")) if kind == "obj" else _parse_ply(data)
    except MeshFileError:
        raise
    except (ValueError, IndexError, KeyError, TypeError) as exc:
        raise MeshFileError(f"malformed {kind.upper()} file ({exc})") from None
    if len(mesh.faces) == 0:
        raise MeshFileError("no faces")
    if not np.all(np.isfinite(mesh.vertices)):
        raise MeshFileError("vertices contain NaN or infinite coordinates")
    return mesh


def _index(token: str, count: int) -> int:
    i = int(token)
    return i - 1 if i > 0 else count + i


def _parse_obj(text: str) -> MeshArrays:
    verts: list[list[float]] = []
    texs: list[list[float]] = []
    corners: list[tuple[int, int]] = []   # (vertex, texcoord or -1) per triangle corner
    for raw in text.splitlines():
        line = raw.split("#", 1)[0]
        parts = line.split()
        if not parts:
            continue
        tag = parts[0]
        if tag == "v":
            verts.append([float(x) for x in parts[1:4]])
        elif tag == "vt":
            texs.append([float(x) for x in parts[1:3]])
        elif tag == "f":
            poly = []
            for tok in parts[1:]:
                fields = tok.split("/")
                vi = _index(fields[0], len(verts))
                ti = _index(fields[1], len(texs)) if len(fields) > 1 and fields[1] else -1
                if not 0 <= vi < len(verts) or ti >= len(texs) or (len(fields) > 1 and fields[1] and ti < 0):
                    raise MeshFileError(f"face refers to a missing vertex or texture coordinate: {line.strip()!r}")
                poly.append((vi, ti))
            if len(poly) < 3:
                raise MeshFileError(f"face with fewer than 3 corners: {line.strip()!r}")
            for k in range(1, len(poly) - 1):
                corners += [poly[0], poly[k], poly[k + 1]]
    if not verts:
        raise MeshFileError("no vertices")
    v = np.array(verts, np.float64)
    if not corners:
        return MeshArrays(v, np.zeros((0, 3), np.int64), None)
    pairs = np.array(corners, np.int64)
    if np.all(pairs[:, 1] >= 0):
        uniq, inv = np.unique(pairs, axis=0, return_inverse=True)
        uv = np.array(texs, np.float64)[uniq[:, 1]]
        uv[:, 1] = 1.0 - uv[:, 1]
        return MeshArrays(v[uniq[:, 0]], inv.reshape(-1, 3).astype(np.int64), uv)
    return MeshArrays(v, pairs[:, 0].reshape(-1, 3), None)


_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def _parse_ply(data: bytes) -> MeshArrays:
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise MeshFileError("not a PLY file (no 'ply' magic or 'end_header')")
    body = data[data.index(b"\n", end) + 1:]
    fmt = None
    elements: list[dict] = []
    for line in data[:end].decode("ascii", errors="replace").splitlines()[1:]:
        p = line.split()
        if not p or p[0] in ("comment", "obj_info"):
            continue
        if p[0] == "format":
            fmt = p[1]
        elif p[0] == "element":
            elements.append({"name": p[1], "count": int(p[2]), "props": []})
        elif p[0] == "property":
            if not elements:
                raise MeshFileError("PLY property before any element")
            if p[1] == "list":
                elements[-1]["props"].append((p[4], "list", _PLY_TYPES[p[2]], _PLY_TYPES[p[3]]))
            else:
                elements[-1]["props"].append((p[2], _PLY_TYPES[p[1]], None, None))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise MeshFileError(f"unsupported PLY format {fmt!r}")
    order = ">" if fmt == "binary_big_endian" else "<"
    values: dict[str, dict[str, list | np.ndarray]] = {}
    if fmt == "ascii":
        tokens = body.decode("ascii", errors="replace").split()
        pos = 0
        for el in elements:
            cols: dict[str, list] = {name: [] for name, *_ in el["props"]}
            for _ in range(el["count"]):
                for name, kind, _ct, _it in el["props"]:
                    if kind == "list":
                        n = int(float(tokens[pos]))
                        cols[name].append([float(x) for x in tokens[pos + 1:pos + 1 + n]])
                        pos += 1 + n
                    else:
                        cols[name].append(float(tokens[pos]))
                        pos += 1
            values[el["name"]] = cols
    else:
        pos = 0
        for el in elements:
            props = el["props"]
            if all(kind != "list" for _, kind, _, _ in props):
                dt = np.dtype([(name, order + kind) for name, kind, _, _ in props])
                arr = np.frombuffer(body, dt, count=el["count"], offset=pos)
                pos += dt.itemsize * el["count"]
                values[el["name"]] = {name: arr[name].astype(np.float64) for name, *_ in props}
                continue
            cols = {name: [] for name, *_ in props}
            for _ in range(el["count"]):
                for name, kind, ct, it in props:
                    if kind == "list":
                        cdt = np.dtype(order + ct)
                        n = int(np.frombuffer(body, cdt, 1, pos)[0])
                        pos += cdt.itemsize
                        idt = np.dtype(order + it)
                        cols[name].append(np.frombuffer(body, idt, n, pos).tolist())
                        pos += idt.itemsize * n
                    else:
                        dt = np.dtype(order + kind)
                        cols[name].append(float(np.frombuffer(body, dt, 1, pos)[0]))
                        pos += dt.itemsize
            values[el["name"]] = cols
    vert = values.get("vertex")
    if not vert or not all(k in vert for k in "xyz"):
        raise MeshFileError("PLY has no vertex element with x, y, z")
    v = np.column_stack([np.asarray(vert[k], np.float64) for k in "xyz"])
    uv = None
    for un, vn in (("u", "v"), ("s", "t"), ("texture_u", "texture_v")):
        if un in vert and vn in vert:
            uv = np.column_stack([np.asarray(vert[un], np.float64), 1.0 - np.asarray(vert[vn], np.float64)])
            break
    face = values.get("face", {})
    lists = face.get("vertex_indices", face.get("vertex_index"))
    if lists is None:
        raise MeshFileError("PLY has no face element with vertex_indices")
    tris = []
    for poly in lists:
        poly = [int(i) for i in poly]
        if len(poly) < 3:
            raise MeshFileError("PLY face with fewer than 3 corners")
        tris += [[poly[0], poly[k], poly[k + 1]] for k in range(1, len(poly) - 1)]
    faces = np.array(tris, np.int64).reshape(-1, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= len(v)):
        raise MeshFileError(f"PLY face refers to a missing vertex (index {int(faces.max())} of {len(v)})")
    return MeshArrays(v, faces, uv)


def format_obj(vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray | None = None, *, exact: bool = False,
               comment: str = "shadowless mesh (millimetres)") -> str:
    """OBJ text of a mesh; ``exact`` writes every float so it reads back bit for bit (else 7
    significant digits, enough for float32 vertices)."""
    num = (lambda x: repr(float(x))) if exact else (lambda x: f"{x:.7g}")  # noqa: E731
    lines = [f"# {comment}"]
    lines += [f"v {num(x)} {num(y)} {num(z)}" for x, y, z in np.asarray(vertices, np.float64)]
    f1 = np.asarray(faces, np.int64) + 1
    if uvs is not None:
        lines += [f"vt {num(u)} {num(1.0 - v)}" for u, v in np.asarray(uvs, np.float64)]
        lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in f1]
    else:
        lines += [f"f {a} {b} {c}" for a, b, c in f1]
    return "\n".join(lines) + "\n"


def format_ply(vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray | None = None, *, binary: bool = True,
               comment: str = "shadowless mesh (millimetres)") -> bytes:
    """PLY bytes of a mesh (float32 vertices and uvs; binary little-endian or ASCII)."""
    has_uv = uvs is not None
    header = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0", f"comment {comment}",
              f"element vertex {len(vertices)}", "property float x", "property float y", "property float z"]
    if has_uv:
        header += ["property float u", "property float v"]
    header += [f"element face {len(faces)}", "property list uchar uint vertex_indices", "end_header"]
    head = ("\n".join(header) + "\n").encode("ascii")
    cols = [np.asarray(vertices, np.float64)]
    if has_uv:
        uv = np.asarray(uvs, np.float64)
        cols.append(np.column_stack([uv[:, 0], 1.0 - uv[:, 1]]))
    vert = np.hstack(cols).astype("<f4")
    f = np.asarray(faces, np.int64)
    if binary:
        fdt = np.dtype([("n", "u1"), ("i", "<u4", (3,))])
        packed = np.empty(len(f), dtype=fdt)
        packed["n"] = 3
        packed["i"] = f
        return head + vert.tobytes() + packed.tobytes()
    body = "\n".join(" ".join(f"{x:.7g}" for x in row) for row in vert)
    body += "\n" + "\n".join(f"3 {a} {b} {c}" for a, b, c in f)
    return head + body.encode("ascii") + b"\n"
