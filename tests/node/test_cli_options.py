"""`shadowless node`'s asset options: --cache-max sizes and the per-slot default cache directory."""
from __future__ import annotations

import argparse

import pytest

from node import cli
from node.asset_cache import default_cache_dir


@pytest.mark.parametrize("text, value", [
    ("20G", 20 << 30), ("500M", 500 << 20), ("8g", 8 << 30), ("1.5G", 3 << 29), ("64k", 64 << 10),
    ("1048576", 1 << 20), ("20GB", 20 << 30), ("20GiB", 20 << 30), (" 2T ", 2 << 40),
])
def test_sizes_parse_in_powers_of_1024(text, value):
    assert cli.parse_size(text) == value


@pytest.mark.parametrize("text", ["", "0", "0M", "-1G", "abc", "20X", "G", "1e9", "0.5", "20 G B", "NaN"])
def test_bad_sizes_are_refused_with_an_example(text):
    with pytest.raises(argparse.ArgumentTypeError, match=r"is not a size.*e\.g\. 20G or 500M"):
        cli.parse_size(text)


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="shadowless node")
    cli.configure(p)
    return p


def test_defaults_and_a_clear_error_for_a_bad_cache_max(capsys):
    args = parser().parse_args(["--slot", "r0c0"])
    assert args.cache_max == 8 << 30 and args.cache_dir is None and args.fetch_rate is None
    args = parser().parse_args(["--slot", "r0c0", "--cache-max", "500M", "--cache-dir", "/tmp/x", "--fetch-rate", "20M"])
    assert (args.cache_max, str(args.cache_dir), args.fetch_rate) == (500 << 20, "/tmp/x", 20 << 20)
    with pytest.raises(SystemExit) as exit_:
        parser().parse_args(["--slot", "r0c0", "--cache-max", "lots"])
    assert exit_.value.code == 2
    assert "--cache-max: 'lots' is not a size" in capsys.readouterr().err


def test_each_slot_gets_its_own_default_cache_directory(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    dirs = [cli.node_config(parser().parse_args(["--slot", s]), b"t" * 32, None).cache_dir for s in ("r0c0", "r0c1")]
    assert dirs == [tmp_path / "shadowless" / "assets" / "r0c0", tmp_path / "shadowless" / "assets" / "r0c1"]
    assert default_cache_dir() == tmp_path / "shadowless" / "assets"
    cfg = cli.node_config(parser().parse_args(["--slot", "r0c0", "--cache-dir", str(tmp_path / "c"), "--cache-max",
                                               "1G"]), b"t" * 32, None)
    assert (cfg.cache_dir, cfg.cache_max_bytes, cfg.fetch_rate) == (tmp_path / "c", 1 << 30, None)
