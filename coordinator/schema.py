"""The rig directory's files as pydantic models, defined once: ``rig.toml``, ``slots/<slot>.json``
and ``content/current.json``; plus safe readers that turn any damage into one line naming the file.

Every refusal is a :class:`~coordinator.errors.RigError` whose message is a single line
``<file>: <what is wrong>``; unknown keys suggest the closest valid one.
"""
from __future__ import annotations

import difflib
import json
import math
import re
import os
import tomllib
import types
import typing
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    model_validator,
)

from coordinator.errors import RigError
from coordinator.npy_header import check_npy_fits

SLOT_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,31}$")
FILE_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,127}$")
MIN_SIDE, MAX_SIDE = 16, 16384
#: a slot's linear gain lies in 0..MAX_GAIN (0: its light off)
MAX_GAIN = 16.0


# ---- field checks (plain functions, also used outside the models) -------------------------
def is_number(v: object) -> bool:
    """A finite int or float (numpy floats too), never a bool."""
    return (not isinstance(v, bool) and isinstance(v, (int, float, np.floating, np.integer))
            and math.isfinite(float(v)))


def valid_gain(gain: object) -> bool:
    """Whether ``gain`` is a number (not a bool) in 0..MAX_GAIN."""
    return is_number(gain) and 0.0 <= float(gain) <= MAX_GAIN


def _gain(v: object, info: ValidationInfo) -> float:
    if not valid_gain(v):
        raise ValueError(f"{info.field_name} must be a number in 0..{MAX_GAIN:g}, got {v!r}")
    return float(v)


def _side(v: object, info: ValidationInfo) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not MIN_SIDE <= v <= MAX_SIDE:
        raise ValueError(f"{info.field_name} must be an integer in {MIN_SIDE}..{MAX_SIDE}, got {v!r}")
    return v


def _int_in(lo: int, hi: int | None = None):
    def check(v: object, info: ValidationInfo) -> int:
        if isinstance(v, bool) or not isinstance(v, int) or v < lo or (hi is not None and v > hi):
            rng = f"{lo}..{hi}" if hi is not None else f">= {lo}"
            raise ValueError(f"{info.field_name} must be an integer {rng}, got {v!r}")
        return v
    return BeforeValidator(check)


def _num_in(lo: float, hi: float | None = None, *, lo_open: bool = False):
    def check(v: object, info: ValidationInfo) -> float:
        ok = is_number(v) and (float(v) > lo if lo_open else float(v) >= lo) and (hi is None or float(v) <= hi)
        if not ok:
            rng = f"{lo:g}..{hi:g}" if hi is not None else (f"> {lo:g}" if lo_open else f">= {lo:g}")
            raise ValueError(f"{info.field_name} must be a finite number {rng}, got {v!r}")
        return float(v)
    return BeforeValidator(check)


def _text(v: object, info: ValidationInfo) -> str:
    if not isinstance(v, str):
        raise ValueError(f"{info.field_name} must be a string, got {v!r}")
    return v


def _nonempty(v: object, info: ValidationInfo) -> str:
    if not isinstance(v, str) or not v:
        raise ValueError(f"`{info.field_name}` must be a non-empty string, got {v!r}")
    return v


def _slot_name(v: str) -> str:
    if not SLOT_RE.match(v):
        raise ValueError(f"slot name {v!r} must be 1-32 letters, digits, '_', '-' or '.'")
    return v


def _file_name(v: object, info: ValidationInfo) -> str:
    if not isinstance(v, str) or not FILE_RE.match(v):
        raise ValueError(f"{info.field_name} must be a plain file name in the same folder, got {v!r}")
    return v


def _mesh_id(v: object, info: ValidationInfo) -> str:
    if not isinstance(v, str) or not v or v.startswith(".") or any(c in v for c in "/\\\x00") or len(v) > 200:
        raise ValueError(f"{info.field_name} must be a mesh id (a file name in meshes/), got {v!r}")
    return v


def _rel_path(v: object, info: ValidationInfo) -> str:
    parts = v.split("/") if isinstance(v, str) else []
    if not parts or not all(FILE_RE.match(p) for p in parts):
        raise ValueError(f"{info.field_name} must be a path inside the rig directory, e.g. luts/r0c0.r1.npy, got {v!r}")
    return v


