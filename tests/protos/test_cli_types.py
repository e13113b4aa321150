"""The argparse types every command shares: values parsed, mistakes refused with an example."""
from __future__ import annotations

import argparse
import math

import pytest

from protos import cli_types as t


@pytest.mark.parametrize("text, value", [
    ("20G", 20 << 30), ("500M", 500 << 20), ("8g", 8 << 30), ("1.5G", 3 << 29), ("64k", 64 << 10),
    ("1048576", 1 << 20), ("20GB", 20 << 30), ("20GiB", 20 << 30), (" 2T ", 2 << 40),
])
def test_byte_sizes_parse_in_powers_of_1024(text, value):
    assert t.byte_size(text) == value


@pytest.mark.parametrize("text", ["", "0", "0M", "-1G", "abc", "20X", "G", "1e9", "0.5", "20 G B", "NaN"])
def test_bad_byte_sizes_are_refused_with_an_example(text):
    with pytest.raises(argparse.ArgumentTypeError, match=r"is not a size.*e\.g\. 20G or 500M"):
        t.byte_size(text)


@pytest.mark.parametrize("text, value", [("1920x1080", (1920, 1080)), (" 64 X 36 ", (64, 36)), ("1×1", (1, 1)),
                                         (f"{t.MAX_SIDE}x1", (t.MAX_SIDE, 1))])
def test_sizes(text, value):
    assert t.size(text) == value


@pytest.mark.parametrize("text", ["1920", "1920x", "x1080", "0x10", "10x0", "-5x5", "1.5x2", "axb", "",
                                  f"{t.MAX_SIDE + 1}x1", "1920x1080x3"])
def test_bad_sizes_name_the_form_and_an_example(text):
    with pytest.raises(argparse.ArgumentTypeError, match=r"is not a size WxH.*1920x1080"):
        t.size(text)


def test_grids_are_bounded_to_a_sensible_array():
    assert t.grid("5x5") == (5, 5)
    for bad in ("0x5", "65x1", "5"):
        with pytest.raises(argparse.ArgumentTypeError, match="COLSxROWS"):
            t.grid(bad)


def test_points_and_paths():
    assert t.pair("600,-300.5") == (600.0, -300.5)
    assert t.points_path("0,0:10,5:20,0") == [(0, 0), (10, 5), (20, 0)]
    for bad in ("1", "1,2,3", "nan,1", "inf,0", "a,b", ""):
        with pytest.raises(argparse.ArgumentTypeError, match="X,Y"):
            t.pair(bad)
    for bad in ("1,2", "1,2:x", "1,2:3"):
        with pytest.raises(argparse.ArgumentTypeError, match="two or more points"):
            t.points_path(bad)


def test_numbers_respect_their_bounds_and_refuse_nan_and_infinity():
    gain = t.number(0, 16, lo_open=True)
    assert gain("1.5") == 1.5 and gain("16") == 16.0
    for bad in ("0", "-1", "16.01", "nan", "inf", "-inf", "x", ""):
        with pytest.raises(argparse.ArgumentTypeError, match="above 0 and at most 16"):
            gain(bad)
    assert t.number()("-1e300") == -1e300
    with pytest.raises(argparse.ArgumentTypeError):
        t.number()("nan")
    assert math.isclose(t.number(0)("0"), 0.0)


def test_whole_numbers_and_lists():
    nodes = t.int_range(1, 256)
    assert nodes("16") == 16
    for bad in ("0", "257", "1.5", "x", "-3"):
        with pytest.raises(argparse.ArgumentTypeError, match="whole number 1..256"):
            nodes(bad)
    assert t.int_range(0)("0") == 0
    assert t.int_list(1, 25)("1, 9,25") == [1, 9, 25]
    for bad in ("", ",", "1,x", "0,1", "26"):
        with pytest.raises(argparse.ArgumentTypeError, match="list of whole numbers"):
            t.int_list(1, 25)(bad)
    assert t.names(" r0c0, r0c1 ,") == ["r0c0", "r0c1"]
    with pytest.raises(argparse.ArgumentTypeError, match="names"):
        t.names(" , ")


def test_paths_that_must_exist(tmp_path):
    f = tmp_path / "a.npy"
    f.write_bytes(b"x")
    assert t.existing_file(str(f)) == f and t.existing_dir(str(tmp_path)) == tmp_path
    with pytest.raises(argparse.ArgumentTypeError, match="no such file"):
        t.existing_file(str(tmp_path / "missing.npy"))
    with pytest.raises(argparse.ArgumentTypeError, match="not a file"):
        t.existing_file(str(tmp_path))
    with pytest.raises(argparse.ArgumentTypeError, match="not a folder"):
        t.existing_dir(str(f))
