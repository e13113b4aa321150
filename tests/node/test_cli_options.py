"""`shadowless node`'s asset options: --cache-max sizes and the per-slot default cache directory
(the size type itself: tests/protos/test_cli_types.py)."""
from __future__ import annotations

import argparse

import pytest

from node import cli
from node.asset_cache import default_cache_dir


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


def test_an_empty_cache_dir_from_an_env_file_means_the_default(tmp_path, monkeypatch):
    """A unit's ``--cache-dir ${CACHE_DIR}`` with CACHE_DIR empty must not put the cache in the cwd."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    cfg = cli.node_config(parser().parse_args(["--slot", "r0c0", "--cache-dir", ""]), b"t" * 32, None)
    assert cfg.cache_dir == tmp_path / "shadowless" / "assets" / "r0c0"
