"""Whether a stored blend still describes the rig: what each projector's measured light depends on.

A blend is measured through each slot's pose (where its pixels land), its LUT (the light is linear
only through it) and its gain (folded into the measured contributions). When any of them changes
after the measurement (a recalibration, a new response run, a gain set by hand), the maps no longer
even the light, and the operator should measure again. The blend job stores one digest per slot;
the core compares it with the slot as it is now.
"""
from __future__ import annotations

import hashlib
import weakref
from collections.abc import Mapping

from coordinator.rig import Rig, SlotState, hash_slot_state

__all__ = ["slot_digest", "slot_digests", "changed_since"]


def slot_digest(st: SlotState) -> str:
    """A digest of what a slot's measured light depends on (:func:`coordinator.rig.hash_slot_state`)."""
    h = hashlib.blake2b(digest_size=8)
    hash_slot_state(h, st)
    return h.hexdigest()


def slot_digests(rig: Rig, slots) -> dict[str, str]:
    """``{slot: slot_digest}`` for ``slots`` of ``rig`` as they are now."""
    return {s: slot_digest(rig.slot(s)) for s in slots if s in rig.slots}


def changed_since(rig: Rig, measured: Mapping[str, str] | None) -> list[str]:
    """The slots whose pose, LUT, gain or size changed since ``measured`` (a blend's stored digests;
    a blend stored without them, or a slot the rig no longer has, is not judged)."""
    if not measured:
        return []
    return sorted(s for s, d in measured.items() if s in rig.slots and _current_digest(rig, s) != d)


#: per rig, per slot: (pose, LUT, gain, size) as last hashed, and their digest
_DIGESTS: "weakref.WeakKeyDictionary[Rig, dict[str, tuple[tuple, str]]]" = weakref.WeakKeyDictionary()


def _current_digest(rig: Rig, slot: str) -> str:
    """:func:`slot_digest` of the slot as it is now, hashed again only when its pose or LUT was replaced or
    its gain or size changed (a status asks every slot each time: 25 LUTs took 2 ms of the event loop).
    The pose and LUT are compared by identity: the rig replaces them, never changes them in place."""
    st = rig.slot(slot)
    held = _DIGESTS.setdefault(rig, {})
    key = (st.pose, st.lut, st.gain, st.width, st.height)
    last = held.get(slot)
    if last is not None and last[0][0] is key[0] and last[0][1] is key[1] and last[0][2:] == key[2:]:
        return last[1]
    digest = slot_digest(st)
    held[slot] = (key, digest)
    return digest
