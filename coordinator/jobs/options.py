"""One definition per job option: the dataclass a job receives, its validation, its CLI
flag and its documentation all come from the same field.

A job declares its options as a frozen dataclass whose fields are made with
:func:`option`::

    @dataclass(frozen=True)
    class TransportOptions:
        \"\"\"Measure the rig's light transport.\"\"\"
        radius: int | None = option(None, lo=1, hi=64, help="PSF recovery radius in camera pixels")
        frames: int = option(1, lo=1, hi=64, help="captures averaged per pattern")
        force: bool = option(False, help="measure again instead of reusing stored results")

* :func:`parse_options` turns the JSON parameters of a job request into that dataclass,
  refusing unknown keys, wrong types and values out of range with a :class:`JobError` that
  names the parameter and what it accepts; a ``validate(self)`` method on the dataclass adds
  checks across fields.
* :func:`add_arguments` adds one ``--flag`` per field to an argparse parser (help text with
  the default and range), and :func:`params_from_args` collects only what the operator gave,
  so the defaults live in one place, the job's dataclass, applied on the coordinator.
* :func:`describe` lists the options (name, type, default, help) for documentation, and
  :func:`form_fields` describes them for a form (the operator console): a human label
  (``label=``, else derived from the name by :func:`derive_label`: ``keep_going`` -> "Keep
  going", ``settle_s`` -> "Settle (s)"), the unit, the range, the default and the help text.

Supported field types: ``bool``, ``int``, ``float``, ``str``, ``list[str]``, ``tuple[int, int]``,
``tuple[float, float]``, any of them ``| None``, and anything else through ``parse=``.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import types
import typing
from typing import Any, Callable, Mapping, Sequence

from coordinator.jobs.errors import JobError
from protos import cli_types

__all__ = ["option", "parse_options", "add_arguments", "params_from_args", "describe", "form_fields", "OptionInfo",
           "derive_label", "derive_unit"]

_META = "shadowless.option"

#: a name's last word that is a unit: the label shows it in brackets ("settle_s" -> "Settle (s)")
UNIT_SUFFIXES = {"s": "s", "ms": "ms", "ns": "ns", "mm": "mm", "mm2": "mm²", "px": "px", "pct": "%", "db": "dB",
                 "hz": "Hz", "mb": "MB", "mib": "MiB", "deg": "°"}
#: words of option names written out, or spelled as people write them
LABEL_WORDS = {"min": "minimum", "max": "maximum", "tol": "tolerance", "est": "estimate", "iter": "iterations",
               "eval": "evaluation", "lut": "LUT", "luts": "LUTs", "psnr": "PSNR", "srgb": "sRGB",
               "charuco": "ChArUco", "fps": "frame rate (fps)", "obj": "OBJ", "id": "ID", "ids": "IDs", "gl": "GL",
               "3d": "3D"}


@dataclasses.dataclass(frozen=True)
class OptionInfo:
    """What :func:`option` records about a field."""

    help: str
    lo: float | None = None
    hi: float | None = None
    choices: tuple[Any, ...] | None = None
    parse: Callable[[Any], Any] | None = None      # JSON value -> field value (raise ValueError/JobError)
    cli: bool = True                               # offer a --flag
    flag: str | None = None                        # default: --name-with-dashes
    metavar: str | None = None
    cli_type: Callable[[str], Any] | None = None   # command-line text -> JSON value
    group: str | None = None
    label: str | None = None                       # the form's label; default: derived from the name
    unit: str | None = None                        # shown beside the value; default: from the name's suffix


def derive_unit(name: str) -> str:
    """The unit a name's last word states (``settle_s`` -> ``s``, ``table_mm`` -> ``mm``); "" when none."""
    head, _, last = name.rpartition("_")
    return UNIT_SUFFIXES.get(last.lower(), "") if head else ""


def derive_label(name: str) -> str:
    """A human label from an option's name: words split at ``_``, abbreviations written out, the
    unit suffix in brackets, the first letter capitalised (``keep_going`` -> "Keep going",
    ``max_iter`` -> "Maximum iterations", ``settle_s`` -> "Settle (s)")."""
    unit = derive_unit(name)
    words = [w for w in name.split("_") if w]
    if unit:
        words = words[:-1]
    words = [LABEL_WORDS.get(w.lower(), w) for w in words]
    text = " ".join(words) or name
    if text[:2].islower() or text[1:2] in ("", " "):      # "sRGB", "LUT" keep their letters
        text = text[:1].upper() + text[1:]
    return f"{text} ({unit})" if unit else text


