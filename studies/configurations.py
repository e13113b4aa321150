"""The projector configurations a perception study compares: names and the slots that light them.

They are data, in a TOML file (``[configurations]``, ``NAME = ["slot", ...]``), because they
belong to the rig, not to the code: the default file shipped beside this module describes the
5x5 rig of the paper (P1, P9D, P9W, P13, P17, P20, P25); a rig with other slot names passes a
file of its own.
"""
from __future__ import annotations

import re
import tomllib
from pathlib import Path

#: the shipped configurations of the 5x5 rig
DEFAULT_FILE = Path(__file__).with_name("configurations.toml")

_NAME = re.compile(r"^[A-Za-z0-9_.+-]{1,32}$")


def load_configurations(path: str | Path | None = None) -> dict[str, tuple[str, ...]]:
    """Configuration name -> its slots, in file order. ValueError (naming the file) for a file that
    cannot be read, or a configuration without slots, with a repeated slot or an odd name."""
    p = Path(path) if path is not None else DEFAULT_FILE
    try:
        doc = tomllib.loads(p.read_text())
    except OSError as exc:
        raise ValueError(f"cannot read {p}: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{p}: not TOML: {exc}") from None
    table = doc.get("configurations")
    if not isinstance(table, dict) or not table:
        raise ValueError(f"{p}: needs a [configurations] table of NAME = [\"slot\", ...]")
    out: dict[str, tuple[str, ...]] = {}
    for name, slots in table.items():
        if not _NAME.match(name):
            raise ValueError(f"{p}: configuration name {name!r} must be 1-32 letters, digits or _.+-")
        if not isinstance(slots, list) or not slots or not all(isinstance(s, str) and s for s in slots):
            raise ValueError(f"{p}: configuration {name} must be a non-empty list of slot names")
        if len(set(slots)) != len(slots):
            raise ValueError(f"{p}: configuration {name} names a slot twice")
        out[name] = tuple(slots)
    return out