def _matrix(rows: int, cols: int, *, invertible: bool):
    """A check for a (rows, cols) list of finite numbers (stored as float64); ``invertible`` adds
    :func:`check_homography`."""
    def check(v: object, info: ValidationInfo) -> list[list[float]]:
        shape = None
        try:
            if isinstance(v, list) and all(isinstance(r, list) for r in v) and all(is_number(x) or isinstance(x, float)
                                                                                    for r in v for x in r):
                m = np.array(v, dtype=np.float64)
                shape = m.shape
        except ValueError:
            pass
        what = "homography" if invertible else "projection matrix"
        if shape != (rows, cols):
            raise ValueError(f"{info.field_name}: a {what} must be a ({rows}, {cols}) list of numbers")
        if not np.all(np.isfinite(m)):
            raise ValueError(f"{info.field_name}: a {what} must be finite (no NaN or infinity)")
        if invertible:
            check_homography(m)
        return m.tolist()
    return BeforeValidator(check)


def check_homography(m: np.ndarray) -> np.ndarray:
    """A homography is a finite, invertible (3, 3) float64 matrix; returns it as float64."""
    m = np.asarray(m, dtype=np.float64)
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        raise ValueError(f"a homography must be a finite, invertible (3, 3) matrix, got shape {m.shape}")
    if abs(np.linalg.det(m)) < 1e-12:
        raise ValueError("a homography must be invertible, this one is singular (determinant ~0)")
    return m


def validate_lut(lut: np.ndarray) -> None:
    """A LUT is (C, E) float32 with C in {1, 3}, 2 <= E <= 65536, values in [0, 1], finite."""
    if lut.ndim != 2 or lut.shape[0] not in (1, 3) or not 2 <= lut.shape[1] <= 65536:
        raise ValueError(f"a LUT must be (C, E) with C in {{1, 3}} and 2 <= E <= 65536, got {lut.shape}")
    if not np.all(np.isfinite(lut)) or lut.min() < 0.0 or lut.max() > 1.0:
        raise ValueError("LUT values must be finite and within [0, 1]")