def option(default: Any = dataclasses.MISSING, *, help: str, lo: float | None = None, hi: float | None = None,
           choices: Sequence[Any] | None = None, parse: Callable[[Any], Any] | None = None, cli: bool = True,
           flag: str | None = None, metavar: str | None = None, cli_type: Callable[[str], Any] | None = None,
           group: str | None = None, default_factory: Callable[[], Any] | None = None, label: str | None = None,
           unit: str | None = None) -> Any:
    """A dataclass field that is a job option (see the module docstring).

    ``lo``/``hi`` bound numbers (inclusive), ``choices`` restricts values, ``parse`` converts
    a JSON value the generic rules do not cover, ``cli=False`` keeps it off the command line,
    ``flag``/``metavar``/``cli_type``/``group`` shape the command-line argument; ``label`` and
    ``unit`` are what a form shows (default: :func:`derive_label`, :func:`derive_unit`).
    """
    info = OptionInfo(help=help, lo=lo, hi=hi, choices=tuple(choices) if choices is not None else None, parse=parse,
                      cli=cli, flag=flag, metavar=metavar, cli_type=cli_type, group=group, label=label, unit=unit)
    if default_factory is not None:
        return dataclasses.field(default_factory=default_factory, metadata={_META: info})
    return dataclasses.field(default=default, metadata={_META: info})


def _fields(cls: type) -> list[tuple[dataclasses.Field, OptionInfo, Any]]:
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls!r} is not a dataclass")
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        info = f.metadata.get(_META)
        if info is not None:
            out.append((f, info, hints[f.name]))
    return out


