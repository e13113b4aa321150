"""A reader for the subset of YAML that deploy/docker/compose.yaml is written in, so that the
tests read it without PyYAML (which this project does not depend on): block mappings, block
sequences of scalars, flow sequences written as JSON arrays, double- or single-quoted and plain
scalars (ints, true/false, null, strings) and comments. Anything else (anchors, flow mappings,
block scalars, tabs, a key twice) is refused with the line number, so the file stays readable
by this and means the same to Docker Compose (the tests compare with PyYAML where it exists).
"""
from __future__ import annotations

import json
import re

__all__ = ["YamlSubsetError", "load"]

KEY = re.compile(r"([A-Za-z0-9_.-]+):(?:[ ]+(.*))?")


class YamlSubsetError(ValueError):
    def __init__(self, line: int, message: str):
        super().__init__(f"line {line}: {message}")


def _strip_comment(raw: str) -> str:
    quote = None
    for i, ch in enumerate(raw):
        if quote:
            if ch == quote and not (quote == '"' and raw[i - 1] == "\\"):
                quote = None
        elif ch in "\"'" and (i == 0 or raw[i - 1] in " [,:-"):
            quote = ch
        elif ch == "#" and (i == 0 or raw[i - 1] == " "):
            return raw[:i].rstrip()
    return raw.rstrip()


def _scalar(text: str, line: int):
    if text.startswith("["):
        try:
            value = json.loads(text)
        except ValueError as exc:
            raise YamlSubsetError(line, f"a flow sequence must be a JSON array of strings or numbers: {exc}") from exc
        if not all(isinstance(v, (str, int, float)) for v in value):
            raise YamlSubsetError(line, "a flow sequence holds only strings and numbers here")
        return value
    if text.startswith('"'):
        try:
            return json.loads(text)
        except ValueError as exc:
            raise YamlSubsetError(line, f"bad double-quoted string: {exc}") from exc
    if text.startswith("'"):
        if len(text) < 2 or not text.endswith("'"):
            raise YamlSubsetError(line, "unterminated single-quoted string")
        return text[1:-1].replace("''", "'")
    if text[0] in "{&*!|>%@`?" or text.startswith(("- ", "<<")):
        raise YamlSubsetError(line, f"not in the subset: {text!r}")
    if ": " in text or text.endswith(":"):
        raise YamlSubsetError(line, f"a plain scalar with ': ' in it, quote it: {text!r}")
    if re.fullmatch(r"[-+]?[0-9]+", text):
        return int(text)
    if text in ("true", "false"):
        return text == "true"
    if text in ("null", "~"):
        return None
    if re.fullmatch(r"(?i)(yes|no|on|off|y|n|[-+]?[0-9.]+(e[-+]?[0-9]+)?|\.inf|\.nan)", text):
        raise YamlSubsetError(line, f"{text!r} reads differently across YAML versions, quote it")
    return text


def _block(lines, i: int, indent: int):
    if lines[i][2].startswith("- ") or lines[i][2] == "-":
        return _sequence(lines, i, indent)
    return _mapping(lines, i, indent)


def _mapping(lines, i: int, indent: int):
    out: dict = {}
    while i < len(lines):
        n, ind, text = lines[i]
        if ind < indent:
            break
        if ind > indent:
            raise YamlSubsetError(n, "unexpected indentation")
        m = KEY.fullmatch(text)
        if not m:
            raise YamlSubsetError(n, f"expected KEY: VALUE, got {text!r}")
        key, rest = m.group(1), m.group(2)
        if key in out:
            raise YamlSubsetError(n, f"{key!r} given twice")
        i += 1
        if rest:
            out[key] = _scalar(rest, n)
        elif i < len(lines) and lines[i][1] > indent:
            out[key], i = _block(lines, i, lines[i][1])
        else:
            out[key] = None
    return out, i


def _sequence(lines, i: int, indent: int):
    out = []
    while i < len(lines):
        n, ind, text = lines[i]
        if ind < indent:
            break
        if ind > indent or not text.startswith("- "):
            raise YamlSubsetError(n, f"expected '- ITEM' (items are scalars here), got {text!r}")
        item = text[2:].strip()
        if KEY.fullmatch(item):
            raise YamlSubsetError(n, "sequence items are scalars here, not mappings")
        out.append(_scalar(item, n))
        i += 1
    return out, i


def load(text: str):
    lines = []
    for n, raw in enumerate(text.splitlines(), 1):
        if "\t" in raw:
            raise YamlSubsetError(n, "a tab")
        body = _strip_comment(raw)
        if body.strip():
            if body.strip() in ("---", "..."):
                raise YamlSubsetError(n, "one document, without markers")
            lines.append((n, len(body) - len(body.lstrip(" ")), body.strip()))
    if not lines:
        return None
    if lines[0][1] != 0:
        raise YamlSubsetError(lines[0][0], "the document must start at column 0")
    value, i = _block(lines, 0, 0)
    if i != len(lines):
        raise YamlSubsetError(lines[i][0], "unexpected indentation")
    return value