Side = Annotated[int, BeforeValidator(_side)]
Text = Annotated[str, BeforeValidator(_text)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


# ---- rig.toml -------------------------------------------------------------------------------
class SizeDoc(_Strict):
    """A resolution; in ``[defaults]`` and per slot (``r0c0 = { width = 1280, height = 800 }``)."""

    width: Side | None = None
    height: Side | None = None


#: the most of each point's light a blend may hold in reserve for failover (rig.toml [blend] headroom)
MAX_HEADROOM = 0.9


def _headroom(v: object, info: ValidationInfo) -> str | float:
    if v == "auto" or (is_number(v) and 0.0 <= float(v) <= MAX_HEADROOM):
        return v if v == "auto" else float(v)
    raise ValueError(f"headroom must be \"auto\" or a number in 0..{MAX_HEADROOM:g} (the fraction of light held "
                     f"in reserve for failover), got {v!r}")


def _switch_lead(v: object, info: ValidationInfo) -> str | float:
    if v == "auto" or (is_number(v) and 1.0 <= float(v) <= 1000.0):
        return v if v == "auto" else float(v)
    raise ValueError(f"switch_lead_ms must be \"auto\" or a number of ms in 1..1000 (how far ahead a failover's "
                     f"new maps are set), got {v!r}")


def _flag(v: object, info: ValidationInfo) -> bool:
    if not isinstance(v, bool):
        raise ValueError(f"{info.field_name} must be true or false, got {v!r}")
    return v


class BlendDoc(_Strict):
    """``[blend]`` in rig.toml: the per-pixel blend's reserve and the photometric watchdog.

    ``headroom``: "auto" (enough that losing any one projector is covered where others reach) or
    a fraction 0..0.9 of each point's light held back; ``watchdog``: whether the coordinator checks
    the lamps through the camera during a show; ``watchdog_interval_s``: how often."""

    headroom: Annotated[str | float, BeforeValidator(_headroom)] = "auto"
    watchdog: Annotated[bool, BeforeValidator(_flag)] = True
    watchdog_interval_s: Annotated[float, _num_in(0.2, 86_400)] = 1.0
    #: how far ahead a failover's switch of maps is set (ms), or "auto": from the bytes it pushes
    switch_lead_ms: Annotated[str | float, BeforeValidator(_switch_lead)] = "auto"


class RigToml(_Strict):
    """``rig.toml``. heartbeat/lost-after defaults depend on the slot count and are filled in
    by :func:`coordinator.rig.parse_config`."""

    name: Annotated[str, BeforeValidator(_nonempty)]
    id: Annotated[str, BeforeValidator(_nonempty)]
    content_width: Side = 1200
    content_height: Side = 600
    latency_ms: Annotated[float, _num_in(1, 5000)] = 50.0
    heartbeat_ms: Annotated[int, _int_in(50, 60_000)] | None = None
    lost_after_ms: Annotated[int, _int_in(100, 3_600_000)] | None = None
    cameras: list[Annotated[str, BeforeValidator(_nonempty)]] = Field(default_factory=list)
    defaults: SizeDoc = SizeDoc()
    slots: dict[Annotated[str, AfterValidator(_slot_name)], SizeDoc]
    #: the calibrate job's defaults for this rig; its keys are that job's options, checked by
    #: coordinator.calibration.options when a job reads them
    calibration: dict[str, Any] | None = None
    blend: BlendDoc = BlendDoc()
    #: show control over OSC (off unless it names ``listen``); its keys are checked by coordinator.osc.config
    osc: dict[str, Any] | None = None

    @model_validator(mode="after")
    def _check(self) -> RigToml:
        if not self.slots:
            raise ValueError("needs a [slots] table with at least one slot (e.g. r0c0 = {})")
        if self.heartbeat_ms and self.lost_after_ms and self.lost_after_ms < 2 * self.heartbeat_ms:
            raise ValueError("heartbeat_ms must be 50..60000 and lost_after_ms at least twice it")
        return self


# ---- slots/<slot>.json ----------------------------------------------------------------------
class HomographyDoc(_Strict):
    """A planar pose: ``matrix`` is a finite, invertible (3, 3) list (float64), content px -> projector px."""

    kind: Literal["homography"]
    matrix: Annotated[list[list[float]], _matrix(3, 3, invertible=True)]


class ProjectionDoc(_Strict):
    """A 3D pose: ``matrix`` is a finite (3, 4) list (float64), world mm -> projector px; renders
    ``meshes/<mesh>.npz``."""

    kind: Literal["projection"]
    matrix: Annotated[list[list[float]], _matrix(3, 4, invertible=False)]
    mesh: Annotated[str, BeforeValidator(_mesh_id)]
    near_mm: Annotated[float, _num_in(0, lo_open=True)] = 100.0
    far_mm: Annotated[float, _num_in(0, lo_open=True)] = 10_000.0

    @model_validator(mode="after")
    def _check(self) -> ProjectionDoc:
        if not self.near_mm < self.far_mm:
            raise ValueError("projection pose needs 0 < near_mm < far_mm")
        return self


class SlotFile(_Strict):
    """``slots/<slot>.json``: the persisted assignment (the LUT itself is ``lut``, a .npy path)."""

    revision: Annotated[int, _int_in(0)] = 0
    gain: Annotated[float, BeforeValidator(_gain)] = 1.0
    width: Side | None = None
    height: Side | None = None
    source: Text = ""
    updated_at: Annotated[float, _num_in(0)] = 0.0
    pose: Annotated[HomographyDoc | ProjectionDoc, Field(discriminator="kind")] | None = None
    #: the pose a layout planned (`rig init --layout`): never rendered nor used by a job, only by
    #: `coverage --planned`; a calibrated or configured pose replaces it
    planned: ProjectionDoc | None = None
    lut: Annotated[str, BeforeValidator(_rel_path)] | None = None


# ---- content/current.json -------------------------------------------------------------------
class ContentMeta(_Strict):
    """``content/current.json``: which image file in ``content/`` the rig shows."""

    file: Annotated[str, BeforeValidator(_file_name)]
    name: Text = ""
    content_id: Text = ""
    updated_at: Annotated[float, _num_in(0)] = 0.0


# ---- messages -------------------------------------------------------------------------------
def _unwrap(t: Any) -> list[Any]:
    """The concrete types behind Optional/Union/Annotated."""
    origin = typing.get_origin(t)
    if origin is Annotated:
        return _unwrap(typing.get_args(t)[0])
    if origin in (typing.Union, types.UnionType):
        return [x for a in typing.get_args(t) for x in _unwrap(a)]
    return [] if t is type(None) else [t]


def _known_keys(model: type[BaseModel], path: tuple) -> list[str]:
    """The valid keys of the table at ``path`` (a pydantic error location) inside ``model``."""
    current: list[Any] = [model]
    for part in path:
        nxt: list[Any] = []
        for t in current:
            if isinstance(t, type) and issubclass(t, BaseModel):
                if part in t.model_fields:
                    nxt += _unwrap(t.model_fields[part].annotation)
                elif "kind" in t.model_fields and typing.get_args(t.model_fields["kind"].annotation) == (part,):
                    nxt.append(t)   # a discriminated union's tag in the location
            elif typing.get_origin(t) is dict:
                nxt += _unwrap(typing.get_args(t)[1])
        current = nxt
    return sorted({k for t in current if isinstance(t, type) and issubclass(t, BaseModel) for k in t.model_fields})


def one_line(text: str) -> str:
    return " ".join(str(text).split())


def describe(exc: ValidationError, model: type[BaseModel], source: str) -> str:
    """The first problem in ``exc`` as ``<source>: <what is wrong>`` (unknown keys suggest the
    closest valid key)."""
    errors = exc.errors(include_url=False)
    # a misspelled key shows up as unknown + missing: name the unknown one, it carries the hint
    err = next((e for e in errors if e["type"] == "extra_forbidden"), errors[0])
    loc = tuple(err["loc"])
    where = ".".join(str(p) for p in loc)
    if err["type"] == "extra_forbidden":
        key = str(loc[-1])
        known = _known_keys(model, loc[:-1])
        close = difflib.get_close_matches(key, known, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else (f" (valid keys: {', '.join(known)})" if known else "")
        table = f" in [{'.'.join(str(p) for p in loc[:-1])}]" if len(loc) > 1 else ""
        return one_line(f"{source}: unknown key {key!r}{table}{hint}")
    if err["type"] == "missing":
        return one_line(f"{source}: missing key `{where}`")
    if err["type"] == "value_error":
        msg = str(err["ctx"]["error"]) if "ctx" in err else err["msg"]
        prefix = ".".join(str(p) for p in loc[:-1])
        return one_line(f"{source}: {prefix + ': ' if prefix else ''}{msg}")
    if err["type"] in ("union_tag_invalid", "union_tag_not_found"):
        return one_line(f"{source}: {where}: `kind` must be 'homography' or 'projection'")
    return one_line(f"{source}: {where + ': ' if where else ''}{err['msg']}, got {err.get('input')!r}")


def validate(model: type[BaseModel], doc: object, source: str):
    """``model`` built from ``doc``, or a one-line :class:`RigError` naming ``source``."""
    if not isinstance(doc, dict):
        raise RigError(f"{source}: must hold a JSON object / TOML table, got {type(doc).__name__}")
    try:
        return model.model_validate(doc)
    except ValidationError as exc:
        raise RigError(describe(exc, model, source)) from None


# ---- readers --------------------------------------------------------------------------------
def read_bytes(path: Path) -> bytes:
    """A file's bytes, or a one-line RigError: missing, a directory, unreadable."""
    if path.is_dir():
        raise RigError(f"{path}: is a directory, expected a file")
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise RigError(f"{path}: missing") from None
    except OSError as exc:
        raise RigError(f"{path}: cannot read ({exc.strerror})") from None


def read_text(path: Path) -> str:
    """A UTF-8 text file's content; binary data is refused in one line."""
    data = read_bytes(path)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise RigError(f"{path}: not a text file (binary data; is it the right file?)") from None
    if "\x00" in text:
        raise RigError(f"{path}: not a text file (binary data; is it the right file?)")
    return text


def parse_toml(text: str, source: str) -> dict:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RigError(one_line(f"{source}: not valid TOML: {exc}")) from None


def read_json(path: Path) -> object:
    """A JSON file's document; truncated or damaged JSON is one line naming the file."""
    text = read_text(path)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        what = "empty" if not text.strip() else f"not valid JSON ({exc.msg}; line {exc.lineno} column {exc.colno})"
        raise RigError(f"{path}: {what}") from None
    except RecursionError:
        raise RigError(f"{path}: not valid JSON (nested too deep)") from None


def read_npy(path: Path, dtypes: tuple[str, ...], what: str) -> np.ndarray:
    """An array from a .npy file whose dtype is one of ``dtypes`` (e.g. ``("float32",)``);
    pickles, damage and other dtypes are refused in one line."""
    if path.is_dir():
        raise RigError(f"{path}: is a directory, expected a {what} .npy file")
    try:
        with open(path, "rb") as f:
            check_npy_fits(f, os.fstat(f.fileno()).st_size)   # before numpy allocates its shape
            arr = np.load(f, allow_pickle=False)
    except FileNotFoundError:
        raise RigError(f"{path}: missing ({what})") from None
    except (OSError, ValueError, EOFError) as exc:
        raise RigError(one_line(f"{path}: not a readable .npy {what} ({exc})")) from None
    if not isinstance(arr, np.ndarray) or arr.dtype.name not in dtypes:
        got = arr.dtype.name if isinstance(arr, np.ndarray) else type(arr).__name__
        raise RigError(f"{path}: {what} must be {' or '.join(dtypes)}, got {got}")
    return arr
