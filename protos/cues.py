"""The cue list: a show as an ordered list of cues, the record both the coordinator and its
operators' tools speak (the console, ``shadowless cue``, OSC).

A :class:`Cue` says what the projectors show when it fires: a ``still`` (a name of the rig's
stills: ``content`` for the rig's own content), an ``asset`` (a key of the asset store: id,
prefix or name), ``blackout`` or a test ``pattern``; with an optional crossfade (``fade_s``,
done on the nodes from what is on screen, every node at the same rig instant) and an optional
auto-follow (``follow_s``: the next cue fires that many seconds after this one). ``slots``
names the projectors the cue is for (empty: all of them).

A :class:`CueList` is stored in the rig directory as ``cues.json`` (written atomically by the
coordinator). :meth:`CueList.validate` refuses what cannot be fired, with one line naming the
cue and what to change; the slot names are checked by the coordinator, which knows them
(:meth:`CueList.check_slots`).
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping

__all__ = ["KINDS", "MAX_CUES", "Cue", "CueError", "CueList"]

#: what a cue can show
KINDS = ("still", "asset", "blackout", "pattern")
#: kinds whose target names something
TARGETED = ("still", "asset", "pattern")
#: a cue list longer than this is refused (a show of a thousand cues is a mistake, or an attack)
MAX_CUES = 1000
#: the longest fade and follow time, seconds
MAX_SECONDS = 3600.0
_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,31}$")
_FIELDS = ("id", "name", "kind", "target", "fade_s", "follow_s", "slots")


class CueError(ValueError):
    """A cue or cue list is refused; the message is one line naming the cue and the fix."""


def _seconds(value: Any, what: str, where: str, *, allow_none: bool = False) -> float | None:
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CueError(f"{where}: {what} must be a number of seconds, got {value!r}")
    v = float(value)
    if not math.isfinite(v) or v < 0:
        raise CueError(f"{where}: {what} must be 0 s or more, got {value!r}")
    if v > MAX_SECONDS:
        raise CueError(f"{where}: {what} must be at most {MAX_SECONDS:g} s, got {value!r}")
    return v


@dataclass(frozen=True)
class Cue:
    """One cue (see the module docstring). ``fade_s`` 0 is a cut; ``follow_s`` None: wait for GO."""

    id: str
    name: str
    kind: str
    target: str = ""
    fade_s: float = 0.0
    follow_s: float | None = None
    slots: tuple[str, ...] = field(default=())

    @property
    def label(self) -> str:
        """How the operator reads it: ``3 "Opening" (still content)``."""
        what = self.kind if self.kind == "blackout" else f"{self.kind} {self.target}"
        return f"{self.id} {self.name!r} ({what})" if self.name else f"{self.id} ({what})"

    def validate(self) -> None:
        """CueError (one line) for an id, kind, target, fade, follow or slot list that cannot be fired."""
        where = f"cue {self.id!r}" if isinstance(self.id, str) and self.id else "a cue"
        if not isinstance(self.id, str) or not _ID.match(self.id):
            raise CueError(f"{where}: the id must be 1-32 letters, digits, '.', '_' or '-', starting with a letter "
                           f"or digit, got {self.id!r}")
        if not isinstance(self.name, str) or len(self.name) > 200 or any(ord(c) < 32 for c in self.name):
            raise CueError(f"{where}: the name must be one line of at most 200 characters")
        if self.kind not in KINDS:
            raise CueError(f"{where}: unknown kind {self.kind!r} (choose one of {', '.join(KINDS)})")
        if not isinstance(self.target, str) or len(self.target) > 200:
            raise CueError(f"{where}: the target must be a name of at most 200 characters")
        if self.kind in TARGETED and not self.target.strip():
            hint = {"still": "a still's name, e.g. content", "asset": "an asset's name or id",
                    "pattern": "a test pattern, e.g. grid"}[self.kind]
            raise CueError(f"{where}: a {self.kind} cue needs a target ({hint})")
        _seconds(self.fade_s, "the fade", where)
        follow = _seconds(self.follow_s, "the follow time", where, allow_none=True)
        if follow is not None and follow <= 0:
            raise CueError(f"{where}: the follow time must be more than 0 s (leave it out to wait for GO)")
        if not isinstance(self.slots, tuple) or not all(isinstance(s, str) and s for s in self.slots):
            raise CueError(f"{where}: slots must be a list of slot names")
        if self.kind == "blackout" and self.slots:
            raise CueError(f"{where}: a blackout darkens every projector; leave its slots out")
        if len(set(self.slots)) != len(self.slots):
            raise CueError(f"{where}: a slot is named twice in {', '.join(self.slots)}")

    def to_json(self) -> dict[str, Any]:
        return {"id": self.id, "name": self.name, "kind": self.kind, "target": self.target,
                "fade_s": self.fade_s, "follow_s": self.follow_s, "slots": list(self.slots)}

    @classmethod
    def from_json(cls, doc: Any) -> "Cue":
        """A cue from its JSON object (CueError for a malformed one; call :meth:`validate` to check it)."""
        if not isinstance(doc, Mapping):
            raise CueError(f"a cue must be a JSON object, got {type(doc).__name__}")
        unknown = sorted(set(doc) - set(_FIELDS))
        if unknown:
            raise CueError(f"cue {doc.get('id', '?')!r}: unknown field(s) {', '.join(map(str, unknown))} "
                           f"(known: {', '.join(_FIELDS)})")
        slots = doc.get("slots", [])
        if isinstance(slots, str):
            slots = [s for s in slots.replace(",", " ").split() if s]
        if not isinstance(slots, (list, tuple)):
            raise CueError(f"cue {doc.get('id', '?')!r}: slots must be a list of slot names")
        fade = doc.get("fade_s", 0.0)
        return cls(id=doc.get("id", ""), name=doc.get("name", "") or "", kind=doc.get("kind", ""),
                   target=doc.get("target", "") or "", fade_s=0.0 if fade is None else fade,
                   follow_s=doc.get("follow_s"), slots=tuple(slots))


@dataclass(frozen=True)
class CueList:
    """The show's cues, in firing order."""

    cues: tuple[Cue, ...] = ()

    def __len__(self) -> int:
        return len(self.cues)

    def validate(self) -> None:
        """CueError (one line) for the first cue that cannot be fired, or an id used twice."""
        if not isinstance(self.cues, tuple):
            raise CueError("the cue list must be a list of cues")
        if len(self.cues) > MAX_CUES:
            raise CueError(f"a cue list holds at most {MAX_CUES} cues, got {len(self.cues)}")
        seen: set[str] = set()
        for cue in self.cues:
            if not isinstance(cue, Cue):
                raise CueError("the cue list must be a list of cues")
            cue.validate()
            if cue.id in seen:
                raise CueError(f"cue {cue.id!r}: the id is used twice; give each cue its own id")
            seen.add(cue.id)

    def check_slots(self, slots: Iterable[str]) -> None:
        """CueError for a cue naming a slot that is not in ``slots`` (the rig's)."""
        known = list(slots)
        for cue in self.cues:
            for s in cue.slots:
                if s not in known:
                    raise CueError(f"cue {cue.id!r}: slot {s!r} is not in the rig (slots: {', '.join(known)})")

    def index(self, cue_id: str) -> int:
        """The position of cue ``cue_id`` (CueError naming the ids there are)."""
        for i, cue in enumerate(self.cues):
            if cue.id == cue_id:
                return i
        ids = ", ".join(c.id for c in self.cues[:20]) or "none"
        raise CueError(f"no cue {cue_id!r} in the list (cues: {ids}{', …' if len(self.cues) > 20 else ''})")

    def next_id(self) -> str:
        """An id not used yet: one more than the largest whole-number id."""
        nums = [int(c.id) for c in self.cues if c.id.isdigit()]
        return str(max(nums, default=0) + 1)

    def to_json(self) -> dict[str, Any]:
        return {"version": 1, "cues": [c.to_json() for c in self.cues]}

    def dumps(self) -> str:
        return json.dumps(self.to_json(), indent=1)

    @classmethod
    def from_json(cls, doc: Any) -> "CueList":
        """A cue list from ``{"cues": [...]}`` or a bare list (CueError for a malformed one;
        call :meth:`validate` to check the cues)."""
        if isinstance(doc, Mapping):
            if "cues" not in doc:
                raise CueError('a cue list must be {"cues": [...]}')
            doc = doc["cues"]
        if not isinstance(doc, (list, tuple)):
            raise CueError(f"the cues must be a JSON list, got {type(doc).__name__}")
        if len(doc) > MAX_CUES:
            raise CueError(f"a cue list holds at most {MAX_CUES} cues, got {len(doc)}")
        return cls(tuple(Cue.from_json(c) for c in doc))

    @classmethod
    def loads(cls, text: str) -> "CueList":
        try:
            doc = json.loads(text)
        except ValueError as exc:
            raise CueError(f"the cue list is not JSON: {exc}") from None
        return cls.from_json(doc)
