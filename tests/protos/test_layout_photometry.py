"""A layout's [photometry] section passes through protos.layout to the room, which alone reads it."""
from __future__ import annotations

import pytest

from protos.layout import LayoutFileError, read_layout

BASE = """
[table]
size = [1000, 500]
[[projector]]
position = [0, 0, 1000]
[[camera]]
position = [0, -100, 1400]
"""


def test_photometry_is_passed_through_as_written(tmp_path):
    path = tmp_path / "a.toml"
    path.write_text(BASE + "[photometry]\nbrightness_spread = 0.15\nanything = 1\n")
    assert read_layout(path).photometry == {"brightness_spread": 0.15, "anything": 1}
    path.write_text(BASE)
    assert read_layout(path).photometry == {}


def test_a_photometry_that_is_not_a_table_is_refused_in_one_line(tmp_path):
    path = tmp_path / "a.toml"
    path.write_text("photometry = 0.15\n" + BASE)
    with pytest.raises(LayoutFileError, match=r"a\.toml: \[photometry\] must be a table") as err:
        read_layout(path)
    assert "\n" not in str(err.value)