def _split_optional(tp: Any) -> tuple[Any, bool]:
    """``X | None`` -> (X, True); anything else -> (tp, False)."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) < len(typing.get_args(tp)):
            return (args[0] if len(args) == 1 else typing.Union[tuple(args)]), True
    return tp, False


def _type_name(tp: Any) -> str:
    base, optional = _split_optional(tp)
    origin = typing.get_origin(base)
    if base is bool:
        name = "true/false"
    elif base is int:
        name = "an integer"
    elif base is float:
        name = "a number"
    elif base is str:
        name = "a string"
    elif origin is list:
        name = "a list of strings"
    elif origin is tuple:
        name = f"a list of {len(typing.get_args(base))} numbers"
    else:
        name = "a value"
    return name + (" or null" if optional else "")


def _number(name: str, value: Any, kind: type) -> int | float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        if isinstance(value, str):
            try:
                value = float(value)
            except ValueError:
                raise JobError(f"{name} must be {'an integer' if kind is int else 'a number'}, got {value!r}") from None
        else:
            raise JobError(f"{name} must be {'an integer' if kind is int else 'a number'}, got {value!r}")
    if not math.isfinite(float(value)):
        raise JobError(f"{name} must be finite, got {value!r}")
    if kind is int:
        if float(value) != int(value):
            raise JobError(f"{name} must be an integer, got {value!r}")
        return int(value)
    return float(value)


def _convert(name: str, value: Any, tp: Any) -> Any:
    base, optional = _split_optional(tp)
    if value is None:
        if optional:
            return None
        raise JobError(f"{name} must be {_type_name(tp)}, got null")
    origin = typing.get_origin(base)
    if base is bool:
        if isinstance(value, bool):
            return value
        raise JobError(f"{name} must be true or false, got {value!r}")
    if base in (int, float):
        return _number(name, value, base)
    if base is str:
        if isinstance(value, str):
            return value
        raise JobError(f"{name} must be a string, got {value!r}")
    if origin is list:
        if isinstance(value, str):
            value = [v.strip() for v in value.split(",") if v.strip()]
        if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
            raise JobError(f"{name} must be a list of strings, got {value!r}")
        return list(value)
    if origin is tuple:
        kinds = typing.get_args(base)
        if not isinstance(value, (list, tuple)) or len(value) != len(kinds):
            raise JobError(f"{name} must be a list of {len(kinds)} numbers, got {value!r}")
        return tuple(_number(name, v, k) for v, k in zip(value, kinds))
    return value


def _check_range(name: str, value: Any, info: OptionInfo) -> None:
    items = value if isinstance(value, (tuple, list)) else [value]
    for v in items:
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            if (info.lo is not None and v < info.lo) or (info.hi is not None and v > info.hi):
                lo = "-inf" if info.lo is None else f"{info.lo:g}"
                hi = "inf" if info.hi is None else f"{info.hi:g}"
                raise JobError(f"{name} must be in {lo}..{hi}, got {value!r}")
    if info.choices is not None and value is not None and value not in info.choices:
        raise JobError(f"{name} must be one of {', '.join(map(repr, info.choices))}, got {value!r}")


def parse_options(cls: type, params: Mapping[str, Any], *, what: str = "",
                  defaults: Mapping[str, Any] | None = None, defaults_source: str = "") -> Any:
    """Build the option dataclass ``cls`` from a job's JSON parameters.

    ``defaults`` (e.g. a table of rig.toml) fill in what ``params`` leaves out; errors in a value
    that came from them are prefixed with ``defaults_source``. Unknown keys, wrong types, values
    out of range and failed ``validate()`` checks raise :class:`JobError` naming the parameter.
    Keys in neither take the field's default.
    """
    if not isinstance(params, Mapping):
        raise JobError("job parameters must be a JSON object")
    defaults = dict(defaults or {})
    fields = _fields(cls)
    known = {f.name for f, _, _ in fields}
    label = f"{what} " if what else ""
    unknown = sorted(set(params) - known)
    if unknown:
        raise JobError(f"unknown {label}parameter(s) {', '.join(unknown)} (known: {', '.join(sorted(known))})")
    unknown = sorted(set(defaults) - known)
    if unknown:
        raise JobError(f"{defaults_source or 'defaults'}: unknown key(s) {', '.join(unknown)} "
                       f"(known: {', '.join(sorted(known))})")
    merged = {**defaults, **params}
    values: dict[str, Any] = {}
    for f, info, tp in fields:
        if f.name not in merged:
            continue
        raw = merged[f.name]
        try:
            try:
                value = info.parse(raw) if info.parse is not None and raw is not None else _convert(f.name, raw, tp)
            except JobError:
                raise
            except (TypeError, ValueError) as exc:
                raise JobError(f"{f.name}: {exc}") from exc
            _check_range(f.name, value, info)
        except JobError as exc:
            if f.name in params or not defaults_source:
                raise
            raise JobError(f"{defaults_source}: {exc}") from exc
        values[f.name] = value
    missing = [f.name for f in dataclasses.fields(cls)
               if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING and f.name not in values]
    if missing:
        raise JobError(f"missing parameter(s) {', '.join(missing)}")
    opts = cls(**values)
    validate = getattr(opts, "validate", None)
    if callable(validate):
        try:
            validate()
        except JobError:
            raise
        except ValueError as exc:
            raise JobError(str(exc)) from exc
    return opts


def _default_text(f: dataclasses.Field) -> str:
    if f.default is not dataclasses.MISSING:
        d = f.default
    elif f.default_factory is not dataclasses.MISSING:
        d = f.default_factory()
    else:
        return "required"
    if d is None or d == [] or d == ():
        return ""
    if isinstance(d, bool):
        return "on" if d else ""
    if isinstance(d, tuple):
        return "x".join(f"{v:g}" if isinstance(v, float) else str(v) for v in d)
    if isinstance(d, float):
        return f"{d:g}"
    return str(d)


def _cli_type(tp: Any, info: OptionInfo) -> tuple[Callable[[str], Any] | None, str | None]:
    if info.cli_type is not None:
        return info.cli_type, info.metavar
    base, _ = _split_optional(tp)
    origin = typing.get_origin(base)
    if base is int:      # the option's range is checked here too: a mistake costs no round trip
        return cli_types.int_range(-(1 << 62) if info.lo is None else int(math.ceil(info.lo)),
                                   None if info.hi is None else int(math.floor(info.hi))), info.metavar or "N"
    if base is float:
        return cli_types.number(info.lo, info.hi), info.metavar or "X"
    if base is str:
        return str, info.metavar or "TEXT"
    if origin is list:
        return cli_types.names, info.metavar or "A,B,..."
    if origin is tuple:
        kinds = typing.get_args(base)
        return _x_tuple(kinds), info.metavar or "x".join("N" if k is int else "X" for k in kinds)
    return None, info.metavar


def _x_tuple(kinds: tuple[type, ...]) -> Callable[[str], list]:
    def parse(text: str) -> list:
        parts = text.lower().replace(",", "x").split("x")
        try:
            if len(parts) != len(kinds):
                raise ValueError
            return [k(p) for k, p in zip(kinds, parts)]
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {len(kinds)} numbers like 4x4, got {text!r}") from None

    return parse


def add_arguments(parser: argparse.ArgumentParser, cls: type, *, exclude: Sequence[str] = ()) -> None:
    """Add a ``--flag`` for every command-line option of ``cls`` (defaults stay on the coordinator)."""
    groups: dict[str, Any] = {}
    for f, info, tp in _fields(cls):
        if not info.cli or f.name in exclude:
            continue
        target = parser
        if info.group:
            if info.group not in groups:
                groups[info.group] = parser.add_argument_group(info.group)
            target = groups[info.group]
        flag = info.flag or "--" + f.name.replace("_", "-")
        default = _default_text(f)
        text = info.help
        extras = []
        if default and default != "on":
            extras.append(f"default {default}")
        if info.lo is not None or info.hi is not None:
            lo = "" if info.lo is None else f"{info.lo:g}"
            hi = "" if info.hi is None else f"{info.hi:g}"
            extras.append(f"{lo}..{hi}")
        if extras:
            text = f"{text} ({'; '.join(extras)})"
        base, _ = _split_optional(tp)
        if base is bool:
            target.add_argument(flag, dest=f.name, action=argparse.BooleanOptionalAction, default=argparse.SUPPRESS,
                                help=text + (" (default on)" if default == "on" else ""))
            continue
        conv, metavar = _cli_type(tp, info)
        kwargs: dict[str, Any] = {"dest": f.name, "default": argparse.SUPPRESS, "help": text}
        if info.choices is not None and all(isinstance(c, str) for c in info.choices):
            kwargs["choices"] = list(info.choices)
        else:
            kwargs["metavar"] = metavar
        if conv is not None:
            kwargs["type"] = conv
        target.add_argument(flag, **kwargs)


def params_from_args(cls: type, args: argparse.Namespace, *, exclude: Sequence[str] = ()) -> dict[str, Any]:
    """The JSON parameters of ``cls``'s options the operator gave on the command line."""
    out: dict[str, Any] = {}
    for f, info, _ in _fields(cls):
        if info.cli and f.name not in exclude and hasattr(args, f.name):
            out[f.name] = getattr(args, f.name)
    return out


