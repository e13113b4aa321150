"""The cue list: its validation (one line each, nothing stored), its JSON and its file, on a
coordinator core without edges (no network: the cue engine is the core's own)."""
from __future__ import annotations

import asyncio
import json

import pytest

from coordinator.rig import Rig, grid_slots, init_rig
from coordinator.server import Coordinator
from protos.cues import Cue, CueError, CueList

TOKEN = b"q" * 32


class Packets:
    def encoder(self):
        return self

    def prepare(self, contents):
        pass

    def packet(self, **kw):
        return b""


def cues(*items: Cue) -> CueList:
    return CueList(tuple(items))


@pytest.mark.parametrize("bad, says", [
    (Cue("1", "", "movie", "x"), "unknown kind 'movie' (choose one of still, asset, blackout, pattern)"),
    (Cue("1", "", "still", ""), "a still cue needs a target"),
    (Cue("1", "", "pattern", " "), "a pattern cue needs a target"),
    (Cue("1", "", "asset", "clip", fade_s=-1.0), "the fade must be 0 s or more"),
    (Cue("1", "", "asset", "clip", fade_s=float("nan")), "the fade must be 0 s or more"),
    (Cue("1", "", "blackout", follow_s=0.0), "the follow time must be more than 0 s"),
    (Cue("1 2", "", "blackout"), "the id must be"),
    (Cue("1", "", "still", "content", slots=("a", "a")), "a slot is named twice"),
    (Cue("1", "", "blackout", slots=("a",)), "a blackout darkens every projector"),
])
def test_a_cue_that_cannot_be_fired_is_refused_in_one_line(bad, says):
    with pytest.raises(CueError) as err:
        cues(bad).validate()
    assert says in str(err.value) and "\n" not in str(err.value)
    assert str(err.value).startswith("cue '")


def test_duplicate_ids_are_refused_and_the_json_round_trips():
    a = Cue("1", "Opening", "still", "content", fade_s=2.0, follow_s=5.0, slots=("r0c0",))
    with pytest.raises(CueError, match="cue '1': the id is used twice"):
        cues(a, Cue("1", "", "blackout")).validate()
    good = cues(a, Cue("2", "", "blackout"), Cue("3", "End", "asset", "clip"))
    good.validate()
    assert CueList.loads(good.dumps()) == good
    assert CueList.from_json(json.loads(good.dumps())["cues"]) == good, "a bare list reads too"
    with pytest.raises(CueError, match="unknown field"):
        CueList.from_json({"cues": [{"id": "1", "kind": "blackout", "colour": "red"}]})
    assert good.next_id() == "4" and good.index("3") == 2
    with pytest.raises(CueError, match="no cue '9' in the list"):
        good.index("9")


def test_the_core_stores_a_valid_list_and_refuses_one_naming_an_unknown_slot(tmp_path):
    rig_dir = init_rig(tmp_path / "rig", name="cues", slots=grid_slots(1, 2), width=32, height=32,
                       content_width=32, content_height=32)

    async def go():
        coord = Coordinator(Rig(rig_dir), TOKEN, encoding=Packets)
        first = cues(Cue("1", "Black", "blackout"), Cue("2", "", "still", "content", slots=("r0c1",)))
        assert coord.set_cues(first, who="ana") == "2 cues stored"
        before = (rig_dir / "cues.json").read_bytes()
        with pytest.raises(CueError, match="cue '1': slot 'r9c9' is not in the rig \\(slots: r0c0, r0c1\\)"):
            coord.set_cues(cues(Cue("1", "", "still", "content", slots=("r9c9",))))
        with pytest.raises(CueError, match="unknown test pattern 'plaid'"):
            coord.set_cues(cues(Cue("1", "", "pattern", "plaid")))
        # an asset a cue names must be there when the list is stored, not found missing mid-show
        with pytest.raises(CueError, match="cue '2': no asset matches 'nope.mp4'") as err:
            coord.set_cues(cues(Cue("1", "", "blackout"), Cue("2", "", "asset", "nope.mp4")))
        assert "\n" not in str(err.value)
        assert (rig_dir / "cues.json").read_bytes() == before, "a refused list changes nothing stored"
        assert coord.cue_state().cues == first.cues
        state = coord.cue_state()
        assert (state.current, state.next, state.fired_at) == (None, 0, None)
        with pytest.raises(CueError, match="no cue before this one"):
            coord.cue_back()
        # a second core on the same rig directory reads the same list
        again = Coordinator(Rig(rig_dir), TOKEN, encoding=Packets)
        assert again.cue_state().cues == first.cues

    asyncio.run(go())
