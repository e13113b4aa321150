"""The software's version is written once in the code and once in pyproject.toml: they agree, and
``shadowless --version`` prints it."""
from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

from protos.version import SOFTWARE_VERSION

ROOT = Path(__file__).resolve().parents[2]


def test_the_code_and_pyproject_name_one_version():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["version"] == SOFTWARE_VERSION


def test_the_cli_prints_it():
    out = subprocess.run([sys.executable, "-m", "shadowless", "--version"], capture_output=True, text=True,
                         timeout=60, check=True).stdout
    assert out.strip() == f"shadowless {SOFTWARE_VERSION}"