def _json_default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        d = f.default
    elif f.default_factory is not dataclasses.MISSING:
        d = f.default_factory()
    else:
        return None
    if isinstance(d, tuple):
        return list(d)
    return d if isinstance(d, (bool, int, float, str, list)) or d is None else str(d)


def form_fields(cls: type) -> list[dict[str, Any]]:
    """One entry per option, for a form (the operator console): name, ``label`` (human, see
    :func:`derive_label`), ``unit`` ("" when none), ``kind`` (``bool``, ``int``, ``float``,
    ``str``, ``choice``, ``list``, ``pair`` or ``json``), the default as JSON, the choices, the
    bounds, whether it may be null, its group, its help and ``flag`` (its command-line flag,
    "" when it has none: a page names the label instead)."""
    out = []
    for f, info, tp in _fields(cls):
        base, optional = _split_optional(tp)
        origin = typing.get_origin(base)
        if info.choices is not None:
            kind = "choice"
        elif base in (bool, int, float, str):
            kind = base.__name__
        elif origin is list:
            kind = "list"
        elif origin is tuple and len(typing.get_args(base)) == 2:
            kind = "pair"
        else:
            kind = "json"
        unit = derive_unit(f.name) if info.unit is None else info.unit
        out.append({"name": f.name, "label": info.label or derive_label(f.name), "unit": unit, "kind": kind,
                    "default": _json_default(f), "optional": optional,
                    "choices": list(info.choices) if info.choices is not None else None, "lo": info.lo,
                    "hi": info.hi, "group": info.group or "", "help": info.help,
                    "flag": (info.flag or "--" + f.name.replace("_", "-")) if info.cli else ""})
    return out


def describe(cls: type) -> list[dict[str, str]]:
    """One row per option: name, type, default and help (for documentation and `--help`)."""
    return [{"name": f.name, "type": _type_name(tp), "default": _default_text(f), "help": info.help}
            for f, info, tp in _fields(cls)]
